//! The cluster path: Postgres, a standalone coordinator, separate worker processes — and the
//! faults it must survive: a worker SIGKILLed mid-task, a worker SIGTERMed mid-task (a rollout),
//! a coordinator restarted mid-job, a coordinator down for longer than a lease while a task runs
//! for more than 90 s, a worker whose lease was reaped trying to complete.

use std::collections::BTreeSet;
use std::path::Path;
use std::sync::OnceLock;
use std::time::Duration;

use vint_core::{AttemptOutcome, Stage};
use vint_proto::v1 as pb;
use vint_proto::v1::work_service_client::WorkServiceClient;
use vint_store::{RetryPolicy, Store};
use vint_tests::*;

/// tiny.toml's dataset on the embedded default: what every cluster run must equal.
struct Reference {
    manifest: String,
    manifest_sha256: String,
    samples: usize,
}

fn reference() -> &'static Reference {
    static REFERENCE: OnceLock<Reference> = OnceLock::new();
    REFERENCE.get_or_init(|| {
        let tmp = tempfile::tempdir().unwrap();
        let o = run_tiny(tmp.path(), 1);
        assert!(o.status.success(), "reference run failed: {}", stderr(&o));
        let out = tmp.path().join("out");
        let samples = verify_dataset(&out).len();
        assert!(samples > 0, "the reference run packaged no samples");
        Reference {
            manifest: std::fs::read_to_string(out.join("manifest.jsonl")).unwrap(),
            manifest_sha256: manifest_sha256(&out),
            samples,
        }
    })
}

struct Cluster {
    database: String,
    /// Environment for workers and vintctl (S3 credentials and endpoint when storing in S3).
    env: Vec<(String, String)>,
    store_url: String,
    coordinator: String,
    port: u16,
    dir: tempfile::TempDir,
}

impl Cluster {
    async fn new(tag: &str) -> Cluster {
        let dir = tempfile::tempdir().unwrap();
        let store_url = format!("file://{}", dir.path().join("objects").display());
        let port = free_port();
        Cluster {
            env: Vec::new(),
            database: postgres_database(tag).await,
            store_url,
            coordinator: format!("http://127.0.0.1:{port}"),
            port,
            dir,
        }
    }
    fn logs(&self) -> std::path::PathBuf {
        self.dir.path().join("logs")
    }
    fn coordinator_proc(&self, name: &str) -> Proc {
        start_coordinator(&self.database, self.port, &self.logs(), name)
    }
    fn worker(&self, id: &str) -> Proc {
        start_worker(&self.coordinator, &self.store_url, id, &self.logs(), &self.dir.path().join("scratch"), &self.env)
    }
    fn submit(&self) -> String {
        let o = vintctl(&["submit", tiny_spec().to_str().unwrap(), "--coordinator", &self.coordinator]);
        assert!(o.status.success(), "submit: {}", stderr(&o));
        stdout(&o).trim().to_string()
    }
    fn watch(&self, job: &str) {
        let o = vintctl(&["watch", job, "--coordinator", &self.coordinator, "--json"]);
        assert!(o.status.success(), "job did not succeed: {}\n{}", stdout(&o), stderr(&o));
    }
    fn export(&self, job: &str) -> std::path::PathBuf {
        let out = self.dir.path().join("dataset");
        let o = vintctl_with_env(
            &[
                "export",
                job,
                "--out",
                out.to_str().unwrap(),
                "--store",
                &self.store_url,
                "--coordinator",
                &self.coordinator,
            ],
            &self.env,
        );
        assert!(o.status.success(), "export: {}", stderr(&o));
        verify_dataset(&out);
        out
    }
    async fn store(&self) -> Store {
        Store::open(&self.database, RetryPolicy::default()).await.unwrap()
    }
}

/// The exported dataset is the embedded run's, byte for byte: same manifest hash, as many samples.
fn assert_same_as_embedded(out: &Path) {
    let reference = reference();
    assert_eq!(verify_dataset(out).len(), reference.samples, "the cluster packaged a different number of samples");
    let ours = std::fs::read_to_string(out.join("manifest.jsonl")).unwrap();
    if manifest_sha256(out) != reference.manifest_sha256 {
        let (ours, theirs): (BTreeSet<&str>, BTreeSet<&str>) =
            (ours.lines().collect(), reference.manifest.lines().collect());
        let differing: Vec<&str> = ours.symmetric_difference(&theirs).copied().collect();
        panic!("cluster manifest differs from the embedded run's in these lines:\n{}", differing.join("\n"));
    }
}

#[tokio::test(flavor = "multi_thread")]
async fn postgres_cluster_matches_embedded_and_lineage_shows_the_full_chain() {
    let c = Cluster::new("cluster").await;
    let _coordinator = c.coordinator_proc("coordinator");
    let job = c.submit();
    let resubmit = c.submit();
    assert_eq!(job, resubmit, "a retried submit returns the same job");
    let _w1 = c.worker("w1");
    let _w2 = c.worker("w2");
    c.watch(&job);
    let out = c.export(&job);
    assert_same_as_embedded(&out);

    let manifest = std::fs::read_to_string(out.join("manifest.jsonl")).unwrap();
    let first: serde_json::Value = manifest
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .find(|l| l["sample_id"].is_string())
        .expect("a sample line");
    let sample = first["sample_id"].as_str().unwrap();
    let o = vintctl(&["lineage", sample, "--job", &job, "--coordinator", &c.coordinator, "--json"]);
    assert!(o.status.success(), "lineage: {}", stderr(&o));
    let lineage: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let tasks = lineage["tasks"].as_array().unwrap();
    let stages: Vec<&str> = tasks.iter().map(|t| t["stage"].as_str().unwrap()).collect();
    assert_eq!(stages, ["package", "noise", "render", "grasp"], "{lineage:#}");
    for t in tasks {
        assert_eq!(t["state"], "succeeded");
        assert!(t["engine"]["name"].as_str().unwrap().starts_with("vint-"), "engine recorded: {t:#}");
        assert!(!t["outputs"].as_array().unwrap().is_empty());
        assert!(t["params"].is_object());
    }
    let engine_libs = |stage: &str| tasks.iter().find(|t| t["stage"] == stage).unwrap()["engine"]["libs"].clone();
    assert!(engine_libs("grasp")["mujoco"].is_string());
    assert!(engine_libs("render")["bpy"].is_string());
    // The sample's packaged files are the very artifacts its render and noise tasks made.
    let package = &tasks[0];
    let files = &first["files"];
    for out in package["outputs"].as_array().unwrap() {
        let file = out["name"].as_str().unwrap().rsplit('/').next().unwrap();
        assert_eq!(out["sha256"], files[file]["sha256"], "{file}");
    }
    let render_outputs: Vec<&str> =
        tasks[2]["outputs"].as_array().unwrap().iter().map(|a| a["sha256"].as_str().unwrap()).collect();
    assert!(render_outputs.contains(&files["rgb.png"]["sha256"].as_str().unwrap()));

    // Lineage by artifact hash leads to the same render task.
    let rgb = files["rgb.png"]["sha256"].as_str().unwrap();
    let o = vintctl(&["lineage", rgb, "--artifact", "--coordinator", &c.coordinator, "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let by_hash: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(by_hash["tasks"][0]["stage"], "render");

    let status = vintctl(&["status", &job, "--coordinator", &c.coordinator, "--json"]);
    let status: serde_json::Value = serde_json::from_str(&stdout(&status)).unwrap();
    assert_eq!(status["state"], "succeeded");

    let unknown = vintctl(&["status", "jnope", "--coordinator", &c.coordinator]);
    assert_eq!(unknown.status.code(), Some(2));

    // The same spec once more, as a new job: the forecast over the cluster's database says every
    // task will be reused, and none runs; lineage names the task each one took its result from.
    let spec = tiny_spec();
    let o = vintctl(&["--json", "plan", spec.to_str().unwrap(), "--against", &job, "--database", &c.database]);
    assert!(o.status.success(), "plan --against: {}", stderr(&o));
    let forecast: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    for (stage, f) in forecast["stages"].as_object().unwrap() {
        assert!(f["planned"].as_u64().unwrap() > 0 && f["run"] == 0, "{stage}: {forecast:#}");
    }
    let o = vintctl(&["submit", spec.to_str().unwrap(), "--idempotency-key", "again", "--coordinator", &c.coordinator]);
    assert!(o.status.success(), "submit: {}", stderr(&o));
    let again = stdout(&o).trim().to_string();
    assert_ne!(again, job);
    c.watch(&again);
    let status = vintctl(&["status", &again, "--coordinator", &c.coordinator, "--json"]);
    let status: serde_json::Value = serde_json::from_str(&stdout(&status)).unwrap();
    for (stage, s) in status["progress"]["stages"].as_object().unwrap() {
        assert_eq!(s["reused"], s["total"], "{stage}: every task reused: {status:#}");
    }
    let o = vintctl(&["lineage", sample, "--job", &again, "--coordinator", &c.coordinator, "--json"]);
    assert!(o.status.success(), "lineage: {}", stderr(&o));
    let lineage: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    for t in lineage["tasks"].as_array().unwrap() {
        let from = t["reused_from"].as_str().unwrap_or_else(|| panic!("not reused: {t:#}"));
        assert_eq!(from, format!("{job}/{}", t["key"].as_str().unwrap()), "{t:#}");
        assert_eq!(t["attempts"], 0, "{t:#}");
    }
    let store = c.store().await;
    for task in store.tasks_of_job(&again).await.unwrap() {
        assert_eq!(store.attempt_count(&task.id).await.unwrap(), 0, "{} ran", task.id);
    }
    store.close().await;
}

#[tokio::test(flavor = "multi_thread")]
async fn a_worker_killed_mid_task_loses_nothing_and_duplicates_nothing() {
    let c = Cluster::new("sigkill").await;
    let _coordinator = c.coordinator_proc("coordinator");
    let job = c.submit();
    let store = c.store().await;
    let mut victim = c.worker("victim");
    // Kill the victim while it holds a render task (Blender mid-frame, outputs maybe half uploaded).
    let deadline = std::time::Instant::now() + Duration::from_secs(120);
    let killed_task = loop {
        let running = store.running_tasks().await.unwrap();
        if let Some(t) = running.iter().find(|t| t.lease_owner.as_deref() == Some("victim") && t.stage == Stage::Render)
        {
            break t.id.clone();
        }
        assert!(std::time::Instant::now() < deadline, "the victim never ran a render task");
        tokio::time::sleep(Duration::from_millis(10)).await;
    };
    victim.sigkill();
    let _survivor = c.worker("survivor");
    c.watch(&job);

    let attempts = store.attempts(&killed_task).await.unwrap();
    assert!(attempts.len() >= 2, "{attempts:?}");
    assert_eq!(attempts[0].worker_id, "victim");
    assert_eq!(attempts[0].outcome, Some(AttemptOutcome::LeaseExpired));
    assert_eq!(attempts.last().unwrap().outcome, Some(AttemptOutcome::Succeeded));

    let out = c.export(&job);
    assert_same_as_embedded(&out);
    // Content addressing: every stored object is the content of some recorded artifact, once.
    let (_rows, distinct) = store.artifact_stats(&job).await.unwrap();
    let objects = vint_artifacts::ArtifactStore::open(&c.store_url).unwrap().count_objects().await.unwrap();
    assert_eq!(objects as u64, distinct, "no orphaned or duplicated objects");
}

#[tokio::test(flavor = "multi_thread")]
async fn a_worker_sigtermed_mid_task_gives_its_lease_back_at_once_and_exits_0() {
    let c = Cluster::new("sigterm").await;
    let _coordinator = c.coordinator_proc("coordinator");
    let job = c.submit();
    let store = c.store().await;
    // A lease far longer than the test: only a hand-back can requeue the task in time.
    let lease_ms = 600_000;
    let scratch = c.dir.path().join("scratch");
    let mut victim =
        start_worker_with_lease(&c.coordinator, &c.store_url, "victim", &c.logs(), &scratch, &c.env, lease_ms);
    let deadline = std::time::Instant::now() + Duration::from_secs(120);
    let held = loop {
        let running = store.running_tasks().await.unwrap();
        if let Some(t) = running.iter().find(|t| t.lease_owner.as_deref() == Some("victim") && t.stage == Stage::Render)
        {
            break t.clone();
        }
        assert!(std::time::Instant::now() < deadline, "the victim never ran a render task");
        tokio::time::sleep(Duration::from_millis(10)).await;
    };
    let engines = children_of(victim.pid());
    let stopped = std::time::Instant::now();
    let status = victim.sigterm_and_wait_for(Duration::from_secs(10));
    let status = status.expect("the worker did not exit within 10 s of SIGTERM");
    assert!(status.success(), "the worker exited {status}");
    eprintln!("worker stopped in {:?}", stopped.elapsed());
    for pid in engines {
        // Gone, or a zombie for the moment init takes to reap it.
        let alive = || {
            std::fs::read_to_string(format!("/proc/{pid}/stat"))
                .is_ok_and(|stat| stat.rsplit(')').next().is_some_and(|rest| !rest.trim_start().starts_with('Z')))
        };
        assert!(!alive(), "engine {pid} outlived its worker");
    }
    // Back in the queue now, not after the lease: its attempt ended `released`, by the victim.
    let task = store.task(&held.id).await.unwrap().unwrap();
    assert_eq!(task.state, vint_core::TaskState::Queued, "{task:?}");
    let attempts = store.attempts(&held.id).await.unwrap();
    let last = attempts.last().unwrap();
    assert_eq!((last.attempt, last.worker_id.as_str()), (held.attempt, "victim"));
    assert_eq!(last.outcome, Some(AttemptOutcome::Released), "{attempts:?}");

    let _survivor = c.worker("survivor");
    c.watch(&job);
    let attempts = store.attempts(&held.id).await.unwrap();
    assert_eq!(attempts.last().unwrap().outcome, Some(AttemptOutcome::Succeeded), "{attempts:?}");
    assert_same_as_embedded(&c.export(&job));
}

/// A worker leasing batches (`--batch`): a task waiting its turn behind slower ones keeps its lease
/// through the one heartbeat (a lease shorter than a render would expire otherwise), SIGTERM gives
/// back every lease of the batch at once, started or not, and the dataset is the embedded run's.
#[tokio::test(flavor = "multi_thread")]
async fn a_batching_worker_keeps_its_waiting_tasks_leases_and_gives_them_all_back_on_sigterm() {
    let c = Cluster::new("batch").await;
    let _coordinator = c.coordinator_proc("coordinator");
    let job = c.submit();
    let store = c.store().await;
    let scratch = c.dir.path().join("scratch");
    let mut env = c.env.clone();
    env.push(("VINT_WORKER_BATCH".into(), "4".into()));

    // A lease far longer than the test: only a hand-back can requeue the tasks in time.
    let mut first = start_worker_with_lease(&c.coordinator, &c.store_url, "first", &c.logs(), &scratch, &env, 600_000);
    let deadline = std::time::Instant::now() + Duration::from_secs(120);
    let held = loop {
        let running = store.running_tasks().await.unwrap();
        let held: Vec<_> = running.into_iter().filter(|t| t.lease_owner.as_deref() == Some("first")).collect();
        if held.len() >= 2 {
            break held;
        }
        assert!(std::time::Instant::now() < deadline, "the worker never held two leases at once");
        tokio::time::sleep(Duration::from_millis(10)).await;
    };
    let status = first.sigterm_and_wait_for(Duration::from_secs(10)).expect("no exit within 10 s of SIGTERM");
    assert!(status.success(), "the worker exited {status}");
    for t in &held {
        let attempts = store.attempts(&t.id).await.unwrap();
        let last = attempts.last().unwrap();
        // Given back (`released`), or reported just before the signal (a finished task).
        assert!(
            matches!(last.outcome, Some(AttemptOutcome::Released | AttemptOutcome::Succeeded)),
            "{}: {attempts:?}",
            t.key
        );
    }
    assert!(
        store.running_tasks().await.unwrap().iter().all(|t| t.lease_owner.as_deref() != Some("first")),
        "a lease of the stopped worker is still held"
    );

    // Leases of 3 s against renders of about as long each: a batch's later tasks wait longer than
    // a lease, so only the heartbeat keeps them.
    let _second = start_worker(&c.coordinator, &c.store_url, "second", &c.logs(), &scratch, &env);
    c.watch(&job);
    for t in store.tasks_of_job(&job).await.unwrap() {
        let attempts = store.attempts(&t.id).await.unwrap();
        assert!(
            attempts.iter().all(|a| a.outcome != Some(AttemptOutcome::LeaseExpired)),
            "{}: a lease expired: {attempts:?}",
            t.key
        );
    }
    assert_same_as_embedded(&c.export(&job));
}

#[tokio::test(flavor = "multi_thread")]
async fn a_coordinator_restart_mid_job_loses_nothing() {
    let c = Cluster::new("restart").await;
    let mut coordinator = c.coordinator_proc("coordinator-1");
    let job = c.submit();
    let store = c.store().await;
    let _w1 = c.worker("w1");
    let _w2 = c.worker("w2");
    wait_for(Duration::from_secs(120), "some work to finish", || {
        let store = store.clone();
        let job = job.clone();
        async move {
            let p = store.progress(&job).await.unwrap();
            p.stage_count(Stage::Render, vint_core::TaskState::Succeeded) >= 1
        }
    })
    .await;
    coordinator.sigkill();
    tokio::time::sleep(Duration::from_secs(2)).await;
    let _coordinator = c.coordinator_proc("coordinator-2");
    c.watch(&job);
    let out = c.export(&job);
    assert_same_as_embedded(&out);
}

/// Stops every engine process of `worker` (SIGSTOP), again every 50 ms, including engines it
/// starts meanwhile, until the returned flag is cleared; then continues them all.
fn stall_engines(worker: i32) -> (std::sync::Arc<std::sync::atomic::AtomicBool>, std::thread::JoinHandle<()>) {
    use nix::sys::signal::{Signal, kill};
    use nix::unistd::Pid;
    let stalled = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(true));
    let flag = stalled.clone();
    let thread = std::thread::spawn(move || {
        while flag.load(std::sync::atomic::Ordering::SeqCst) {
            for pid in children_of(worker) {
                let _ = kill(Pid::from_raw(pid), Signal::SIGSTOP);
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        for pid in children_of(worker) {
            let _ = kill(Pid::from_raw(pid), Signal::SIGCONT);
        }
    });
    (stalled, thread)
}

/// The outage the issue that asked for it describes: the coordinator is down for far longer than
/// a lease (3 s here), and a task runs for more than 90 s (its engine stalled) and finishes while
/// the coordinator is still down, so its completion can only be retried until it is back. Nothing
/// may be lost, no task may fail, and no task may run twice.
#[tokio::test(flavor = "multi_thread")]
async fn a_coordinator_outage_longer_than_a_lease_loses_nothing_and_fails_nothing() {
    let c = Cluster::new("outage").await;
    let mut coordinator = c.coordinator_proc("coordinator-1");
    let job = c.submit();
    let store = c.store().await;
    let worker = c.worker("w1");
    wait_for(Duration::from_secs(120), "a render task to run", || {
        let store = store.clone();
        async move { store.running_tasks().await.unwrap().iter().any(|t| t.stage == Stage::Render) }
    })
    .await;
    let (stalled, engines) = stall_engines(worker.pid());
    // The render may have finished just before its engine stopped: wait until a task of an engine
    // stage is running (stalled) for a second on end, the one whose report the outage will hold.
    let engine_stage = |t: &vint_store::TaskRecord| matches!(t.stage, Stage::Grasp | Stage::Render | Stage::Noise);
    let mut stalled_task = None;
    let give_up = std::time::Instant::now() + Duration::from_secs(60);
    while stalled_task.is_none() {
        let first = store.running_tasks().await.unwrap().into_iter().find(|t| engine_stage(t)).map(|t| t.id);
        tokio::time::sleep(Duration::from_secs(1)).await;
        let still = store.running_tasks().await.unwrap().into_iter().any(|t| Some(&t.id) == first.as_ref());
        if still {
            stalled_task = first;
        }
        assert!(std::time::Instant::now() < give_up, "no engine task stayed running with its engine stopped");
    }
    let stalled_task = stalled_task.unwrap_or_default();
    let stall_started = std::time::Instant::now();
    coordinator.sigkill();
    // More than 90 s of task, all but its first seconds without a coordinator; the engine goes on
    // while the coordinator is still down, and the coordinator comes back only once the task's
    // report has met the outage (the worker retries it).
    tokio::time::sleep(Duration::from_secs(92).saturating_sub(stall_started.elapsed())).await;
    stalled.store(false, std::sync::atomic::Ordering::SeqCst);
    engines.join().unwrap();
    let log = c.logs().join("w1.log");
    wait_for(Duration::from_secs(180), "the stalled task's report to meet the outage", || {
        let log = log.clone();
        async move { std::fs::read_to_string(log).unwrap_or_default().contains("retrying the report") }
    })
    .await;
    tokio::time::sleep(Duration::from_secs(3)).await;
    let _coordinator = c.coordinator_proc("coordinator-2");
    c.watch(&job);

    let attempts = store.attempts(&stalled_task).await.unwrap();
    assert_eq!(attempts.len(), 1, "{stalled_task} ran again: {attempts:?}");
    let took = attempts[0].ended_ms.unwrap_or(0) - attempts[0].started_ms;
    assert!(took > 90_000, "{stalled_task} took {took} ms, not more than 90 s: {attempts:?}");
    for t in store.tasks_of_job(&job).await.unwrap() {
        let attempts = store.attempts(&t.id).await.unwrap();
        assert!(attempts.len() <= 1, "{} ran {} times: {attempts:?}", t.id, attempts.len());
        assert!(attempts.iter().all(|a| a.outcome == Some(AttemptOutcome::Succeeded)), "{}: {attempts:?}", t.id);
    }
    assert_same_as_embedded(&c.export(&job));
}

#[tokio::test(flavor = "multi_thread")]
async fn a_worker_whose_lease_was_reaped_cannot_complete_its_task() {
    let c = Cluster::new("fence").await;
    let _coordinator = c.coordinator_proc("coordinator");
    let job = c.submit();
    let mut client = WorkServiceClient::connect(c.coordinator.clone()).await.unwrap();
    let lease = |worker: &str| pb::LeaseTasksRequest {
        worker_id: worker.into(),
        stages: vec!["grasp".into()],
        capacity: 1,
        lease_ms: 1_000,
        engines: Default::default(),
        timing_only: false,
    };
    let stale = client.lease_tasks(lease("stale")).await.unwrap().into_inner().tasks.remove(0);
    // The reaper returns it to the queue once its deadline has passed (the coordinator's clock is
    // this machine's) and a whole lease has passed since the coordinator started.
    let store = c.store().await;
    wait_for(Duration::from_secs(10), "the task to be requeued", || {
        let store = store.clone();
        let id = stale.task_id.clone();
        async move { store.task(&id).await.unwrap().unwrap().state == vint_core::TaskState::Queued }
    })
    .await;
    assert!(now_ms() > stale.lease_deadline_ms, "requeued before its deadline");
    let complete = |worker: &str, t: &pb::LeasedTask| pb::CompleteTaskRequest {
        worker_id: worker.into(),
        task_id: t.task_id.clone(),
        attempt: t.attempt,
        outputs: vec![],
        engine_json: "{}".into(),
        timings: None,
        result_json: r#"{"accepted": []}"#.into(),
    };
    let refused = client.complete_task(complete("stale", &stale)).await.unwrap_err();
    assert_eq!(refused.code(), tonic::Code::FailedPrecondition, "{refused}");
    let fail = pb::FailTaskRequest {
        worker_id: "stale".into(),
        task_id: stale.task_id.clone(),
        attempt: stale.attempt,
        retryable: false,
        message: "late".into(),
    };
    assert_eq!(client.fail_task(fail).await.unwrap_err().code(), tonic::Code::FailedPrecondition);
    // A live worker takes it over and can complete it.
    // Lease until the requeued task comes back (after its retry backoff, --backoff-ms 200), other
    // grasp tasks with it; bounded, so a task that never returns fails the test instead of hanging it.
    let give_up = std::time::Instant::now() + Duration::from_secs(10);
    let fresh = loop {
        let mut request = lease("fresh");
        request.capacity = 64;
        let tasks = client.lease_tasks(request).await.unwrap().into_inner().tasks;
        if let Some(t) = tasks.into_iter().find(|t| t.task_id == stale.task_id) {
            break t;
        }
        assert!(std::time::Instant::now() < give_up, "{} was never leased again", stale.task_id);
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    assert_eq!(fresh.attempt, stale.attempt + 1);
    client.complete_task(complete("fresh", &fresh)).await.unwrap();
    assert_eq!(store.task(&fresh.task_id).await.unwrap().unwrap().state, vint_core::TaskState::Succeeded);
    let _ = job;
}

#[tokio::test(flavor = "multi_thread")]
async fn a_crashed_engine_fails_its_task_as_retryable_and_is_restarted() {
    let c = Cluster::new("crash").await;
    let _coordinator = c.coordinator_proc("coordinator");
    let job = c.submit();
    let store = c.store().await;
    let worker = c.worker("lone");
    let deadline = std::time::Instant::now() + Duration::from_secs(120);
    let crashed_task = loop {
        let running = store.running_tasks().await.unwrap();
        if let Some(t) = running.iter().find(|t| t.stage == Stage::Render) {
            let engines = children_of(worker.pid());
            if !engines.is_empty() {
                for pid in engines {
                    let _ = nix::sys::signal::kill(nix::unistd::Pid::from_raw(pid), nix::sys::signal::Signal::SIGKILL);
                }
                break t.id.clone();
            }
        }
        assert!(std::time::Instant::now() < deadline, "the worker never ran a render task");
        tokio::time::sleep(Duration::from_millis(10)).await;
    };
    c.watch(&job);
    // The kill may land just after the render finished; then the engine's next task (of this
    // worker, whichever it is) takes the hit instead. Either way: exactly the crash's attempts end
    // `retry` with the engine's crash as their error, and each of those tasks then succeeds.
    let mut retried = Vec::new();
    for t in store.tasks_of_job(&job).await.unwrap() {
        let attempts = store.attempts(&t.id).await.unwrap();
        for a in attempts.iter().filter(|a| a.outcome == Some(AttemptOutcome::Retry)) {
            assert!(a.error.as_deref().unwrap_or("").contains("crashed"), "{a:?}");
            assert_eq!(attempts.last().unwrap().outcome, Some(AttemptOutcome::Succeeded), "{}: {attempts:?}", t.id);
            retried.push(t.id.clone());
        }
    }
    assert!(!retried.is_empty(), "the crash must have failed some attempt as retryable");
    assert!(
        retried.contains(&crashed_task) || store.attempts(&crashed_task).await.unwrap().len() == 1,
        "the killed task {crashed_task} either took the crash or had finished: retried {retried:?}"
    );
    assert_same_as_embedded(&c.export(&job));
}

#[tokio::test(flavor = "multi_thread")]
async fn artifacts_in_s3_give_the_same_dataset() {
    let mut c = Cluster::new("s3").await;
    let (_s3, env) = start_s3(&c.logs());
    c.env = env;
    c.store_url = "s3://vint/datasets/tiny".into();
    let _coordinator = c.coordinator_proc("coordinator");
    let job = c.submit();
    let _w1 = c.worker("w1");
    let _w2 = c.worker("w2");
    c.watch(&job);
    let out = c.export(&job);
    assert_same_as_embedded(&out);
}

#[tokio::test(flavor = "multi_thread")]
async fn a_submitted_user_file_has_lineage_by_its_hash() {
    let c = Cluster::new("userfile").await;
    let _coordinator = start_coordinator_with_store(&c.database, c.port, &c.logs(), "coordinator", Some(&c.store_url));
    let spec = repo_root().join("examples").join("custom.toml");
    let o = vintctl(&["submit", spec.to_str().unwrap(), "--coordinator", &c.coordinator]);
    assert!(o.status.success(), "submit: {}", stderr(&o));
    let job = stdout(&o).trim().to_string();
    let cup = repo_root().join("examples").join("assets").join("cup.obj");
    let sha = hex::encode(<sha2::Sha256 as sha2::Digest>::digest(std::fs::read(cup).unwrap()));
    let o = vintctl(&["--json", "lineage", &sha, "--artifact", "--coordinator", &c.coordinator]);
    assert!(o.status.success(), "lineage: {}", stderr(&o));
    let lineage: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(lineage["job_id"], job.as_str());
    assert_eq!(lineage["user_files"][0]["path"], "assets/cup.obj");
    let keys: Vec<&str> = lineage["tasks"].as_array().unwrap().iter().map(|t| t["key"].as_str().unwrap()).collect();
    assert!(!keys.is_empty() && keys.iter().all(|k| k.starts_with("grasp/cup/")), "{keys:?}");
    let unknown = vintctl(&["lineage", &"0".repeat(64), "--artifact", "--coordinator", &c.coordinator]);
    assert!(!unknown.status.success());
}
