//! States as types, end to end: the database accepts exactly the states, stages and attempt
//! outcomes `vint_core` defines, and every change the store makes to a task is a transition
//! `TaskState::can_transition` allows — with every allowed transition actually made, against
//! Postgres and SQLite alike.

#[macro_use]
mod common;

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use common::*;
use sqlx::Connection;
use vint_core::TaskState::{Cancelled, Failed, Queued, Running, Succeeded, Waiting};
use vint_core::{AttemptOutcome, JobState, Stage, TaskState};
use vint_store::{Fence, Store, StoreError, TaskRecord};

// ---------------------------------------------------------------------------------------------
// The migrations name exactly the enums' values.

/// Each check of migration 0004 (and any later one that redefines it), with the names it admits.
fn checks() -> [(&'static str, Vec<&'static str>); 4] {
    [
        ("jobs_state_known", JobState::ALL.iter().map(|s| s.as_str()).collect()),
        ("tasks_state_known", TaskState::ALL.iter().map(|s| s.as_str()).collect()),
        ("tasks_stage_known", Stage::ALL.iter().map(|s| s.as_str()).collect()),
        ("attempts_outcome_known", AttemptOutcome::ALL.iter().map(|o| o.as_str()).collect()),
    ]
}

fn migrations(backend: &str) -> Vec<(PathBuf, String)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("migrations").join(backend);
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().path()).collect();
    files.sort();
    files.into_iter().map(|f| (f.clone(), std::fs::read_to_string(f).unwrap())).collect()
}

/// The quoted names in the first `IN (…)` after each occurrence of `anchor` in `sql`.
fn in_lists_after(sql: &str, anchor: &str) -> Vec<BTreeSet<String>> {
    sql.match_indices(anchor)
        .map(|(at, _)| {
            let rest = &sql[at..];
            let open = rest.find("IN (").unwrap_or_else(|| panic!("no IN list after {anchor}")) + "IN (".len();
            let close = open + rest[open..].find(')').unwrap();
            rest[open..close].split(',').map(|name| name.trim().trim_matches('\'').to_string()).collect()
        })
        .collect()
}

#[test]
fn every_state_check_in_the_migrations_names_exactly_the_enums_values() {
    // Postgres: `ADD CONSTRAINT <check> CHECK (… IN (…))`; SQLite: one trigger per check and event.
    let anchors = |check: &str| {
        [
            ("postgres", vec![format!("CONSTRAINT {check}")]),
            ("sqlite", vec![format!("TRIGGER {check}_on_insert"), format!("TRIGGER {check}_on_update")]),
        ]
    };
    for (check, names) in checks() {
        let expected: BTreeSet<String> = names.iter().map(|n| n.to_string()).collect();
        for (backend, anchors) in anchors(check) {
            let files = migrations(backend);
            for anchor in anchors {
                // The newest migration that mentions the check defines it.
                let (file, sql) = files
                    .iter()
                    .rev()
                    .find(|(_, sql)| sql.contains(&anchor))
                    .unwrap_or_else(|| panic!("{backend}: no migration defines {anchor}"));
                let lists = in_lists_after(sql, &anchor);
                assert!(!lists.is_empty());
                for list in lists {
                    assert_eq!(list, expected, "{}: {anchor} disagrees with vint_core", file.display());
                }
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// The database refuses any other name.

database_test!(
    the_database_refuses_a_state_stage_or_outcome_the_enums_do_not_define,
    |store: Store, url: String| async move {
        store.submit_job(&job("j"), &[task("grasp/a", Stage::Grasp, &[])], 0).await.unwrap();
        store.lease("w", &[Stage::Grasp], 1, 1_000, 0).await.unwrap();
        // An attempt's row is written when it ends: end this one (requeued for a retry).
        let fence = Fence { task_id: "j/grasp/a".into(), worker_id: "w".into(), attempt: 1 };
        assert!(store.fail(&fence, true, "try again", 1).await.unwrap());
        let mut conn = sqlx::AnyConnection::connect(&url).await.unwrap();
        // (check, statement setting one value on an existing row, every name the enum defines, a stranger)
        let updates = [
            ("jobs_state_known", "UPDATE jobs SET state = $1 WHERE id = 'j'", "finished"),
            ("tasks_state_known", "UPDATE tasks SET state = $1 WHERE id = 'j/grasp/a'", "done"),
            ("tasks_stage_known", "UPDATE tasks SET stage = $1 WHERE id = 'j/grasp/a'", "paint"),
            ("attempts_outcome_known", "UPDATE attempts SET outcome = $1 WHERE task_id = 'j/grasp/a'", "timeout"),
        ];
        let known: BTreeMap<&str, Vec<&str>> = checks().into_iter().collect();
        for (check, update, stranger) in updates {
            for name in &known[check] {
                let changed = sqlx::query(update).bind(*name).execute(&mut conn).await.unwrap().rows_affected();
                assert_eq!(changed, 1, "{update} with {name:?}");
            }
            let err = sqlx::query(update).bind(stranger).execute(&mut conn).await.unwrap_err();
            assert!(err.to_string().contains(check), "{update} with {stranger:?}: {err}");
        }
        let running = sqlx::query("UPDATE attempts SET outcome = NULL WHERE task_id = 'j/grasp/a'");
        running.execute(&mut conn).await.expect("no outcome is not a stranger outcome");

        let inserts = [
            (
                "jobs_state_known",
                "INSERT INTO jobs (id, name, seed, spec_toml, idempotency_key, state, created_ms) \
             VALUES ('k', 'k', 1, '', 'key-k', 'finished', 0)",
            ),
            (
                "tasks_state_known",
                "INSERT INTO tasks (id, job_id, key, stage, priority, params_json, state, deps_pending, max_attempts, \
             created_ms, updated_ms) VALUES ('j/x', 'j', 'x', 'grasp', 0, '{}', 'done', 0, 1, 0, 0)",
            ),
            (
                "tasks_stage_known",
                "INSERT INTO tasks (id, job_id, key, stage, priority, params_json, state, deps_pending, max_attempts, \
             created_ms, updated_ms) VALUES ('j/x', 'j', 'x', 'paint', 0, '{}', 'queued', 0, 1, 0, 0)",
            ),
            (
                "attempts_outcome_known",
                "INSERT INTO attempts (task_id, attempt, worker_id, started_ms, ended_ms, outcome) \
             VALUES ('j/grasp/a', 9, 'w', 0, 1, 'timeout')",
            ),
        ];
        for (check, insert) in inserts {
            let err = sqlx::query(insert).execute(&mut conn).await.unwrap_err();
            assert!(err.to_string().contains(check), "{insert}: {err}");
        }
        conn.close().await.unwrap();
    }
);

// ---------------------------------------------------------------------------------------------
// Every transition the store makes is one the state machine allows, and it makes them all.

/// Everything a store operation changed, sorted by id.
#[derive(Debug, Default, PartialEq)]
struct Changes {
    /// Existing tasks whose state changed: (task id, from, to).
    moved: Vec<(String, TaskState, TaskState)>,
    /// Tasks the operation inserted, and the state they start in.
    appeared: Vec<(String, TaskState)>,
    /// Attempts that ended: (task id, outcome).
    ended: Vec<(String, AttemptOutcome)>,
    /// Jobs whose state changed: (job id, from, to).
    jobs: Vec<(String, JobState, JobState)>,
}

fn moved(list: &[(&str, TaskState, TaskState)]) -> Vec<(String, TaskState, TaskState)> {
    list.iter().map(|(id, from, to)| (id.to_string(), *from, *to)).collect()
}

fn appeared(list: &[(&str, TaskState)]) -> Vec<(String, TaskState)> {
    list.iter().map(|(id, state)| (id.to_string(), *state)).collect()
}

fn ended(list: &[(&str, AttemptOutcome)]) -> Vec<(String, AttemptOutcome)> {
    list.iter().map(|(id, outcome)| (id.to_string(), *outcome)).collect()
}

/// Every job, task and attempt in the store at one moment.
struct Snapshot {
    jobs: BTreeMap<String, JobState>,
    tasks: BTreeMap<String, TaskRecord>,
    /// (task id, attempt) → outcome.
    attempts: BTreeMap<(String, u32), Option<AttemptOutcome>>,
}

impl Snapshot {
    async fn take(store: &Store) -> Snapshot {
        let mut snapshot = Snapshot { jobs: BTreeMap::new(), tasks: BTreeMap::new(), attempts: BTreeMap::new() };
        for job in store.list_jobs(1_000).await.unwrap() {
            for task in store.tasks_of_job(&job.id).await.unwrap() {
                for a in store.attempts(&task.id).await.unwrap() {
                    snapshot.attempts.insert((a.task_id, a.attempt), a.outcome);
                }
                snapshot.tasks.insert(task.id.clone(), task);
            }
            snapshot.jobs.insert(job.id, job.state);
        }
        snapshot
    }
}

/// Watches the store through a sequence of operations: after each, checks every change against
/// the state machines and remembers which transitions and outcomes it has seen.
struct StateWatch {
    last: Snapshot,
    transitions: BTreeSet<(TaskState, TaskState)>,
    outcomes: BTreeSet<(AttemptOutcome, TaskState)>,
}

impl StateWatch {
    async fn start(store: &Store) -> StateWatch {
        StateWatch { last: Snapshot::take(store).await, transitions: BTreeSet::new(), outcomes: BTreeSet::new() }
    }

    /// What `operation` (just run) changed, after checking that every change is a legal one.
    async fn after(&mut self, operation: &str, store: &Store) -> Changes {
        let now = Snapshot::take(store).await;
        let before = std::mem::replace(&mut self.last, now);
        let now = &self.last;
        let mut changes = Changes::default();
        for id in before.tasks.keys() {
            assert!(now.tasks.contains_key(id), "{operation}: task {id} disappeared");
        }
        for (id, task) in &now.tasks {
            let Some(old) = before.tasks.get(id) else {
                assert!(
                    matches!(task.state, Waiting | Queued),
                    "{operation}: {id} was inserted {}, not waiting or queued",
                    task.state
                );
                assert_eq!(task.attempt, 0, "{operation}: {id} was inserted with attempts");
                changes.appeared.push((id.clone(), task.state));
                continue;
            };
            let (from, to) = (old.state, task.state);
            if from != to {
                assert!(
                    from.can_transition(to),
                    "{operation}: {id} went {from} -> {to}, which the state machine forbids"
                );
                self.transitions.insert((from, to));
                changes.moved.push((id.clone(), from, to));
            }
            // A lease starts exactly one attempt; nothing else does.
            let started = if to == Running && from != Running { 1 } else { 0 };
            assert_eq!(task.attempt, old.attempt + started, "{operation}: {id} attempt counter ({from} -> {to})");
            if started == 1 {
                let key = (id.clone(), task.attempt);
                assert!(!before.attempts.contains_key(&key), "{operation}: {id} reused attempt {}", task.attempt);
                assert_eq!(now.attempts.get(&key), Some(&None), "{operation}: {id}'s new attempt must be running");
            }
            // Leaving running ends the running attempt, with an outcome that names where the task went.
            if from == Running && to != Running {
                let outcome = now.attempts.get(&(id.clone(), old.attempt)).copied().flatten();
                let outcome =
                    outcome.unwrap_or_else(|| panic!("{operation}: {id} left running, its attempt did not end"));
                assert!(
                    outcome.leaves_task_in().contains(&to),
                    "{operation}: {id} attempt {} ended {outcome} but the task went {from} -> {to}",
                    old.attempt
                );
                self.outcomes.insert((outcome, to));
            }
        }
        for (key @ (id, attempt), outcome) in &now.attempts {
            match (before.attempts.get(key), outcome) {
                (Some(old), new) if old == new => {}
                (Some(None), Some(outcome)) => {
                    let left_running = changes.moved.iter().any(|(task, from, _)| task == id && *from == Running);
                    assert!(
                        left_running,
                        "{operation}: {id} attempt {attempt} ended {outcome}, but the task did not leave running"
                    );
                    changes.ended.push((id.clone(), *outcome));
                }
                (None, None) => {
                    let leased = changes.moved.iter().any(|(task, _, to)| task == id && *to == Running);
                    assert!(leased, "{operation}: {id} attempt {attempt} started without a lease");
                }
                (old, new) => panic!("{operation}: {id} attempt {attempt} outcome went {old:?} -> {new:?}"),
            }
        }
        for (id, state) in &now.jobs {
            match before.jobs.get(id) {
                Some(old) if old != state => {
                    assert_eq!(*old, JobState::Running, "{operation}: job {id} left terminal state {old} for {state}");
                    changes.jobs.push((id.clone(), *old, *state));
                }
                Some(_) => {}
                None => assert_eq!(*state, JobState::Running, "{operation}: job {id} was created {state}"),
            }
        }
        changes
    }

    /// The operations run so far made every transition the state machine allows, and ended
    /// attempts with every outcome for every state it can leave a task in.
    fn assert_saw_the_whole_machine(&self) {
        let allowed: BTreeSet<(TaskState, TaskState)> = TaskState::ALL
            .into_iter()
            .flat_map(|from| TaskState::ALL.into_iter().map(move |to| (from, to)))
            .filter(|(from, to)| from.can_transition(*to))
            .collect();
        let missing: Vec<_> = allowed.difference(&self.transitions).collect();
        assert!(missing.is_empty(), "transitions the store was never seen to make: {missing:?}");
        let outcomes: BTreeSet<(AttemptOutcome, TaskState)> =
            AttemptOutcome::ALL.into_iter().flat_map(|o| o.leaves_task_in().iter().map(move |to| (o, *to))).collect();
        let missing: Vec<_> = outcomes.difference(&self.outcomes).collect();
        assert!(missing.is_empty(), "attempt outcomes never seen: {missing:?}");
    }
}

store_test!(
    every_transition_the_store_makes_is_one_the_state_machine_allows_and_it_makes_them_all,
    |store: Store| async move {
        use AttemptOutcome as O;
        let mut watch = StateWatch::start(&store).await;

        // Submit: tasks without dependencies start queued, the others wait.
        let tasks = [
            task("grasp/a", Stage::Grasp, &[]),
            task("grasp/b", Stage::Grasp, &[]),
            task("render/a", Stage::Render, &["grasp/a"]),
            task("noise/a", Stage::Noise, &["render/a"]),
            task("package/a", Stage::Package, &["grasp/a", "noise/a"]),
        ];
        store.submit_job(&job("j"), &tasks, 0).await.unwrap();
        let c = watch.after("submit", &store).await;
        let inserted = [
            ("j/grasp/a", Queued),
            ("j/grasp/b", Queued),
            ("j/noise/a", Waiting),
            ("j/package/a", Waiting),
            ("j/render/a", Waiting),
        ];
        assert_eq!(c, Changes { appeared: appeared(&inserted), ..Changes::default() });

        let grasp_a = store.lease("w1", &[Stage::Grasp], 1, 1_000, 1).await.unwrap().remove(0);
        let c = watch.after("lease", &store).await;
        assert_eq!(c, Changes { moved: moved(&[("j/grasp/a", Queued, Running)]), ..Changes::default() });

        let lost =
            store.heartbeat("w1", &[(grasp_a.id.clone(), grasp_a.attempt)], 1_000, 2).await.map(|b| b.lost).unwrap();
        assert!(lost.is_empty());
        assert_eq!(watch.after("heartbeat", &store).await, Changes::default());

        // Complete: the task succeeds, its dependent is queued, and the children it unlocked are
        // inserted queued (their one dependency has succeeded) or waiting.
        let children = [
            task("render/c", Stage::Render, &["grasp/a"]),
            task("render/d", Stage::Render, &["grasp/a"]),
            task("noise/c", Stage::Noise, &["render/c"]),
        ];
        store.complete(&completion(fence(&grasp_a, "w1"), &["grasps.json"]), &children, 3).await.unwrap();
        let c = watch.after("complete", &store).await;
        let expected = Changes {
            moved: moved(&[("j/grasp/a", Running, Succeeded), ("j/render/a", Waiting, Queued)]),
            appeared: appeared(&[("j/noise/c", Waiting), ("j/render/c", Queued), ("j/render/d", Queued)]),
            ended: ended(&[("j/grasp/a", O::Succeeded)]),
            jobs: vec![],
        };
        assert_eq!(c, expected);

        // A retryable failure with attempts left requeues the task.
        let render_a = store.lease("w1", &[Stage::Render], 1, 1_000, 4).await.unwrap().remove(0);
        assert_eq!(render_a.key, "render/a");
        watch.after("lease", &store).await;
        assert!(store.fail(&fence(&render_a, "w1"), true, "transient", 5).await.unwrap());
        let c = watch.after("retryable failure", &store).await;
        let expected = Changes {
            moved: moved(&[("j/render/a", Running, Queued)]),
            ended: ended(&[("j/render/a", O::Retry)]),
            ..Changes::default()
        };
        assert_eq!(c, expected);

        // A permanent failure fails the task and, transitively, everything waiting on it.
        let render_a = store.lease("w1", &[Stage::Render], 1, 1_000, 105).await.unwrap().remove(0);
        assert_eq!((render_a.key.as_str(), render_a.attempt), ("render/a", 2));
        watch.after("lease after backoff", &store).await;
        assert!(!store.fail(&fence(&render_a, "w1"), false, "bad params", 106).await.unwrap());
        let c = watch.after("permanent failure", &store).await;
        let expected = Changes {
            moved: moved(&[
                ("j/noise/a", Waiting, Failed),
                ("j/package/a", Waiting, Failed),
                ("j/render/a", Running, Failed),
            ]),
            ended: ended(&[("j/render/a", O::Failed)]),
            ..Changes::default()
        };
        assert_eq!(c, expected);

        // A worker whose task has failed changes nothing.
        let late = store.complete(&completion(fence(&render_a, "w1"), &[]), &[], 107).await.unwrap_err();
        assert!(matches!(late, StoreError::LeaseLost { .. }), "{late}");
        assert_eq!(watch.after("late completion", &store).await, Changes::default());

        // Lease expiry with attempts left requeues; on the last attempt it fails the task.
        let grasp_b = store.lease("w2", &[Stage::Grasp], 1, 1_000, 107).await.unwrap().remove(0);
        watch.after("lease", &store).await;
        assert_eq!(store.reap_expired(1_107, 0).await.unwrap(), 0, "the deadline itself is still held");
        assert_eq!(store.reap_expired(1_108, 0).await.unwrap(), 1);
        let c = watch.after("reap with attempts left", &store).await;
        let expected = Changes {
            moved: moved(&[("j/grasp/b", Running, Queued)]),
            ended: ended(&[("j/grasp/b", O::LeaseExpired)]),
            ..Changes::default()
        };
        assert_eq!(c, expected);
        let grasp_b2 = store.lease("w2", &[Stage::Grasp], 1, 1_000, 1_208).await.unwrap().remove(0);
        assert_eq!((grasp_b2.id.as_str(), grasp_b2.attempt), (grasp_b.id.as_str(), 2));
        watch.after("lease after backoff", &store).await;
        assert!(store.fail(&fence(&grasp_b2, "w2"), true, "transient", 1_209).await.unwrap());
        watch.after("retryable failure", &store).await;
        let grasp_b3 = store.lease("w2", &[Stage::Grasp], 1, 1_000, 1_409).await.unwrap().remove(0);
        assert_eq!(grasp_b3.attempt, RETRY.max_attempts);
        watch.after("lease of the last attempt", &store).await;
        assert_eq!(store.reap_expired(2_410, 0).await.unwrap(), 1);
        let c = watch.after("reap of the last attempt", &store).await;
        let expected = Changes {
            moved: moved(&[("j/grasp/b", Running, Failed)]),
            ended: ended(&[("j/grasp/b", O::LeaseExpired)]),
            ..Changes::default()
        };
        assert_eq!(c, expected);

        // A release (its worker shutting down) queues the task again at once.
        let render_c = store.lease("w3", &[Stage::Render], 1, 1_000, 2_411).await.unwrap().remove(0);
        assert_eq!(render_c.key, "render/c");
        watch.after("lease", &store).await;
        let released = store.release("w3", &[(render_c.id.clone(), render_c.attempt)], 2_411).await.unwrap();
        assert_eq!(released, [(render_c.id.clone(), 1)]);
        let c = watch.after("release", &store).await;
        let expected = Changes {
            moved: moved(&[("j/render/c", Running, Queued)]),
            ended: ended(&[("j/render/c", O::Released)]),
            ..Changes::default()
        };
        assert_eq!(c, expected);

        // Cancel: every unfinished task is cancelled, whatever its state, and the running attempt ends.
        let render_c = store.lease("w3", &[Stage::Render], 1, 1_000, 2_411).await.unwrap().remove(0);
        assert_eq!((render_c.key.as_str(), render_c.attempt), ("render/c", 2), "leased again without a backoff");
        watch.after("lease after a release", &store).await;
        store.cancel_job("j", 2_412).await.unwrap();
        let c = watch.after("cancel", &store).await;
        let expected = Changes {
            moved: moved(&[
                ("j/noise/c", Waiting, Cancelled),
                ("j/render/c", Running, Cancelled),
                ("j/render/d", Queued, Cancelled),
            ]),
            ended: ended(&[("j/render/c", O::Cancelled)]),
            jobs: vec![("j".into(), JobState::Running, JobState::Cancelled)],
            ..Changes::default()
        };
        assert_eq!(c, expected);

        watch.assert_saw_the_whole_machine();
    }
);
