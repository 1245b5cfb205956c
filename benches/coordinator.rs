//! Coordinator throughput: how many tasks per second the real gRPC coordinator can lease and
//! complete, on Postgres and on the embedded SQLite, when the work itself costs nothing.
//!
//!     cargo bench -p vint-tests --bench coordinator [-- FILTER...]
//!
//! (plain `cargo bench` uses the `bench` profile, i.e. release, the build benches and deployments
//! use; `--profile dev` measures the quick-to-compile development build instead. Each JSON line
//! says which.) `benches/queue.sh` runs these cases side by side with the raw SQL ceiling and awa.
//!
//! Each run makes a fresh database, inserts N grasp tasks with `Store::submit_job` (a job whose
//! spec is `examples/tiny.toml` cut to its first hand and first object, with `trials_per_pair = N`
//! and `chunk_size = 1`, so every key is a real chunk key the planner accepts), serves the
//! coordinator in-process on a loopback port and lets `WORKERS` concurrent `NoopWorker`s drain the
//! queue over gRPC: `LeaseTasks(capacity = batch)`, then one `CompleteTasks` call for the whole
//! lease, every task with no outputs and `{"accepted": []}` (which unlocks nothing), until a lease
//! comes back empty. With prefetch on, a worker leases its next batch while its last completion
//! is still in flight (as a real worker with a small prefetch would), so each worker has at most
//! one lease and one completion RPC outstanding. The clock runs from the first lease to the last
//! completion; inserting the tasks is not timed. Every completion result must be COMPLETED, and
//! every run checks that all N tasks and the job succeeded.
//!
//! No tracing subscriber is installed, so the coordinator's per-lease and per-completion log
//! lines (written to stderr by the real binary) cost nothing here.
//!
//! FILTER words select cases whose name (`postgres/batch1`, `sqlite/batch64`, …) contains one of
//! them; without any, every case runs. Postgres comes from `VINT_TEST_POSTGRES_URL` (an admin URL)
//! or 127.0.0.1:5432, as in the tests; the bench fails without it.
//!
//! Knobs, for exploring (the defaults are what the figures in docs/benchmarks.md use):
//! `VINT_BENCH_REPEATS` (runs per case, default 3), `VINT_BENCH_TASKS` (tasks per run, every case;
//! default: per case, sized for runs of 2 s or more), `VINT_BENCH_WORKERS` (default 4) and
//! `VINT_BENCH_PREFETCH` (1 = on, the default; 0 = lease only after the last completion returned).
//!
//! The smoke, the test command's check that the bench still runs (seconds, no release build, not a
//! figure): `VINT_BENCH_TASKS=64 VINT_BENCH_REPEATS=1 cargo bench --profile dev -p vint-tests --bench
//! coordinator`.

use std::net::{Ipv4Addr, SocketAddr};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use serde_json::json;
use tonic::transport::{Channel, Endpoint};
use vint_coordinator::{CoordinatorConfig, now_ms};
use vint_core::plan::{JobPlan, initial_tasks};
use vint_core::spec::TRIALS_PER_PAIR;
use vint_core::{DatasetSpec, JobState, Stage, TaskState};
use vint_proto::v1 as pb;
use vint_proto::v1::completion_result::Outcome;
use vint_proto::v1::work_service_client::WorkServiceClient;
use vint_store::{NewJob, RetryPolicy, Store};

/// Concurrent no-op workers, each on its own HTTP/2 connection, as separate processes would be.
const WORKERS: Knob = Knob { var: "VINT_BENCH_WORKERS", default: 4, min: 1, max: 64 };
/// Whether a worker leases its next batch while its last completion is in flight.
const PREFETCH: Knob = Knob { var: "VINT_BENCH_PREFETCH", default: 1, min: 0, max: 1 };
/// Runs per case; each on a fresh database. The summary is their median.
const REPEATS: Knob = Knob { var: "VINT_BENCH_REPEATS", default: 3, min: 1, max: 100 };
/// Tasks per run for every case, overriding the per-case counts (short trial runs, or a machine
/// fast enough that the defaults take less than `MIN_RUN`).
const TASKS: Knob = Knob { var: "VINT_BENCH_TASKS", default: 0, min: 1, max: TRIALS_PER_PAIR.max };
/// Shorter runs than this are too noisy to compare; the bench says so next to the figure.
const MIN_RUN: Duration = Duration::from_secs(2);
/// Long enough that no lease expires mid-run, so the reaper never interferes.
const LEASE_MS: u32 = 60_000;

/// A bench setting read from the environment, with its default and bounds.
struct Knob {
    var: &'static str,
    default: u32,
    min: u32,
    max: u32,
}

impl Knob {
    /// The setting's value; `None` when unset (the default then applies).
    fn read(&self) -> Result<Option<u32>, String> {
        let Ok(raw) = std::env::var(self.var) else {
            return Ok(None);
        };
        match raw.trim().parse::<u32>() {
            Ok(v) if (self.min..=self.max).contains(&v) => Ok(Some(v)),
            _ => Err(format!("{} = {raw:?}: must be an integer from {} to {}", self.var, self.min, self.max)),
        }
    }
}

/// The run's settings, after the environment has had its say.
struct Settings {
    workers: usize,
    prefetch: bool,
    repeats: usize,
    tasks: Option<u32>,
}

impl Settings {
    fn from_env() -> Result<Settings, String> {
        Ok(Settings {
            workers: WORKERS.read()?.unwrap_or(WORKERS.default) as usize,
            prefetch: PREFETCH.read()?.unwrap_or(PREFETCH.default) == 1,
            repeats: REPEATS.read()?.unwrap_or(REPEATS.default) as usize,
            tasks: TASKS.read()?,
        })
    }
}

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

/// The cases, and the tasks per run that keep each above `MIN_RUN` at today's speed. SQLite at
/// batch 256 is left out: one writer serializes every transaction there, so a bigger batch than
/// 64 changes only how long the write lock is held, not what the embedded path can do.
fn cases(tasks: Option<u32>) -> Vec<Case> {
    [
        (Backend::Postgres, 1, 8_000),
        (Backend::Postgres, 64, 60_000),
        (Backend::Postgres, 256, 60_000),
        (Backend::Sqlite, 1, 8_000),
        (Backend::Sqlite, 64, 40_000),
    ]
    .into_iter()
    .map(|(backend, batch, default)| Case { backend, batch, tasks: tasks.unwrap_or(default) })
    .collect()
}

/// What one run measured.
struct Run {
    tasks: u64,
    /// Inserting the tasks (untimed in the figure; it bounds how long a case takes to run).
    seeding: Duration,
    elapsed: Duration,
    lease_rpc_ms: Vec<f64>,
    complete_rpc_ms: Vec<f64>,
}

impl Run {
    fn tasks_per_s(&self) -> f64 {
        self.tasks as f64 / self.elapsed.as_secs_f64()
    }
}

/// Which build is measuring: debug assertions are on in the dev profile, off in release/bench.
fn profile() -> &'static str {
    if cfg!(debug_assertions) { "dev" } else { "release" }
}

#[tokio::main]
async fn main() -> ExitCode {
    let settings = match Settings::from_env() {
        Ok(s) => s,
        Err(e) => {
            eprintln!("coordinator bench: {e}");
            return ExitCode::from(2);
        }
    };
    // cargo passes `--bench`; every other word is a case filter.
    let filters: Vec<String> = std::env::args().skip(1).filter(|a| !a.starts_with("--")).collect();
    let mut cases = cases(settings.tasks);
    cases.retain(|c| c.selected(&filters));
    if cases.is_empty() {
        eprintln!("coordinator bench: no case matches the filters {filters:?}");
        return ExitCode::from(2);
    }

    println!(
        "coordinator lease+complete throughput ({} build): {} no-op workers over gRPC, prefetch {}, {} runs per case, fresh database each",
        profile(),
        settings.workers,
        if settings.prefetch { "on" } else { "off" },
        settings.repeats,
    );
    println!("load average at start: {}", load_average());
    // Rounds run every case once, so a change in the machine's load touches all cases alike.
    let mut runs_by_case: Vec<Vec<Run>> = cases.iter().map(|_| Vec::new()).collect();
    for repeat in 0..settings.repeats {
        for (case, runs) in cases.iter().zip(&mut runs_by_case) {
            let run = run_case(case, repeat, &settings).await;
            println!(
                "  {:<24} run {}: {:>6} tasks in {:>7.1} ms = {:>7.0} tasks/s  (p50 LeaseTasks {:.2} ms, p50 CompleteTasks {:.2} ms; seeded in {:.1} s){}",
                case.name(),
                repeat + 1,
                run.tasks,
                run.elapsed.as_secs_f64() * 1e3,
                run.tasks_per_s(),
                median(run.lease_rpc_ms.clone()),
                median(run.complete_rpc_ms.clone()),
                run.seeding.as_secs_f64(),
                if run.elapsed < MIN_RUN { "  [shorter than 2 s: raise VINT_BENCH_TASKS]" } else { "" },
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
            "workers": settings.workers,
            "prefetch": settings.prefetch,
            "profile": profile(),
            "runs_tasks_per_s": rates.iter().map(|r| r.round()).collect::<Vec<_>>(),
            "runs_elapsed_s": runs.iter().map(|r| round2(r.elapsed.as_secs_f64())).collect::<Vec<_>>(),
            "median_tasks_per_s": median(rates.clone()).round(),
            "min_tasks_per_s": min(&rates).round(),
            "max_tasks_per_s": max(&rates).round(),
            "p50_lease_rpc_ms": round2(median(runs.iter().flat_map(|r| r.lease_rpc_ms.clone()).collect())),
            "p50_complete_rpc_ms": round2(median(runs.iter().flat_map(|r| r.complete_rpc_ms.clone()).collect())),
        });
        println!("{line}");
    }
    ExitCode::SUCCESS
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
    if let (Some(b256), Some(b64)) = (med(Backend::Postgres, 256), med(Backend::Postgres, 64)) {
        println!("ratio postgres: batch256 / batch64 = {:.2}x", b256 / b64);
    }
    for batch in [1, 64] {
        if let (Some(pg), Some(sq)) = (med(Backend::Postgres, batch), med(Backend::Sqlite, batch)) {
            println!("ratio batch{batch}: postgres / sqlite = {:.2}x", pg / sq);
        }
    }
}

async fn run_case(case: &Case, repeat: usize, settings: &Settings) -> Run {
    let scratch = tempfile::tempdir().expect("temp dir");
    let (url, pg_database) = match case.backend {
        Backend::Postgres => {
            let url = vint_tests::postgres_database("bench").await;
            let db = url.rsplit_once('/').map(|(_, d)| d.to_string());
            (url, db)
        }
        Backend::Sqlite => (format!("sqlite://{}", scratch.path().join("vint.db").display()), None),
    };
    let store = Store::open(&url, RetryPolicy::default())
        .await
        .unwrap_or_else(|e| panic!("opening {}: {e}", vint_telemetry::redact_url(&url)));

    let job_id = format!("bench-{}-b{}-r{repeat}", case.backend.name(), case.batch);
    let spec_toml = bench_spec(case.tasks);
    let spec = DatasetSpec::parse(&spec_toml).expect("bench spec parses");
    let tasks = initial_tasks(&spec, &[]).expect("the bench spec names no assets");
    assert_eq!(tasks.len(), case.tasks as usize);
    let seeding = Instant::now();
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
                timing_only: false,
                submitted_by: None,
            },
            &tasks,
            now_ms(),
        )
        .await
        .expect("submit the bench job");
    let seeding = seeding.elapsed();

    let (listener, addr) =
        vint_coordinator::bind(SocketAddr::from((Ipv4Addr::LOCALHOST, 0))).await.expect("bind the coordinator");
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let shutdown = async {
        let _ = stop_rx.await;
    };
    let server = tokio::spawn(vint_coordinator::serve(store.clone(), CoordinatorConfig::default(), listener, shutdown));

    let mut workers = Vec::new();
    for i in 0..settings.workers {
        workers.push(NoopWorker::connect(addr, format!("noop-{i}"), case.batch, settings.prefetch).await);
    }
    let started = Instant::now();
    let handles: Vec<_> = workers.into_iter().map(|w| tokio::spawn(w.drain())).collect();
    let mut run =
        Run { tasks: 0, seeding, elapsed: Duration::ZERO, lease_rpc_ms: Vec::new(), complete_rpc_ms: Vec::new() };
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
#[derive(Default)]
struct Drained {
    completed: u64,
    lease_rpc_ms: Vec<f64>,
    complete_rpc_ms: Vec<f64>,
}

/// A test-only worker that does no work: it leases grasp tasks and completes each lease at once,
/// in one `CompleteTasks` call, with no outputs and no accepted grasps, so the measured cost is
/// the coordinator's and the store's.
struct NoopWorker {
    client: WorkServiceClient<Channel>,
    worker_id: String,
    batch: u32,
    prefetch: bool,
}

impl NoopWorker {
    async fn connect(addr: SocketAddr, worker_id: String, batch: u32, prefetch: bool) -> NoopWorker {
        let channel = Endpoint::from_shared(format!("http://{addr}"))
            .expect("coordinator URL")
            .connect()
            .await
            .expect("connect to the coordinator");
        NoopWorker { client: WorkServiceClient::new(channel), worker_id, batch, prefetch }
    }

    /// Leases and completes until a lease comes back empty. All tasks are queued before the
    /// workers start and none fails, so an empty lease means the queue is drained. With prefetch,
    /// the completion of one lease runs on the same connection while the next lease is asked for.
    async fn drain(mut self) -> Drained {
        let mut done = Drained::default();
        let mut in_flight: Option<tokio::task::JoinHandle<(u64, f64)>> = None;
        loop {
            let t = Instant::now();
            let leased = self
                .client
                .lease_tasks(pb::LeaseTasksRequest {
                    worker_id: self.worker_id.clone(),
                    stages: vec![Stage::Grasp.as_str().to_string()],
                    capacity: self.batch,
                    lease_ms: LEASE_MS,
                    engines: Default::default(),
                    timing_only: false,
                })
                .await
                .expect("LeaseTasks")
                .into_inner()
                .tasks;
            done.lease_rpc_ms.push(ms(t.elapsed()));
            if let Some(completion) = in_flight.take() {
                let (completed, rpc_ms) = completion.await.expect("CompleteTasks call panicked");
                done.completed += completed;
                done.complete_rpc_ms.push(rpc_ms);
            }
            if leased.is_empty() {
                return done;
            }
            let completion = complete_all(self.client.clone(), self.worker_id.clone(), leased);
            if self.prefetch {
                in_flight = Some(tokio::spawn(completion));
            } else {
                let (completed, rpc_ms) = completion.await;
                done.completed += completed;
                done.complete_rpc_ms.push(rpc_ms);
            }
        }
    }
}

/// Completes every leased task in one `CompleteTasks` call and checks that each one completed.
/// Returns how many did and how long the call took, in milliseconds.
async fn complete_all(
    mut client: WorkServiceClient<Channel>,
    worker_id: String,
    leased: Vec<pb::LeasedTask>,
) -> (u64, f64) {
    let tasks: Vec<pb::CompleteTaskRequest> = leased
        .into_iter()
        .map(|task| pb::CompleteTaskRequest {
            worker_id: worker_id.clone(),
            task_id: task.task_id,
            attempt: task.attempt,
            outputs: vec![],
            engine_json: "{}".into(),
            timings: Some(pb::Timings::default()),
            result_json: r#"{"accepted": []}"#.into(),
        })
        .collect();
    let sent = tasks.len();
    let t = Instant::now();
    let results =
        client.complete_tasks(pb::CompleteTasksRequest { tasks }).await.expect("CompleteTasks").into_inner().results;
    let rpc_ms = ms(t.elapsed());
    assert_eq!(results.len(), sent, "{worker_id}: one CompleteTasks result per task");
    for r in &results {
        assert_eq!(
            Outcome::try_from(r.outcome),
            Ok(Outcome::Completed),
            "{worker_id}: task {} attempt {}: {}",
            r.task_id,
            r.attempt,
            r.message
        );
    }
    (results.len() as u64, rpc_ms)
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
