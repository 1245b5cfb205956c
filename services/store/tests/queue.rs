//! The store's contract, run against a real Postgres and a real SQLite: the same suite for both
//! (see `common` for how each test gets its databases).

#[macro_use]
mod common;

use std::collections::BTreeSet;

use common::*;
use serde_json::json;
use vint_core::plan::NewTask;
use vint_core::{AttemptOutcome, JobState, Stage, TaskState};
use vint_store::{Store, StoreError};

/// The package task of `submit_chain`, keyed as the planner keys them (object, hand, chunk).
const PACKAGE: &str = "package/can/trx3/c00000";
/// A sample `PACKAGE` makes.
const SAMPLE: &str = "can.trx3.g000000.v00";

async fn submit_chain(store: &Store, id: &str) {
    submit_chain_at(store, id, 0).await;
}

async fn submit_chain_at(store: &Store, id: &str, now_ms: i64) {
    let tasks = [
        task("grasp/a", Stage::Grasp, &[]),
        task("render/a", Stage::Render, &["grasp/a"]),
        task(PACKAGE, Stage::Package, &["grasp/a", "render/a"]),
    ];
    store.submit_job(&job(id), &tasks, now_ms).await.unwrap();
}

async fn state_of(store: &Store, task_id: &str) -> TaskState {
    store.task(task_id).await.unwrap().unwrap().state
}

// More tasks than one insert statement takes (5,000): a chain whose links cross batches still
// counts each task's one pending dependency, and only its head is queued.
store_test!(a_job_larger_than_one_insert_batch_is_inserted_whole_with_its_edges, |store: Store| async move {
    let keys: Vec<String> = (0..12_001).map(|i| format!("grasp/{i:05}")).collect();
    let tasks: Vec<NewTask> = keys
        .iter()
        .enumerate()
        .map(|(i, k)| {
            let deps: Vec<&str> = if i == 0 { vec![] } else { vec![keys[i - 1].as_str()] };
            task(k, Stage::Grasp, &deps)
        })
        .collect();
    store.submit_job(&job("j"), &tasks, 0).await.unwrap();
    let all = store.tasks_of_job("j").await.unwrap();
    assert_eq!(all.len(), 12_001);
    let progress = store.progress("j").await.unwrap();
    assert_eq!(progress.count(TaskState::Queued), 1);
    assert_eq!(progress.count(TaskState::Waiting), 12_000);
    assert_eq!(store.table_rows().await.unwrap().task_deps, 12_000);
    assert_eq!(store.lineage("j/grasp/00001").await.unwrap()[0].depends_on, ["j/grasp/00000"]);
});

store_test!(submit_is_idempotent, |store: Store| async move {
    let (a, created_a) = store.submit_job(&job("j1"), &[task("grasp/a", Stage::Grasp, &[])], 0).await.unwrap();
    let mut again = job("j2");
    again.idempotency_key = "key-j1".into();
    let (b, created_b) = store.submit_job(&again, &[task("grasp/a", Stage::Grasp, &[])], 5).await.unwrap();
    assert!(created_a && !created_b);
    assert_eq!(a.id, b.id);
    assert_eq!(store.list_jobs(10).await.unwrap().len(), 1);
});

store_test!(dependencies_gate_leasing_until_they_succeed, |store: Store| async move {
    submit_chain(&store, "j").await;
    assert_eq!(state_of(&store, "j/render/a").await, TaskState::Waiting);
    let all = [Stage::Grasp, Stage::Render, Stage::Noise, Stage::Package];
    let leased = store.lease("w", &all, 10, 1_000, 1).await.unwrap();
    assert_eq!(leased.iter().map(|t| t.key.as_str()).collect::<Vec<_>>(), ["grasp/a"]);
    store.complete(&completion(fence(&leased[0], "w"), &["grasps.json"]), &[], 2).await.unwrap();
    let next = store.lease("w", &all, 10, 1_000, 3).await.unwrap();
    assert_eq!(next.len(), 1);
    assert_eq!(next[0].key, "render/a");
    assert_eq!(next[0].inputs.len(), 1);
    assert_eq!(next[0].inputs[0].name, "grasps.json");
    assert_eq!(next[0].inputs[0].task_key, "grasp/a");
    assert_eq!(state_of(&store, &format!("j/{PACKAGE}")).await, TaskState::Waiting);
    store.complete(&completion(fence(&next[0], "w"), &["v00_rgb.png"]), &[], 4).await.unwrap();
    let package = store.lease("w", &all, 10, 1_000, 5).await.unwrap();
    assert_eq!(package[0].key, PACKAGE);
    assert_eq!(package[0].inputs.len(), 2, "package sees both dependencies' outputs");
});

store_test!(leasing_is_restricted_to_the_workers_stages, |store: Store| async move {
    submit_chain(&store, "j").await;
    assert!(store.lease("w", &[Stage::Render], 10, 1_000, 1).await.unwrap().is_empty());
    assert_eq!(store.lease("w", &[Stage::Grasp], 10, 1_000, 1).await.unwrap().len(), 1);
});

store_test!(concurrent_workers_never_lease_the_same_task, |store: Store| async move {
    let tasks: Vec<NewTask> = (0..200).map(|i| task(&format!("grasp/{i:03}"), Stage::Grasp, &[])).collect();
    store.submit_job(&job("j"), &tasks, 0).await.unwrap();
    let mut handles = Vec::new();
    for w in 0..8 {
        let store = store.clone();
        handles.push(tokio::spawn(async move {
            let mut mine = Vec::new();
            loop {
                let got = store.lease(&format!("w{w}"), &[Stage::Grasp], 7, 60_000, 1).await.unwrap();
                if got.is_empty() {
                    break mine;
                }
                mine.extend(got.into_iter().map(|t| t.id));
            }
        }));
    }
    let mut all = Vec::new();
    for h in handles {
        all.extend(h.await.unwrap());
    }
    let unique: BTreeSet<_> = all.iter().cloned().collect();
    assert_eq!(all.len(), 200);
    assert_eq!(unique.len(), 200);
});

store_test!(a_reaped_lease_cannot_complete_its_task, |store: Store| async move {
    submit_chain(&store, "j").await;
    let leased = store.lease("slow", &[Stage::Grasp], 1, 1_000, 0).await.unwrap();
    let f = fence(&leased[0], "slow");
    // Reaped: neither a completion nor a failure of the old lease is taken.
    assert_eq!(store.reap_expired(1_002, 0).await.unwrap(), 1);
    let err = store.complete(&completion(f.clone(), &["grasps.json"]), &[], 1_003).await.unwrap_err();
    assert!(matches!(err, StoreError::LeaseLost { .. }), "{err}");
    assert!(matches!(store.fail(&f, true, "x", 1_003).await.unwrap_err(), StoreError::LeaseLost { .. }));
    // After another worker took it over, the old worker still cannot.
    let retaken = store.lease("fast", &[Stage::Grasp], 1, 1_000, 2_000).await.unwrap();
    assert_eq!(retaken[0].attempt, 2);
    let err = store.complete(&completion(f, &["grasps.json"]), &[], 2_001).await.unwrap_err();
    assert!(matches!(err, StoreError::LeaseLost { .. }));
    store.complete(&completion(fence(&retaken[0], "fast"), &["grasps.json"]), &[], 2_002).await.unwrap();
    assert_eq!(store.artifacts_of_task("j/grasp/a").await.unwrap().len(), 1, "exactly one set of outputs");
    let attempts = store.attempts("j/grasp/a").await.unwrap();
    assert_eq!(
        attempts.iter().map(|a| a.outcome).collect::<Vec<_>>(),
        [Some(AttemptOutcome::LeaseExpired), Some(AttemptOutcome::Succeeded)]
    );
});

store_test!(an_expired_lease_is_its_owner_s_until_the_reaper_takes_it, |store: Store| async move {
    // A worker that could not reach the coordinator past its deadline (the coordinator or the
    // database was down) keeps its lease: a heartbeat revives it, a completion is taken.
    let tasks = [task("grasp/a", Stage::Grasp, &[]), task("grasp/b", Stage::Grasp, &[])];
    store.submit_job(&job("j"), &tasks, 0).await.unwrap();
    let a = store.lease("w", &[Stage::Grasp], 1, 1_000, 0).await.unwrap().remove(0);
    let b = store.lease("w", &[Stage::Grasp], 1, 1_000, 0).await.unwrap().remove(0);
    let held = vec![(a.id.clone(), a.attempt)];
    assert!(store.heartbeat("w", &held, 1_000, 5_000).await.map(|b| b.lost).unwrap().is_empty(), "revived until 6,000");
    assert_eq!(store.heartbeat("x", &held, 1_000, 5_000).await.map(|b| b.lost).unwrap(), held, "not by another worker");
    assert_eq!(store.reap_expired(5_500, 0).await.unwrap(), 1, "only the lease nobody revived");
    store.complete(&completion(fence(&a, "w"), &["grasps.json"]), &[], 7_000).await.unwrap();
    assert_eq!(state_of(&store, &a.id).await, TaskState::Succeeded, "completed past the revived deadline too");
    assert_eq!(state_of(&store, &b.id).await, TaskState::Queued);
    let attempts = store.attempts(&a.id).await.unwrap();
    assert_eq!(attempts.iter().map(|t| t.outcome).collect::<Vec<_>>(), [Some(AttemptOutcome::Succeeded)]);
});

/// A heartbeat or lease that waited for a connection dates its deadline from when it got one: had
/// it read the clock before the wait (the database down, the pool busy), it would write a deadline
/// already stale, and the reaper would take the lease from a live worker. SQLite's pool holds one
/// connection, so a heartbeat whose clock stalls (read while it holds the connection) makes the
/// next wait; the next one's deadline must not be earlier.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lease_s_clock_is_read_once_a_connection_is_held() {
    let db = sqlite_db().await;
    let store = db.store.clone();
    store
        .submit_job(&job("j"), &[task("grasp/a", Stage::Grasp, &[]), task("grasp/b", Stage::Grasp, &[])], 0)
        .await
        .unwrap();
    let leased = store.lease("w", &[Stage::Grasp], 1, 1_000, 0).await.unwrap();
    let held = vec![(leased[0].id.clone(), leased[0].attempt)];
    let wall = || std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap().as_millis() as i64;
    let stalled = move || {
        std::thread::sleep(std::time::Duration::from_millis(400));
        wall()
    };
    let first = tokio::spawn({
        let (store, held) = (store.clone(), held.clone());
        async move { store.heartbeat("w", &held, 1_000, stalled).await.unwrap() }
    });
    tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    let second = store.heartbeat("w", &held, 1_000, wall).await.unwrap();
    let first = first.await.unwrap();
    assert!(first.lost.is_empty() && second.lost.is_empty());
    assert!(
        second.deadline_ms >= first.deadline_ms,
        "the second heartbeat waited for the connection, yet dated its deadline {} ms before the first's",
        first.deadline_ms - second.deadline_ms
    );
    let stalled = move || {
        std::thread::sleep(std::time::Duration::from_millis(400));
        wall()
    };
    let beat = tokio::spawn({
        let (store, held) = (store.clone(), held.clone());
        async move { store.heartbeat("w", &held, 1_000, stalled).await.unwrap() }
    });
    tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    let b = store.lease("w2", &[Stage::Grasp], 1, 1_000, wall).await.unwrap().remove(0);
    assert!(b.lease_deadline_ms >= beat.await.unwrap().deadline_ms, "a lease too");
}

store_test!(the_reaper_gives_a_worker_a_whole_lease_to_be_heard_after_an_outage, |store: Store| async move {
    // Leases of 1,000 ms granted at 0; the coordinator could hear again from 10,000 (it started,
    // or the database came back).
    let tasks = [task("grasp/a", Stage::Grasp, &[]), task("grasp/b", Stage::Grasp, &[])];
    store.submit_job(&job("j"), &tasks, 0).await.unwrap();
    let leased = store.lease("w", &[Stage::Grasp], 2, 1_000, 0).await.unwrap();
    assert_eq!(store.reap_expired(10_999, 10_000).await.unwrap(), 0, "a lease's worth not yet heard");
    // The worker of a heartbeats within that lease; b's worker died in the outage.
    let held = vec![(leased[0].id.clone(), leased[0].attempt)];
    assert!(store.heartbeat("w", &held, 1_000, 10_500).await.map(|b| b.lost).unwrap().is_empty());
    assert_eq!(store.reap_expired(11_000, 10_000).await.unwrap(), 1);
    assert_eq!(state_of(&store, &leased[0].id).await, TaskState::Running);
    assert_eq!(state_of(&store, &leased[1].id).await, TaskState::Queued);
    // Its expiry did not count, and it comes back at once.
    let expired = store.attempts(&leased[1].id).await.unwrap();
    assert_eq!(expired[0].outcome, Some(AttemptOutcome::LeaseExpired));
    assert!(expired[0].error.as_deref().is_some_and(|e| e.contains("not counted")), "{expired:?}");
    let again = store.lease("w2", &[Stage::Grasp], 1, 1_000, 11_000).await.unwrap();
    assert_eq!(again.len(), 1, "no backoff for an attempt that does not count");
});

store_test!(expiries_in_an_outage_never_fail_a_task_and_others_do, |store: Store| async move {
    // RETRY.max_attempts = 3. Ten leases that ran out while nobody could hear them leave the task
    // queued; then three that were heard and went quiet fail it.
    submit_chain(&store, "j").await;
    let mut now = 0;
    for _ in 0..10 {
        let t = store.lease("w", &[Stage::Grasp], 1, 1_000, now).await.unwrap().remove(0);
        now += 1_001;
        assert_eq!(store.reap_expired(now + 1_000, now).await.unwrap(), 1);
        assert_eq!(state_of(&store, &t.id).await, TaskState::Queued);
        now += 1_000;
    }
    for n in 1..=RETRY.max_attempts {
        now += RETRY.backoff_cap_ms;
        store.lease("w", &[Stage::Grasp], 1, 1_000, now).await.unwrap().remove(0);
        now += 1_001;
        assert_eq!(store.reap_expired(now, 0).await.unwrap(), 1);
        let expected = if n < RETRY.max_attempts { TaskState::Queued } else { TaskState::Failed };
        assert_eq!(state_of(&store, "j/grasp/a").await, expected, "counted expiry {n}");
    }
});

store_test!(wrong_worker_or_attempt_cannot_complete, |store: Store| async move {
    submit_chain(&store, "j").await;
    let leased = store.lease("w1", &[Stage::Grasp], 1, 1_000, 0).await.unwrap();
    let mut other = fence(&leased[0], "w2");
    let refused = store.complete(&completion(other.clone(), &[]), &[], 1).await;
    assert!(matches!(refused, Err(StoreError::LeaseLost { ref worker_id, .. }) if worker_id == "w2"), "{refused:?}");
    other.worker_id = "w1".into();
    other.attempt += 1;
    let refused = store.complete(&completion(other, &[]), &[], 1).await;
    assert!(matches!(refused, Err(StoreError::LeaseLost { attempt: 2, .. })), "{refused:?}");
    assert_eq!(state_of(&store, "j/grasp/a").await, TaskState::Running);
});

store_test!(a_released_task_is_queued_again_at_once_and_its_attempt_says_released, |store: Store| async move {
    let tasks = [task("grasp/a", Stage::Grasp, &[]), task("grasp/b", Stage::Grasp, &[])];
    store.submit_job(&job("j"), &tasks, 0).await.unwrap();
    let leased = store.lease("w", &[Stage::Grasp], 2, 60_000, 10).await.unwrap();
    let held: Vec<(String, u32)> = leased.iter().map(|t| (t.id.clone(), t.attempt)).collect();
    let released = store.release("w", &held, 20).await.unwrap();
    assert_eq!(released, held, "both leases given back");
    for (id, _) in &held {
        assert_eq!(state_of(&store, id).await, TaskState::Queued);
        let attempts = store.attempts(id).await.unwrap();
        assert_eq!(attempts.len(), 1, "{attempts:?}");
        assert_eq!(attempts[0].outcome, Some(AttemptOutcome::Released));
        assert_eq!((attempts[0].worker_id.as_str(), attempts[0].started_ms, attempts[0].ended_ms), ("w", 10, Some(20)));
    }
    // No backoff: another worker leases them in the same millisecond, as their second attempts.
    let again = store.lease("w2", &[Stage::Grasp], 2, 60_000, 20).await.unwrap();
    assert_eq!(
        again.iter().map(|t| (t.id.clone(), t.attempt)).collect::<Vec<_>>(),
        [("j/grasp/a".to_string(), 2), ("j/grasp/b".to_string(), 2)]
    );
});

store_test!(a_release_by_anyone_but_the_lease_holder_at_its_attempt_is_refused, |store: Store| async move {
    submit_chain(&store, "j").await;
    let leased = store.lease("w1", &[Stage::Grasp], 1, 1_000, 0).await.unwrap().remove(0);
    let id = leased.id.clone();
    assert!(store.release("w2", &[(id.clone(), 1)], 1).await.unwrap().is_empty(), "another worker");
    assert!(store.release("w1", &[(id.clone(), 2)], 1).await.unwrap().is_empty(), "another attempt");
    assert!(store.release("w1", &[("j/grasp/missing".into(), 1)], 1).await.unwrap().is_empty(), "no such task");
    assert_eq!(state_of(&store, &id).await, TaskState::Running);
    assert!(store.attempts(&id).await.unwrap()[0].outcome.is_none(), "the attempt still runs");
    // The holder itself can, and only once; a completion after it is refused.
    assert_eq!(store.release("w1", &[(id.clone(), 1)], 1_000).await.unwrap(), [(id.clone(), 1)]);
    assert!(store.release("w1", &[(id.clone(), 1)], 1_000).await.unwrap().is_empty());
    let late = store.complete(&completion(fence(&leased, "w1"), &[]), &[], 1_000).await.unwrap_err();
    assert!(matches!(late, StoreError::LeaseLost { .. }), "{late}");
    assert_eq!(store.attempts(&id).await.unwrap().len(), 1, "the attempt is written once");
});

store_test!(releases_do_not_bring_a_task_closer_to_failing_for_good, |store: Store| async move {
    submit_chain(&store, "j").await;
    let mut now = 0;
    let lease = |now: i64| {
        let store = store.clone();
        async move { store.lease("w", &[Stage::Grasp], 1, 1_000, now).await.unwrap().remove(0) }
    };
    for _ in 0..10 {
        let t = lease(now).await;
        assert_eq!(store.release("w", &[(t.id.clone(), t.attempt)], now).await.unwrap().len(), 1);
        now += 1;
    }
    // Still every retry a fresh task has (RETRY.max_attempts = 3): two retryable failures requeue
    // it, the third fails it for good.
    for n in 1..=RETRY.max_attempts {
        now += RETRY.backoff_cap_ms;
        let t = lease(now).await;
        assert_eq!(t.attempt, 10 + n);
        let will_retry = store.fail(&fence(&t, "w"), true, "transient", now).await.unwrap();
        assert_eq!(will_retry, n < RETRY.max_attempts, "failure {n} after 10 releases");
    }
    assert_eq!(state_of(&store, "j/grasp/a").await, TaskState::Failed);
    let outcomes: Vec<_> = store.attempts("j/grasp/a").await.unwrap().iter().map(|a| a.outcome).collect();
    assert_eq!(outcomes.iter().filter(|o| **o == Some(AttemptOutcome::Released)).count(), 10);
    assert_eq!(outcomes.last(), Some(&Some(AttemptOutcome::Failed)));
});

store_test!(heartbeat_extends_leases_and_reports_lost_ones, |store: Store| async move {
    submit_chain(&store, "j").await;
    let leased = store.lease("w", &[Stage::Grasp], 1, 1_000, 0).await.unwrap();
    let held = vec![(leased[0].id.clone(), leased[0].attempt)];
    assert!(store.heartbeat("w", &held, 1_000, 900).await.map(|b| b.lost).unwrap().is_empty());
    assert_eq!(store.reap_expired(1_500, 0).await.unwrap(), 0, "extended to 1900");
    let lost = store.heartbeat("w", &[("j/grasp/missing".into(), 1)], 1_000, 1_000).await.map(|b| b.lost).unwrap();
    assert_eq!(lost.len(), 1);
    assert_eq!(store.reap_expired(1_901, 0).await.unwrap(), 1);
    assert_eq!(
        store.heartbeat("w", &held, 1_000, 1_902).await.map(|b| b.lost).unwrap(),
        held,
        "a reaped lease is lost"
    );
});

store_test!(retries_back_off_then_fail_with_the_last_error, |store: Store| async move {
    submit_chain(&store, "j").await;
    let mut now = 0;
    for attempt in 1..=3u32 {
        let leased = store.lease("w", &[Stage::Grasp], 1, 1_000, now).await.unwrap();
        assert_eq!(leased.len(), 1, "attempt {attempt} leasable at {now}");
        assert_eq!(leased[0].attempt, attempt);
        let will_retry = store.fail(&fence(&leased[0], "w"), true, &format!("boom {attempt}"), now + 1).await.unwrap();
        assert_eq!(will_retry, attempt < 3);
        if will_retry {
            let backoff = 100 * (1 << (attempt - 1));
            assert!(store.lease("w", &[Stage::Grasp], 1, 1_000, now + backoff).await.unwrap().is_empty(), "backoff");
            now += backoff + 1;
        }
    }
    let t = store.task("j/grasp/a").await.unwrap().unwrap();
    assert_eq!(t.state, TaskState::Failed);
    assert_eq!(t.last_error.as_deref(), Some("boom 3"));
    // Its dependents can never run: they fail too, and the job ends failed.
    assert_eq!(state_of(&store, "j/render/a").await, TaskState::Failed);
    assert_eq!(state_of(&store, &format!("j/{PACKAGE}")).await, TaskState::Failed);
    assert_eq!(store.job("j").await.unwrap().unwrap().state, JobState::Failed);
});

store_test!(permanent_failure_is_not_retried, |store: Store| async move {
    submit_chain(&store, "j").await;
    let leased = store.lease("w", &[Stage::Grasp], 1, 1_000, 0).await.unwrap();
    assert!(!store.fail(&fence(&leased[0], "w"), false, "bad params", 1).await.unwrap());
    assert_eq!(state_of(&store, "j/grasp/a").await, TaskState::Failed);
});

store_test!(cancel_stops_leasing_and_fences_running_attempts, |store: Store| async move {
    let tasks = [task("grasp/a", Stage::Grasp, &[]), task("grasp/b", Stage::Grasp, &[])];
    store.submit_job(&job("j"), &tasks, 0).await.unwrap();
    let leased = store.lease("w", &[Stage::Grasp], 1, 10_000, 0).await.unwrap();
    let cancelled = store.cancel_job("j", 1).await.unwrap();
    assert_eq!(cancelled.state, JobState::Cancelled);
    assert!(store.lease("w", &[Stage::Grasp], 10, 10_000, 2).await.unwrap().is_empty());
    let refused = store.complete(&completion(fence(&leased[0], "w"), &[]), &[], 3).await;
    assert!(matches!(refused, Err(StoreError::LeaseLost { .. })), "{refused:?}");
    assert_eq!(store.progress("j").await.unwrap().count(TaskState::Cancelled), 2);
});

store_test!(completion_inserts_planned_children_atomically, |store: Store| async move {
    store.submit_job(&job("j"), &[task("grasp/a", Stage::Grasp, &[])], 0).await.unwrap();
    let leased = store.lease("w", &[Stage::Grasp], 1, 1_000, 0).await.unwrap();
    let children = [task("render/a", Stage::Render, &["grasp/a"]), task("noise/a", Stage::Noise, &["render/a"])];
    store.complete(&completion(fence(&leased[0], "w"), &["grasps.json"]), &children, 1).await.unwrap();
    assert_eq!(state_of(&store, "j/render/a").await, TaskState::Queued);
    assert_eq!(state_of(&store, "j/noise/a").await, TaskState::Waiting);
    assert_eq!(store.job("j").await.unwrap().unwrap().state, JobState::Running);
});

store_test!(job_succeeds_when_every_task_has_and_lineage_reaches_the_root, |store: Store| async move {
    let files = [format!("{SAMPLE}/rgb.png"), format!("{SAMPLE}/meta.json"), "can.trx3.g000000/grasp.json".into()];
    let package_files: Vec<&str> = files.iter().map(String::as_str).collect();
    for (job, at) in [("j", 0), ("newer", 10)] {
        submit_chain_at(&store, job, at).await;
        for (now, outputs) in [(1, vec!["grasps.json"]), (2, vec!["v00_rgb.png"]), (3, package_files.clone())] {
            let now = at + now;
            let leased = store.lease("w", &Stage::ALL, 1, 1_000, now).await.unwrap();
            let mut c = completion(fence(&leased[0], "w"), &outputs);
            if leased[0].stage == Stage::Package {
                c.samples = vec![SAMPLE.into()];
            }
            store.complete(&c, &[], now).await.unwrap();
        }
        assert_eq!(store.job(job).await.unwrap().unwrap().state, JobState::Succeeded);
    }
    let samples = store.samples("j").await.unwrap();
    assert_eq!(samples.keys().collect::<Vec<_>>(), [SAMPLE], "the grasp record is no sample");
    assert_eq!(samples[SAMPLE].iter().map(|a| a.name.as_str()).collect::<Vec<_>>(), ["meta.json", "rgb.png"]);
    let (job, package) = store.sample_package_task(Some("j"), SAMPLE).await.unwrap().unwrap();
    assert_eq!((job.as_str(), package.as_str()), ("j", format!("j/{PACKAGE}").as_str()));
    let newest = Some(("newer".to_string(), format!("newer/{PACKAGE}")));
    assert_eq!(store.sample_package_task(None, SAMPLE).await.unwrap(), newest, "the newest job that packaged it");
    assert_eq!(store.sample_package_task(Some("other"), SAMPLE).await.unwrap(), None);
    assert_eq!(store.sample_package_task(Some("j"), "can.trx3.g000000.v01").await.unwrap(), None, "not packaged");
    assert_eq!(store.sample_package_task(Some("j"), "not a sample id").await.unwrap(), None);
    assert_eq!(store.grasp_records("j").await.unwrap().keys().collect::<Vec<_>>(), ["can.trx3.g000000"]);
    let chain = store.lineage(&package).await.unwrap();
    let keys: Vec<_> = chain.iter().map(|e| e.task.key.as_str()).collect();
    assert_eq!(keys, [PACKAGE, "grasp/a", "render/a"]);
    assert_eq!(chain[0].inputs.len(), 2, "package consumed grasps.json and the render output");
    assert!(chain.iter().all(|e| e.task.engine_json.as_deref() == Some(r#"{"name":"test-double"}"#)));
    let producers = store.producers_of(&artifact("grasps.json").sha256, Some("j"), 10).await.unwrap();
    // The test double's hash is its name's length: the render's v00_rgb.png has it too.
    assert_eq!(producers.iter().map(|a| a.task_id.as_str()).collect::<Vec<_>>(), ["j/grasp/a", "j/render/a"]);
    assert_eq!(store.producers_of(&artifact("grasps.json").sha256, None, 10).await.unwrap().len(), 4, "both jobs'");
    let first = store.producers_of(&artifact("grasps.json").sha256, None, 1).await.unwrap();
    assert_eq!(first.len(), 1, "no more than asked for");
    assert!(store.producers_of(&"f".repeat(64), None, 10).await.unwrap().is_empty());
    let progress = store.progress("j").await.unwrap();
    assert_eq!((progress.total(), progress.count(TaskState::Succeeded), progress.samples), (3, 3, 1));
    assert_eq!(store.artifact_stats("j").await.unwrap(), (5, 4), "5 files, 4 contents (as above)");
});

store_test!(deleting_an_ended_job_removes_its_rows_and_nothing_of_another, |store: Store| async move {
    // Two finished jobs of the same chain, one with a submitted file, and one still running.
    let mut with_asset = job("gone");
    with_asset.assets = vec![vint_store::JobAsset {
        path: "assets/bowl.obj".into(),
        sha256: "ab".repeat(32),
        size: 42,
        media_type: "model/obj".into(),
        object_key: format!("sha256/ab/{}", "ab".repeat(32)),
    }];
    let chain = [
        task("grasp/a", Stage::Grasp, &[]),
        task("render/a", Stage::Render, &["grasp/a"]),
        task(PACKAGE, Stage::Package, &["grasp/a", "render/a"]),
    ];
    // The test double's hash is its name's length: gone.png and kept_image.png differ.
    for (job, at, outputs) in
        [("gone", 0, ["grasps.json", "gone.png"]), ("kept", 10, ["grasps.json", "kept_image.png"])]
    {
        if job == "gone" {
            store.submit_job(&with_asset, &chain, at).await.unwrap();
        } else {
            submit_chain_at(&store, job, at).await;
        }
        for now in at + 1..=at + 3 {
            let leased = store.lease("w", &Stage::ALL, 1, 1_000, now).await.unwrap();
            assert_eq!(leased[0].job_id, job);
            store.complete(&completion(fence(&leased[0], "w"), &outputs), &[], now).await.unwrap();
        }
        assert_eq!(store.job(job).await.unwrap().unwrap().state, JobState::Succeeded, "{job}");
    }
    submit_chain_at(&store, "running", 20).await;
    let keys_before = store.referenced_object_keys().await.unwrap();
    assert!(keys_before.contains(&artifact("gone.png").object_key));

    let dry = store.delete_job("gone", true).await.unwrap();
    assert_eq!(dry, vint_store::DeletedJob { tasks: 3, attempts: 3, outputs: 3, assets: 1 });
    assert!(store.job("gone").await.unwrap().is_some(), "a dry run deletes nothing");
    assert_eq!(store.delete_job("gone", false).await.unwrap(), dry, "the dry run counted what goes");

    assert!(store.job("gone").await.unwrap().is_none());
    assert!(store.tasks_of_job("gone").await.unwrap().is_empty());
    assert!(store.attempts("gone/grasp/a").await.unwrap().is_empty());
    assert!(store.job_assets("gone").await.unwrap().is_empty());
    assert_eq!(store.progress("gone").await.unwrap(), vint_store::Progress::default());
    let keys = store.referenced_object_keys().await.unwrap();
    assert!(!keys.contains(&artifact("gone.png").object_key), "its own objects are no longer referenced");
    assert!(!keys.contains(&format!("sha256/ab/{}", "ab".repeat(32))), "nor its submitted file");
    assert!(keys.contains(&artifact("grasps.json").object_key), "content another job made too stays");
    assert_eq!(store.tasks_of_job("kept").await.unwrap().len(), 3);
    assert_eq!(store.attempts("kept/grasp/a").await.unwrap().len(), 1);

    match store.delete_job("running", false).await {
        Err(StoreError::Invalid(why)) => assert!(why.contains("cancel it first"), "{why}"),
        other => panic!("a running job is not deleted: {other:?}"),
    }
    assert!(matches!(store.delete_job("gone", false).await, Err(StoreError::NotFound(_))));
});

store_test!(a_jobs_assets_are_recorded_and_shown_as_inputs_of_the_tasks_naming_them, |store: Store| async move {
    let sha = "ab".repeat(32);
    let mut j = job("j");
    j.assets = vec![vint_store::JobAsset {
        path: "assets/bowl.obj".into(),
        sha256: sha.clone(),
        size: 42,
        media_type: "model/obj".into(),
        object_key: format!("sha256/ab/{sha}"),
    }];
    let mut grasp = task("grasp/a", Stage::Grasp, &[]);
    grasp.params = json!({"object": {"shape": {"type": "mesh", "asset": sha}}});
    store.submit_job(&j, &[grasp, task("grasp/b", Stage::Grasp, &[])], 0).await.unwrap();
    let assets = store.job_assets("j").await.unwrap();
    assert_eq!(assets, j.assets);
    let chain = store.lineage("j/grasp/a").await.unwrap();
    let inputs: Vec<(&str, &str, &str)> =
        chain[0].inputs.iter().map(|a| (a.name.as_str(), a.sha256.as_str(), a.task_key.as_str())).collect();
    assert_eq!(inputs, [("assets/bowl.obj", sha.as_str(), vint_store::ASSET_TASK_KEY)]);
    assert!(store.lineage("j/grasp/b").await.unwrap()[0].inputs.is_empty(), "b names no asset");
    assert_eq!(store.tasks_naming("j", &sha, 10).await.unwrap(), ["j/grasp/a"]);
    assert!(store.tasks_naming("j", &sha, 0).await.unwrap().is_empty(), "no more than asked for");
    assert!(store.tasks_naming("other", &sha, 10).await.unwrap().is_empty());
    assert!(store.job_assets("other").await.unwrap().is_empty());
    let by_hash = store.user_files_with(&sha, None).await.unwrap();
    assert_eq!(
        by_hash.iter().map(|(job, a)| (job.as_str(), a.path.as_str())).collect::<Vec<_>>(),
        [("j", "assets/bowl.obj")]
    );
    assert!(store.user_files_with(&sha, Some("other")).await.unwrap().is_empty());
    assert!(store.user_files_with(&"0".repeat(64), None).await.unwrap().is_empty());
});

// ---------------------------------------------------------------------------------------------
// Batched completion: one transaction, fenced per task.

/// Three grasp tasks leased by `w` at time 0 (deadline 1,000) and their fences.
async fn three_leased(store: &Store) -> Vec<vint_store::Fence> {
    let tasks =
        [task("grasp/a", Stage::Grasp, &[]), task("grasp/b", Stage::Grasp, &[]), task("grasp/c", Stage::Grasp, &[])];
    store.submit_job(&job("j"), &tasks, 0).await.unwrap();
    let leased = store.lease("w", &[Stage::Grasp], 3, 1_000, 0).await.unwrap();
    assert_eq!(leased.len(), 3);
    leased.iter().map(|t| fence(t, "w")).collect()
}

store_test!(a_lost_lease_in_a_batch_refuses_that_task_alone, |store: Store| async move {
    let fences = three_leased(&store).await;
    let mut stranger = fences[1].clone();
    stranger.worker_id = "x".into();
    let batch = vec![
        (completion(fences[0].clone(), &["grasps.json"]), vec![]),
        (completion(stranger, &["grasps.json"]), vec![]),
        (completion(fences[2].clone(), &["grasps.json", "touch.json"]), vec![]),
    ];
    let results = store.complete_batch(&batch, 10).await.unwrap();
    assert!(results[0].is_ok() && results[2].is_ok(), "{results:?}");
    assert!(matches!(results[1], Err(StoreError::LeaseLost { .. })), "{results:?}");
    assert_eq!(state_of(&store, "j/grasp/a").await, TaskState::Succeeded);
    assert_eq!(state_of(&store, "j/grasp/b").await, TaskState::Running, "the refused task keeps its lease");
    assert_eq!(state_of(&store, "j/grasp/c").await, TaskState::Succeeded);
    assert_eq!(store.artifacts_of_task("j/grasp/a").await.unwrap().len(), 1);
    assert!(store.artifacts_of_task("j/grasp/b").await.unwrap().is_empty(), "no outputs for a refused task");
    assert_eq!(store.artifacts_of_task("j/grasp/c").await.unwrap().len(), 2);
    let outcomes = |id: &'static str| {
        let store = store.clone();
        async move { store.attempts(id).await.unwrap().iter().map(|a| a.outcome).collect::<Vec<_>>() }
    };
    assert_eq!(outcomes("j/grasp/a").await, [Some(AttemptOutcome::Succeeded)]);
    assert_eq!(outcomes("j/grasp/b").await, [None], "still running");
    // The holder of b's lease still completes it, and the job ends.
    store.complete_batch(&[(completion(fences[1].clone(), &[]), vec![])], 20).await.unwrap()[0].as_ref().unwrap();
    assert_eq!(store.job("j").await.unwrap().unwrap().state, JobState::Succeeded);
});

store_test!(outputs_the_store_cannot_pack_refuse_that_completion_alone, |store: Store| async move {
    let fences = three_leased(&store).await;
    let mut moved = completion(fences[2].clone(), &["grasps.json"]);
    moved.outputs[0].object_key = "elsewhere/grasps.json".into();
    let batch = vec![
        (completion(fences[0].clone(), &["grasps.json"]), vec![]),
        (completion(fences[1].clone(), &["grasps.json", "grasps.json"]), vec![]),
        (moved, vec![]),
    ];
    let results = store.complete_batch(&batch, 10).await.unwrap();
    assert!(results[0].is_ok(), "{results:?}");
    for (i, rule) in [(1, "named twice"), (2, "is not its content's")] {
        let Err(StoreError::Invalid(why)) = &results[i] else { panic!("{i}: {results:?}") };
        assert!(why.contains(rule) && why.contains(&fences[i].task_id), "{why}");
    }
    assert_eq!(state_of(&store, "j/grasp/a").await, TaskState::Succeeded);
    for refused in ["j/grasp/b", "j/grasp/c"] {
        assert_eq!(state_of(&store, refused).await, TaskState::Running, "{refused} keeps its lease");
        assert!(store.artifacts_of_task(refused).await.unwrap().is_empty());
    }
});

store_test!(a_reaped_lease_in_a_batch_is_refused_alone, |store: Store| async move {
    let tasks = [task("grasp/a", Stage::Grasp, &[]), task("grasp/b", Stage::Grasp, &[])];
    store.submit_job(&job("j"), &tasks, 0).await.unwrap();
    let early = store.lease("w", &[Stage::Grasp], 1, 1_000, 0).await.unwrap(); // deadline 1,000
    let late = store.lease("w", &[Stage::Grasp], 1, 1_000, 500).await.unwrap(); // deadline 1,500
    assert_eq!(store.reap_expired(1_200, 0).await.unwrap(), 1);
    let batch = vec![
        (completion(fence(&early[0], "w"), &["grasps.json"]), vec![]),
        (completion(fence(&late[0], "w"), &["grasps.json"]), vec![]),
    ];
    let results = store.complete_batch(&batch, 1_200).await.unwrap();
    assert!(matches!(results[0], Err(StoreError::LeaseLost { .. })), "{results:?}");
    assert!(results[1].is_ok(), "{results:?}");
    assert_eq!(state_of(&store, &early[0].id).await, TaskState::Queued);
    assert_eq!(state_of(&store, &late[0].id).await, TaskState::Succeeded);
});

store_test!(a_task_twice_in_one_batch_completes_once, |store: Store| async move {
    let fences = three_leased(&store).await;
    let batch = vec![
        (completion(fences[0].clone(), &["grasps.json"]), vec![]),
        (completion(fences[0].clone(), &["other.json"]), vec![]),
    ];
    let results = store.complete_batch(&batch, 10).await.unwrap();
    assert!(results[0].is_ok());
    assert!(matches!(results[1], Err(StoreError::LeaseLost { .. })), "{results:?}");
    let outputs = store.artifacts_of_task("j/grasp/a").await.unwrap();
    assert_eq!(outputs.iter().map(|a| a.name.as_str()).collect::<Vec<_>>(), ["grasps.json"]);
});

store_test!(a_batch_unlocks_dependents_and_inserts_children_like_single_completions, |store: Store| async move {
    // Two jobs, each a grasp chunk whose completion plans a render task and a package task that
    // waits for the chunk and the render; plus a waiting task that depends on both chunks of job j.
    let j_tasks = [
        task("grasp/a", Stage::Grasp, &[]),
        task("grasp/b", Stage::Grasp, &[]),
        task("package/ab", Stage::Package, &["grasp/a", "grasp/b"]),
    ];
    store.submit_job(&job("j"), &j_tasks, 0).await.unwrap();
    store.submit_job(&job("k"), &[task("grasp/a", Stage::Grasp, &[])], 0).await.unwrap();
    let leased = store.lease("w", &[Stage::Grasp], 10, 1_000, 1).await.unwrap();
    assert_eq!(leased.len(), 3);
    let children = |g: &str| {
        vec![
            task(&format!("render/{g}"), Stage::Render, &[&format!("grasp/{g}")]),
            task(&format!("package/{g}"), Stage::Package, &[&format!("grasp/{g}"), &format!("render/{g}")]),
        ]
    };
    let batch: Vec<_> = leased
        .iter()
        .map(|t| {
            let g = t.key.rsplit('/').next().unwrap().to_string();
            (completion(fence(t, "w"), &["grasps.json"]), children(&g))
        })
        .collect();
    let results = store.complete_batch(&batch, 2).await.unwrap();
    assert!(results.iter().all(|r| r.is_ok()), "{results:?}");
    for (job, g) in [("j", "a"), ("j", "b"), ("k", "a")] {
        assert_eq!(state_of(&store, &format!("{job}/render/{g}")).await, TaskState::Queued, "{job}/render/{g}");
        let package = store.task(&format!("{job}/package/{g}")).await.unwrap().unwrap();
        assert_eq!(package.state, TaskState::Waiting, "{job}/package/{g} waits for its render");
    }
    assert_eq!(state_of(&store, "j/package/ab").await, TaskState::Queued, "both chunks of one batch counted");
    // Renders carry their inputs; completing them in a batch queues their packages with lineage.
    let renders = store.lease("w", &[Stage::Render], 10, 1_000, 3).await.unwrap();
    assert_eq!(renders.len(), 3);
    assert!(renders.iter().all(|r| r.inputs.len() == 1 && r.inputs[0].name == "grasps.json"));
    let batch: Vec<_> = renders.iter().map(|t| (completion(fence(t, "w"), &["v00_rgb.png"]), vec![])).collect();
    assert!(store.complete_batch(&batch, 4).await.unwrap().iter().all(|r| r.is_ok()));
    let packages = store.lease("w", &[Stage::Package], 10, 1_000, 5).await.unwrap();
    assert_eq!(packages.len(), 4);
    for p in packages.iter().filter(|p| p.key != "package/ab") {
        let names: BTreeSet<&str> = p.inputs.iter().map(|a| a.name.as_str()).collect();
        assert_eq!(names, BTreeSet::from(["grasps.json", "v00_rgb.png"]), "{}", p.id);
    }
    let lineage = store.lineage("k/render/a").await.unwrap();
    let inputs: Vec<(&str, &str)> = lineage[0].inputs.iter().map(|a| (a.task_key.as_str(), a.name.as_str())).collect();
    assert_eq!(inputs, [("grasp/a", "grasps.json")], "lineage: the dependency's outputs");
});

store_test!(a_table_a_job_grew_is_analyzed_once_until_it_grows_again, |store: Store| async move {
    let tasks: Vec<NewTask> = (0..3_000).map(|i| task(&format!("grasp/t{i:05}"), Stage::Grasp, &[])).collect();
    store.submit_job(&job("j"), &tasks, 0).await.unwrap();
    if store.backend() != vint_store::Backend::Postgres {
        assert!(store.refresh_statistics().await.unwrap().is_empty(), "SQLite keeps no planner statistics here");
        return;
    }
    // Postgres publishes a transaction's row counts to pg_stat_user_tables within a second or so.
    let mut analyzed = Vec::new();
    for _ in 0..50 {
        analyzed = store.refresh_statistics().await.unwrap();
        if analyzed.iter().any(|t| t == "tasks") {
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }
    assert!(analyzed.iter().any(|t| t == "tasks"), "3,000 new tasks leave the statistics stale: {analyzed:?}");
    assert!(!store.refresh_statistics().await.unwrap().iter().any(|t| t == "tasks"), "analyzed already");
});

store_test!(a_heartbeat_and_a_completion_of_the_same_tasks_never_deadlock, |store: Store| async move {
    // A worker's heartbeat names the leases it holds while its completion of them is in flight,
    // and a batch's completions unblock dependents other batches unblock too. A heartbeat skips
    // rows a completion holds and completions lock dependents in id order; otherwise, listing
    // rows in opposite orders, they would wait on each other (a deadlock).
    // A table of some size, analyzed, so that Postgres joins a batch to it row by row in the
    // batch's order (as on a real job) rather than scanning a small table whole.
    let filler: Vec<NewTask> = (0..5_000).map(|i| task(&format!("grasp/f{i:05}"), Stage::Grasp, &[])).collect();
    store.submit_job(&job("filler"), &filler, 0).await.unwrap();
    for _ in 0..50 {
        if store.refresh_statistics().await.unwrap().iter().any(|t| t == "tasks") {
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }
    for round in 0..10 {
        let job_id = format!("j{round}");
        let mut tasks: Vec<NewTask> = (0..256).map(|i| task(&format!("render/r{i:03}"), Stage::Render, &[])).collect();
        let deps: Vec<String> = (0..256).map(|i| format!("render/r{i:03}")).collect();
        let deps: Vec<&str> = deps.iter().map(String::as_str).collect();
        tasks.push(task("package/p1", Stage::Package, &deps));
        tasks.push(task("package/p2", Stage::Package, &deps));
        store.submit_job(&job(&job_id), &tasks, 0).await.unwrap();
        let leased = store.lease("w", &[Stage::Render], 256, 60_000, 1).await.unwrap();
        assert_eq!(leased.len(), 256);
        let held: Vec<(String, u32)> = leased.iter().rev().map(|t| (t.id.clone(), t.attempt)).collect();
        let (first, second) = leased.split_at(128);
        let batch = |ts: &[vint_store::LeasedTask], rev: bool| {
            let mut items: Vec<_> =
                ts.iter().map(|t| (completion(fence(t, "w"), &["v00_rgb.png"]), Vec::new())).collect();
            if rev {
                items.reverse();
            }
            items
        };
        let (a, b) = (batch(first, false), batch(second, true));
        let (s1, s2, s3) = (store.clone(), store.clone(), store.clone());
        let (r1, r2, r3) = tokio::join!(
            async move { s1.complete_batch(&a, 2).await },
            async move { s2.complete_batch(&b, 2).await },
            async move { s3.heartbeat("w", &held, 60_000, 2).await.map(|b| b.lost) },
        );
        for r in [r1.unwrap(), r2.unwrap()] {
            assert!(r.iter().all(Result::is_ok), "round {round}: {r:?}");
        }
        assert!(r3.is_ok(), "round {round}: {r3:?}");
        assert_eq!(state_of(&store, &format!("{job_id}/package/p1")).await, TaskState::Queued);
        assert_eq!(state_of(&store, &format!("{job_id}/package/p2")).await, TaskState::Queued);
    }
});

store_test!(progress_of_a_page_of_jobs_is_each_job_s_own, |store: Store| async move {
    submit_chain(&store, "j1").await;
    submit_chain(&store, "j2").await;
    assert_eq!(store.lease("w", &[Stage::Grasp], 1, 1_000, 1).await.unwrap().len(), 1);
    let all = store.progress_of(&["j1", "j2", "none"]).await.unwrap();
    assert_eq!(all.keys().collect::<BTreeSet<_>>(), BTreeSet::from([&"j1".to_string(), &"j2".to_string()]));
    for id in ["j1", "j2"] {
        assert_eq!(all[id], store.progress(id).await.unwrap(), "{id}");
        assert_eq!(all[id].total(), 3, "{id}");
    }
    assert_eq!(all["j1"].count(TaskState::Running) + all["j2"].count(TaskState::Running), 1);
    assert!(store.progress_of(&[]).await.unwrap().is_empty());
});

store_test!(queue_depth_counts_live_tasks_by_stage_and_state_and_jobs_by_state, |store: Store| async move {
    use vint_store::QueueDepth;
    assert_eq!(store.queue_depth().await.unwrap(), QueueDepth::default());
    submit_chain(&store, "j1").await;
    submit_chain(&store, "j2").await;
    store.cancel_job("j2", 1).await.unwrap();
    let leased = store.lease("w", &[Stage::Grasp], 10, 1_000, 2).await.unwrap();
    let depth = store.queue_depth().await.unwrap();
    // Only j1's tasks are live: j2's are cancelled, and cancelled work is history.
    assert_eq!(depth.tasks_in(Stage::Grasp, TaskState::Running), 1, "{depth:?}");
    assert_eq!(depth.tasks_in(Stage::Render, TaskState::Waiting), 1, "{depth:?}");
    assert_eq!(depth.tasks_in(Stage::Package, TaskState::Waiting), 1, "{depth:?}");
    assert_eq!(depth.tasks.iter().map(|(_, _, n)| n).sum::<u64>(), 3, "{depth:?}");
    assert_eq!((depth.jobs_in(JobState::Running), depth.jobs_in(JobState::Cancelled)), (1, 1));

    store.complete(&completion(fence(&leased[0], "w"), &["grasps.json"]), &[], 3).await.unwrap();
    let depth = store.queue_depth().await.unwrap();
    assert_eq!(depth.tasks_in(Stage::Render, TaskState::Queued), 1, "{depth:?}");
    assert_eq!(depth.tasks_in(Stage::Package, TaskState::Waiting), 1, "{depth:?}");
    assert_eq!(depth.tasks_in(Stage::Grasp, TaskState::Succeeded), 0, "succeeded tasks are not counted");
    assert_eq!(depth.tasks.iter().map(|(_, _, n)| n).sum::<u64>(), 2, "{depth:?}");
    store.ping().await.unwrap();
});
