//! Coordinator throughput: how many tasks per second the real gRPC coordinator can lease and
//! complete, on Postgres and on the embedded SQLite, when the work itself costs nothing.
//!
//!     cargo bench -p vint-tests --bench coordinator --profile dev [-- FILTER...]
//!
//! (`--profile dev` measures the build vint ships from scripts/setup.sh: dependencies optimized,
//! vint's own crates not; plain `cargo bench` builds everything in release first.)
//!
//! Each run makes a fresh database, inserts N grasp tasks with `Store::submit_job` (a job whose
//! spec is `examples/tiny.toml` cut to its first hand and first object, with `trials_per_pair = N`
//! and `chunk_size = 1`, so every key is a real chunk key the planner accepts), serves the
//! coordinator in-process on a loopback port and lets `WORKERS` concurrent `NoopWorker`s drain the
//! queue over gRPC: `LeaseTasks(capacity = batch)`, then `CompleteTask` for each leased task with
//! no outputs and `{"accepted": []}` (which unlocks nothing), until a lease comes back empty. The clock runs from the first lease to the
//! last completion; inserting the tasks is not timed. Every run checks that all N tasks and the
//! job succeeded.
//!
//! No tracing subscriber is installed, so the coordinator's per-lease and per-completion log
//! lines (written to stderr by the real binary) cost nothing here.
//!
//! FILTER words select cases whose name (`postgres/batch1`, `sqlite/batch64`, …) contains one of
//! them; without any, every case runs. Postgres comes from `VINT_TEST_POSTGRES_URL` (an admin URL)
//! or 127.0.0.1:5432, as in the tests; the bench fails without it.

use std::net::{Ipv4Addr, SocketAddr};
use std::time::{Duration, Instant};

use serde_json::json;
use tonic::transport::{Channel, Endpoint};
use vint_coordinator::{CoordinatorConfig, now_ms};
use vint_core::plan::{JobPlan, initial_tasks};
use vint_core::{DatasetSpec, JobState, Stage, TaskState};
use vint_proto::v1 as pb;
use vint_proto::v1::work_service_client::WorkServiceClient;
use vint_store::{NewJob, RetryPolicy, Store};

/// Concurrent no-op workers, each on its own HTTP/2 connection, as separate processes would be.
const WORKERS: usize = 4;
/// Runs per case; each on a fresh database. The summary is their median.
const REPEATS: usize = 3;
/// Long enough that no lease expires mid-run, so the reaper never interferes.
const LEASE_MS: u32 = 60_000;

#[derive(Clone, Copy, PartialEq)]
enum Backend {
    Postgres,
    Sqlite,
}

impl Backend {
    fn name(self) -> &'static str {
        match self {
            Backend::Postgres => "postgres",
            Backend::Sqlite => "sqlite",
        }
    }
}

struct Case {
    backend: Backend,
    batch: u32,
    tasks: u32,
}

impl Case {
    fn name(&self) -> String {
        format!("{}/batch{}", self.backend.name(), self.batch)
    }

    /// Every case runs without filters; with some, those whose name contains one of them.
    fn selected(&self, filters: &[String]) -> bool {
        let name = self.name();
        filters.is_empty() || filters.iter().any(|f| name.contains(f.as_str()))
    }
}

/// What one run measured.
struct Run {
    tasks: u64,
    elapsed: Duration,
    lease_rpc_ms: Vec<f64>,
    complete_rpc_ms: Vec<f64>,
}

impl Run {
    fn tasks_per_s(&self) -> f64 {
        self.tasks as f64 / self.elapsed.as_secs_f64()
    }
}

#[tokio::main]
async fn main() {
    // cargo passes `--bench`; every other word is a case filter.
    let filters: Vec<String> = std::env::args().skip(1).filter(|a| !a.starts_with("--")).collect();
    let mut cases = Vec::new();
    for backend in [Backend::Postgres, Backend::Sqlite] {
        for (batch, tasks) in [(1, 1_000), (64, 5_000)] {
            cases.push(Case { backend, batch, tasks });
        }
    }
    cases.retain(|c| c.selected(&filters));

    println!(
        "coordinator lease+complete throughput: {WORKERS} no-op workers over gRPC, {REPEATS} runs per case, fresh database each"
    );
    println!("load average at start: {}", load_average());
    // Rounds run every case once, so a change in the machine's load touches all cases alike.
    let mut runs_by_case: Vec<Vec<Run>> = cases.iter().map(|_| Vec::new()).collect();
    for repeat in 0..REPEATS {
        for (case, runs) in cases.iter().zip(&mut runs_by_case) {
            let run = run_case(case, repeat).await;
            println!(
                "  {:<24} run {}: {:>6} tasks in {:>7.1} ms = {:>7.0} tasks/s  (p50 LeaseTasks {:.2} ms, p50 CompleteTask {:.2} ms)",
                case.name(),
                repeat + 1,
                run.tasks,
                run.elapsed.as_secs_f64() * 1e3,
                run.tasks_per_s(),
                median(run.lease_rpc_ms.clone()),
                median(run.complete_rpc_ms.clone()),
            );
            runs.push(run);
        }
    }
    println!("load average at end: {}", load_average());
    let summaries: Vec<(&Case, Vec<Run>)> = cases.iter().zip(runs_by_case).collect();

    println!();
    println!(
        "{:<24} {:>6} {:>7} {:>12} {:>10} {:>10} {:>14} {:>16}",
        "case", "batch", "tasks", "median/s", "min/s", "max/s", "p50 lease ms", "p50 complete ms"
    );
    for (case, runs) in &summaries {
        let rates: Vec<f64> = runs.iter().map(Run::tasks_per_s).collect();
        println!(
            "{:<24} {:>6} {:>7} {:>12.0} {:>10.0} {:>10.0} {:>14.2} {:>16.2}",
            case.name(),
            case.batch,
            case.tasks,
            median(rates.clone()),
            min(&rates),
            max(&rates),
            median(runs.iter().flat_map(|r| r.lease_rpc_ms.clone()).collect()),
            median(runs.iter().flat_map(|r| r.complete_rpc_ms.clone()).collect()),
        );
    }
    print_ratios(&summaries);

    println!();
    for (case, runs) in &summaries {
        let rates: Vec<f64> = runs.iter().map(Run::tasks_per_s).collect();
        let line = json!({
            "bench": "coordinator_lease_complete",
            "case": case.name(),
            "backend": case.backend.name(),
            "batch": case.batch,
            "tasks": case.tasks,
            "workers": WORKERS,
            "runs_tasks_per_s": rates.iter().map(|r| r.round()).collect::<Vec<_>>(),
            "median_tasks_per_s": median(rates.clone()).round(),
            "min_tasks_per_s": min(&rates).round(),
            "max_tasks_per_s": max(&rates).round(),
            "p50_lease_rpc_ms": round2(median(runs.iter().flat_map(|r| r.lease_rpc_ms.clone()).collect())),
            "p50_complete_rpc_ms": round2(median(runs.iter().flat_map(|r| r.complete_rpc_ms.clone()).collect())),
        });
        println!("{line}");
    }
}

/// Side-by-side ratios of medians from this run: batch 64 over batch 1, Postgres over SQLite.
fn print_ratios(summaries: &[(&Case, Vec<Run>)]) {
    let med = |backend: Backend, batch: u32| {
        summaries
            .iter()
            .find(|(c, _)| c.backend == backend && c.batch == batch)
            .map(|(_, runs)| median(runs.iter().map(Run::tasks_per_s).collect()))
    };
    println!();
    for backend in [Backend::Postgres, Backend::Sqlite] {
        if let (Some(b64), Some(b1)) = (med(backend, 64), med(backend, 1)) {
            println!("ratio {}: batch64 / batch1 = {:.2}x", backend.name(), b64 / b1);
        }
    }
    for batch in [1, 64] {
        if let (Some(pg), Some(sq)) = (med(Backend::Postgres, batch), med(Backend::Sqlite, batch)) {
            println!("ratio batch{batch}: postgres / sqlite = {:.2}x", pg / sq);
        }
    }
}

async fn run_case(case: &Case, repeat: usize) -> Run {
    let scratch = tempfile::tempdir().expect("temp dir");
    let (url, pg_database) = match case.backend {
        Backend::Postgres => {
            let url = vint_tests::postgres_database("bench").await;
            let db = url.rsplit_once('/').map(|(_, d)| d.to_string());
            (url, db)
        }
        Backend::Sqlite => (format!("sqlite://{}", scratch.path().join("vint.db").display()), None),
    };
    let store = Store::open(&url, RetryPolicy::default()).await.unwrap_or_else(|e| panic!("opening {url}: {e}"));

    let job_id = format!("bench-{}-b{}-r{repeat}", case.backend.name(), case.batch);
    let spec_toml = bench_spec(case.tasks);
    let spec = DatasetSpec::parse(&spec_toml).expect("bench spec parses");
    let tasks = initial_tasks(&spec, &[]).expect("the bench spec names no assets");
    assert_eq!(tasks.len(), case.tasks as usize);
    store
        .submit_job(
            &NewJob {
                id: job_id.clone(),
                name: spec.dataset.name.clone(),
                seed: spec.dataset.seed,
                plan_json: serde_json::to_string(&JobPlan::new(&spec, &[]).expect("the bench spec plans"))
                    .expect("a plan serializes"),
                spec_toml,
                idempotency_key: job_id.clone(),
                assets: vec![],
            },
            &tasks,
            now_ms(),
        )
        .await
        .expect("submit the bench job");

    let (listener, addr) =
        vint_coordinator::bind(SocketAddr::from((Ipv4Addr::LOCALHOST, 0))).await.expect("bind the coordinator");
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let shutdown = async {
        let _ = stop_rx.await;
    };
    let server = tokio::spawn(vint_coordinator::serve(store.clone(), CoordinatorConfig::default(), listener, shutdown));

    let mut workers = Vec::new();
    for i in 0..WORKERS {
        workers.push(NoopWorker::connect(addr, format!("noop-{i}"), case.batch).await);
    }
    let started = Instant::now();
    let handles: Vec<_> = workers.into_iter().map(|w| tokio::spawn(w.drain())).collect();
    let mut run = Run { tasks: 0, elapsed: Duration::ZERO, lease_rpc_ms: Vec::new(), complete_rpc_ms: Vec::new() };
    for h in handles {
        let done = h.await.expect("no-op worker panicked");
        run.tasks += done.completed;
        run.lease_rpc_ms.extend(done.lease_rpc_ms);
        run.complete_rpc_ms.extend(done.complete_rpc_ms);
    }
    run.elapsed = started.elapsed();

    assert_eq!(run.tasks, u64::from(case.tasks), "{}: tasks completed", case.name());
    let progress = store.progress(&job_id).await.expect("progress");
    assert_eq!(
        progress.stage_count(Stage::Grasp, TaskState::Succeeded),
        u64::from(case.tasks),
        "{}: succeeded grasp tasks",
        case.name()
    );
    store.finalize_jobs(now_ms()).await.expect("finalize");
    let job = store.job(&job_id).await.expect("job").expect("job exists");
    assert_eq!(job.state, JobState::Succeeded, "{}: job state", case.name());

    let _ = stop_tx.send(());
    server.await.expect("coordinator task").expect("coordinator served");
    store.close().await;
    if let Some(db) = pg_database {
        drop_postgres_database(&db).await;
    }
    run
}

/// `examples/tiny.toml` cut to its first hand and first object, with `n` grasp trials in chunks of
/// one: `n` valid grasp chunk keys.
fn bench_spec(n: u32) -> String {
    let tiny = std::fs::read_to_string(vint_tests::tiny_spec()).expect("examples/tiny.toml");
    // `key = ["first", ...]` becomes `key = ["first"]`.
    let first_only = |line: &str| {
        let (key, list) = line.split_once('=')?;
        let first = list.split('"').nth(1)?;
        Some(format!("{key}= [\"{first}\"]\n"))
    };
    let mut out = String::new();
    let mut seen = [false; 4];
    for line in tiny.lines() {
        let replaced = if line.starts_with("hands") {
            seen[0] = true;
            first_only(line)
        } else if line.starts_with("objects") {
            seen[1] = true;
            first_only(line)
        } else if line.starts_with("trials_per_pair") {
            seen[2] = true;
            Some(format!("trials_per_pair = {n}\n"))
        } else if line.starts_with("chunk_size") {
            seen[3] = true;
            Some("chunk_size = 1\n".to_string())
        } else {
            None
        };
        out.push_str(&replaced.unwrap_or_else(|| format!("{line}\n")));
    }
    assert!(
        seen.iter().all(|s| *s),
        "examples/tiny.toml no longer sets hands, objects, grasp.trials_per_pair and grasp.chunk_size"
    );
    out
}

async fn drop_postgres_database(db: &str) {
    let admin = std::env::var("VINT_TEST_POSTGRES_URL")
        .unwrap_or_else(|_| "postgres://postgres@127.0.0.1:5432/postgres".to_string());
    let mut conn = <sqlx::AnyConnection as sqlx::Connection>::connect(&admin).await.expect("admin connection");
    sqlx::Executor::execute(&mut conn, sqlx::AssertSqlSafe(format!("DROP DATABASE IF EXISTS {db} WITH (FORCE)")))
        .await
        .unwrap_or_else(|e| panic!("dropping {db}: {e}"));
}

/// What one no-op worker did.
struct Drained {
    completed: u64,
    lease_rpc_ms: Vec<f64>,
    complete_rpc_ms: Vec<f64>,
}

/// A test-only worker that does no work: it leases grasp tasks and completes each at once with
/// no outputs and no accepted grasps, so the measured cost is the coordinator's and the store's.
struct NoopWorker {
    client: WorkServiceClient<Channel>,
    worker_id: String,
    batch: u32,
}

impl NoopWorker {
    async fn connect(addr: SocketAddr, worker_id: String, batch: u32) -> NoopWorker {
        let channel = Endpoint::from_shared(format!("http://{addr}"))
            .expect("coordinator URL")
            .connect()
            .await
            .expect("connect to the coordinator");
        NoopWorker { client: WorkServiceClient::new(channel), worker_id, batch }
    }

    /// Leases and completes until a lease comes back empty. All tasks are queued before the
    /// workers start and none fails, so an empty lease means the queue is drained.
    async fn drain(mut self) -> Drained {
        let mut done = Drained { completed: 0, lease_rpc_ms: Vec::new(), complete_rpc_ms: Vec::new() };
        loop {
            let t = Instant::now();
            let leased = self
                .client
                .lease_tasks(pb::LeaseTasksRequest {
                    worker_id: self.worker_id.clone(),
                    stages: vec![Stage::Grasp.as_str().to_string()],
                    capacity: self.batch,
                    lease_ms: LEASE_MS,
                })
                .await
                .expect("LeaseTasks")
                .into_inner()
                .tasks;
            done.lease_rpc_ms.push(ms(t.elapsed()));
            if leased.is_empty() {
                return done;
            }
            for task in leased {
                let t = Instant::now();
                self.client
                    .complete_task(pb::CompleteTaskRequest {
                        worker_id: self.worker_id.clone(),
                        task_id: task.task_id,
                        attempt: task.attempt,
                        outputs: vec![],
                        engine_json: "{}".into(),
                        timings: Some(pb::Timings::default()),
                        result_json: r#"{"accepted": []}"#.into(),
                    })
                    .await
                    .expect("CompleteTask");
                done.complete_rpc_ms.push(ms(t.elapsed()));
                done.completed += 1;
            }
        }
    }
}

/// The machine's 1, 5 and 15 minute load averages: other work on it skews every figure.
fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|l| l.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|_| "unknown".into())
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let mid = v.len() / 2;
    if v.len() % 2 == 1 { v[mid] } else { (v[mid - 1] + v[mid]) / 2.0 }
}

fn min(v: &[f64]) -> f64 {
    v.iter().copied().fold(f64::INFINITY, f64::min)
}

fn max(v: &[f64]) -> f64 {
    v.iter().copied().fold(f64::NEG_INFINITY, f64::max)
}

fn round2(x: f64) -> f64 {
    (x * 100.0).round() / 100.0
}
