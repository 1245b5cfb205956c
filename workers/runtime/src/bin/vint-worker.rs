//! `vint-worker`: leases tasks of the given stages from a coordinator and runs them.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context;
use clap::{Parser, ValueEnum};
use vint_artifacts::ArtifactStore;
use vint_core::Stage;
use vint_runtime::engine::{EngineCommand, RecyclePolicy};
use vint_runtime::metrics::{WorkerMetrics, liveness_limit};
use vint_runtime::timing_only::{self, TimingOnlyConfig};
use vint_runtime::worker::{Worker, WorkerConfig};

#[derive(Parser)]
#[command(name = "vint-worker", version, about = "vint worker: runs grasp, render, noise and package tasks")]
struct Args {
    /// Coordinator URL (`https://` for a coordinator serving TLS).
    #[arg(long, env = "VINT_COORDINATOR", default_value = "http://127.0.0.1:7700")]
    coordinator: String,
    /// Bearer token for a coordinator started with --auth-tokens: a worker token.
    #[arg(long, env = "VINT_TOKEN", hide_env_values = true)]
    token: Option<String>,
    /// PEM certificate of the authority that signed an https:// coordinator's certificate (default:
    /// the system's trusted roots).
    #[arg(long, env = "VINT_TLS_CA")]
    tls_ca: Option<PathBuf>,
    /// Artifact store URL: file:///abs/dir or s3://bucket[/prefix].
    #[arg(long, env = "VINT_STORE", hide_env_values = true)]
    store: String,
    /// Stages to serve, comma-separated.
    #[arg(long, env = "VINT_STAGES", value_delimiter = ',', default_value = "grasp,render,noise,package")]
    stages: Vec<String>,
    /// Python interpreter with the engines' packages (bpy, mujoco, opencv).
    #[arg(long, env = "VINT_PYTHON")]
    python: Option<PathBuf>,
    /// Directory holding the vint_engines package.
    #[arg(long, env = "VINT_ENGINES_DIR")]
    engines_dir: Option<PathBuf>,
    /// Scratch directory for staged inputs and outputs.
    #[arg(long, env = "VINT_SCRATCH")]
    scratch: Option<PathBuf>,
    /// Lease length requested from the coordinator, in milliseconds; heartbeats renew it.
    #[arg(long, env = "VINT_LEASE_MS", default_value_t = 30_000)]
    lease_ms: u32,
    /// Longest one task may run in an engine, in seconds.
    #[arg(long, env = "VINT_TASK_TIMEOUT_S", default_value_t = 1_800)]
    task_timeout_s: u64,
    /// Replace an engine process after this many tasks (0: never).
    #[arg(long, env = "VINT_ENGINE_MAX_TASKS", default_value_t = 0)]
    engine_max_tasks: u32,
    /// Replace an engine process, between tasks, once its resident memory exceeds this many MiB
    /// (0: never). Blender and MuJoCo hold their scenes between tasks; this bounds any slow leak.
    #[arg(long, env = "VINT_ENGINE_MAX_RSS_MIB", default_value_t = 8_192)]
    engine_max_rss_mib: u64,
    /// Most memory (MiB) one engine process may allocate, set on it as RLIMIT_DATA: a task that
    /// asks for more fails (permanently, naming the limit) instead of exhausting the node (0: no
    /// limit).
    #[arg(long, env = "VINT_ENGINE_MEMORY_LIMIT_MIB", default_value_t = 16_384)]
    engine_memory_limit_mib: u64,
    /// Run every task leased, even one whose result (same stage, engine identity, parameters and
    /// input contents) is already in the store; what this worker makes is then not reusable.
    /// By default the worker declares its engines' identities and such tasks are reused.
    #[arg(long, env = "VINT_NO_REUSE")]
    no_reuse: bool,
    /// Worker id (default: host name, process id and a random suffix).
    #[arg(long, env = "VINT_WORKER_ID")]
    worker_id: Option<String>,
    /// Log as JSON lines.
    #[arg(long, env = "VINT_LOG_JSON")]
    log_json: bool,
    /// Address to serve HTTP on: Prometheus metrics at /metrics, a health check at /healthz
    /// (200 while the worker's loop comes around). Off when not given.
    #[arg(long, env = "VINT_METRICS_LISTEN")]
    metrics_listen: Option<SocketAddr>,
    /// `engines` runs each task in its engine (the default, and the only mode that makes data);
    /// `timing-only` runs none and answers each task with outputs of the real names and sizes
    /// but constant bytes, to measure the coordinator, database and store at scale.
    #[arg(long, env = "VINT_ENGINE_MODE", value_enum, default_value_t = EngineMode::Engines)]
    engine_mode: EngineMode,
    /// timing-only: share of grasp trials accepted (by their seeds). 0.84 is the built-in
    /// objects' mean (docs/physics.md).
    #[arg(long, env = "VINT_ACCEPT_RATE", default_value_t = 0.84, value_parser = share)]
    accept_rate: f64,
    /// Tasks per lease (1–256; default 1 with engines, 64 timing-only). With engines, a batch
    /// above 1 suits short tasks (noise, package): the next lease is in flight while a batch's
    /// last task runs, and one heartbeat keeps every leased task's lease. Timing-only: also tasks
    /// per completion call.
    #[arg(long, env = "VINT_WORKER_BATCH", value_parser = clap::value_parser!(u32).range(1..=256))]
    batch: Option<u32>,
    /// timing-only: lease-and-complete loops in flight (1–64).
    #[arg(long, env = "VINT_CONCURRENCY", default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=64))]
    concurrency: u32,
    /// timing-only: append one CSV line per batch (unix_ms,slot,tasks,lease_ms,complete_ms).
    #[arg(long, env = "VINT_LATENCY_LOG")]
    latency_log: Option<PathBuf>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum EngineMode {
    Engines,
    TimingOnly,
}

fn share(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(x) if (0.0..=1.0).contains(&x) => Ok(x),
        _ => Err(format!("{s:?} is not a share in [0, 1]")),
    }
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    vint_telemetry::init_tracing(args.log_json);
    let stages = args.stages.iter().map(|s| s.parse::<Stage>()).collect::<Result<Vec<_>, _>>().context("--stages")?;
    let checkout = vint_engine_env::EngineEnv::checkout();
    let worker_id = args.worker_id.unwrap_or_else(|| {
        let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_else(|_| "host".into());
        format!("{}-{}-{}", host.trim(), std::process::id(), &uuid::Uuid::new_v4().simple().to_string()[..6])
    });
    let scratch = args.scratch.unwrap_or_else(|| std::env::temp_dir().join(format!("vint-worker-{worker_id}")));
    let store = ArtifactStore::open(&args.store)
        .with_context(|| format!("opening artifact store {}", vint_telemetry::redact_url(&args.store)))?;
    let max_idle_poll = Duration::from_millis(500);
    let metrics = WorkerMetrics::new(liveness_limit(args.lease_ms, max_idle_poll));
    metrics.serving(&stages);
    if let Some(addr) = args.metrics_listen {
        let listener =
            tokio::net::TcpListener::bind(addr).await.with_context(|| format!("binding --metrics-listen {addr}"))?;
        tracing::info!(addr = %listener.local_addr()?, "serving /metrics and /healthz");
        // Serves until the process exits: the last scrape sees the finished worker.
        tokio::spawn(vint_telemetry::serve_http(listener, metrics.router(), std::future::pending()));
    }
    let coordinator = vint_connect::Remote { url: args.coordinator, token: args.token, tls_ca: args.tls_ca };
    if args.engine_mode == EngineMode::TimingOnly {
        let config = TimingOnlyConfig {
            coordinator,
            worker_id,
            stages,
            lease_ms: args.lease_ms,
            accept_rate: args.accept_rate,
            batch: args.batch.unwrap_or(64),
            concurrency: args.concurrency,
            max_idle_poll,
            latency_log: args.latency_log,
            metrics,
        };
        tracing::warn!(worker = %config.worker_id, stages = ?config.stages, batch = config.batch,
            concurrency = config.concurrency, "worker starting in timing-only mode: no engine runs, outputs are not data");
        timing_only::run(config, store, shutdown_signal()).await?;
        return Ok(());
    }
    let config = WorkerConfig {
        coordinator,
        worker_id,
        stages,
        lease_ms: args.lease_ms,
        scratch: scratch.clone(),
        engine: EngineCommand {
            python: args.python.unwrap_or(checkout.python),
            engines_dir: args.engines_dir.unwrap_or(checkout.engines_dir),
            task_timeout: Duration::from_secs(args.task_timeout_s),
            start_timeout: Duration::from_secs(120),
            recycle: RecyclePolicy {
                max_tasks: Some(args.engine_max_tasks).filter(|&n| n > 0),
                max_rss_bytes: Some(args.engine_max_rss_mib << 20).filter(|&n| n > 0),
            },
            memory_limit_mib: Some(args.engine_memory_limit_mib).filter(|&n| n > 0),
        },
        max_idle_poll,
        batch: args.batch.unwrap_or(1),
        metrics,
        reuse: !args.no_reuse,
    };
    tracing::info!(worker = %config.worker_id, stages = ?config.stages, batch = config.batch, "worker starting");
    let worker = Worker::new(config, store)?;
    worker.run(shutdown_signal()).await;
    let _ = std::fs::remove_dir_all(&scratch);
    Ok(())
}

/// Resolves on SIGINT or SIGTERM.
async fn shutdown_signal() {
    let mut term = match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
        Ok(s) => s,
        Err(_) => {
            let _ = tokio::signal::ctrl_c().await;
            return;
        }
    };
    tokio::select! {
        _ = tokio::signal::ctrl_c() => {}
        _ = term.recv() => {}
    }
}

#[cfg(test)]
mod tests {
    use clap::CommandFactory;

    use super::Args;

    /// A deployment configures a process through its environment (a ConfigMap, a Secret): every
    /// flag has a `VINT_*` variable.
    #[test]
    fn every_flag_has_an_environment_variable() {
        let command = Args::command();
        let missing: Vec<String> = command
            .get_arguments()
            .filter(|a| a.get_long().is_some_and(|l| l != "help" && l != "version"))
            .filter(|a| !a.get_env().is_some_and(|e| e.to_string_lossy().starts_with("VINT_")))
            .map(|a| format!("--{}", a.get_long().unwrap_or_default()))
            .collect();
        assert!(missing.is_empty(), "flags without a VINT_* environment variable: {missing:?}");
    }
}
