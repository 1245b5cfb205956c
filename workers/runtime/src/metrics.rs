//! What a worker measures, served at `/metrics` when it serves HTTP (`--metrics-listen`; every
//! metric is listed in docs/operations.md), and its health at `/healthz`: 200 while its loop
//! comes around (`Liveness`), 503 once it has not for `liveness_limit`.
//!
//! The engine worker and the timing-only worker record the same task counters; only the engine
//! worker has engines to time and restart.

use std::sync::Arc;
use std::time::Duration;

use prometheus_client::encoding::EncodeLabelSet;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::histogram::Histogram;
use prometheus_client::registry::Registry;
use vint_core::Stage;
use vint_telemetry::Liveness;

use crate::engine::{EngineError, Recycle};

/// How a task this worker leased ended, as far as the worker knows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TaskOutcome {
    /// The coordinator recorded its completion.
    Completed,
    /// It failed and the worker reported it as worth retrying.
    RetryableFailure,
    /// It failed and the worker reported it as permanent (bad input).
    PermanentFailure,
    /// The lease was lost (while it ran, or at completion): its result was discarded.
    LeaseLost,
    /// The coordinator refused the completion for another reason (an invalid report).
    Refused,
    /// The worker could not reach the coordinator to report it; its lease will expire.
    Unreported,
}

impl TaskOutcome {
    pub const ALL: [TaskOutcome; 6] = [
        TaskOutcome::Completed,
        TaskOutcome::RetryableFailure,
        TaskOutcome::PermanentFailure,
        TaskOutcome::LeaseLost,
        TaskOutcome::Refused,
        TaskOutcome::Unreported,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            TaskOutcome::Completed => "completed",
            TaskOutcome::RetryableFailure => "retryable_failure",
            TaskOutcome::PermanentFailure => "permanent_failure",
            TaskOutcome::LeaseLost => "lease_lost",
            TaskOutcome::Refused => "refused",
            TaskOutcome::Unreported => "unreported",
        }
    }
}

/// Why an engine process was replaced.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RestartReason {
    /// It exited or its pipes failed.
    Crash,
    /// It broke the protocol or its stage's contract.
    Protocol,
    /// It overran a task's (or its start-up's) deadline and was killed.
    Timeout,
    /// It served `--engine-max-tasks` tasks.
    MaxTasks,
    /// Its resident memory passed `--engine-max-rss-mib`.
    MaxRss,
}

impl RestartReason {
    pub const ALL: [RestartReason; 5] = [
        RestartReason::Crash,
        RestartReason::Protocol,
        RestartReason::Timeout,
        RestartReason::MaxTasks,
        RestartReason::MaxRss,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            RestartReason::Crash => "crash",
            RestartReason::Protocol => "protocol",
            RestartReason::Timeout => "timeout",
            RestartReason::MaxTasks => "max_tasks",
            RestartReason::MaxRss => "max_rss",
        }
    }

    /// Why an engine that failed a task is replaced.
    pub fn of_error(error: &EngineError) -> RestartReason {
        match error {
            EngineError::Spawn { .. } | EngineError::Crashed { .. } => RestartReason::Crash,
            EngineError::TimedOut { .. } => RestartReason::Timeout,
            EngineError::Protocol { .. } => RestartReason::Protocol,
        }
    }

    /// Why a warm engine past its limits is replaced.
    pub fn of_recycle(recycle: &Recycle) -> RestartReason {
        match recycle {
            Recycle::Tasks { .. } => RestartReason::MaxTasks,
            Recycle::Memory { .. } => RestartReason::MaxRss,
        }
    }
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct StageLabels {
    stage: &'static str,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct TaskLabels {
    stage: &'static str,
    outcome: &'static str,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct RestartLabels {
    stage: &'static str,
    reason: &'static str,
}

type HistogramFamily<L> = Family<L, Histogram, fn() -> Histogram>;

fn task_histogram() -> Histogram {
    Histogram::new(vint_telemetry::task_seconds_buckets())
}

/// The longest a healthy worker's loop goes without coming around: it beats on every lease poll
/// (at most `max_idle_poll` apart) and every heartbeat (a third of the lease), and reporting a
/// task retries through a coordinator outage for up to a lease and a minute.
pub fn liveness_limit(lease_ms: u32, max_idle_poll: Duration) -> Duration {
    let lease = Duration::from_millis(u64::from(lease_ms));
    (2 * lease + Duration::from_secs(60)).max(20 * max_idle_poll)
}

/// A worker's metrics, its liveness and the registry that exports them. Clones share them.
#[derive(Clone, Debug)]
pub struct WorkerMetrics {
    registry: Arc<Registry>,
    liveness: Liveness,
    tasks: Family<TaskLabels, Counter>,
    engine_seconds: HistogramFamily<StageLabels>,
    fetch_seconds: HistogramFamily<StageLabels>,
    upload_seconds: HistogramFamily<StageLabels>,
    downloaded_bytes: Counter,
    uploaded_bytes: Counter,
    engine_restarts: Family<RestartLabels, Counter>,
    leases_lost: Counter,
}

impl Default for WorkerMetrics {
    /// Metrics nobody serves, with a liveness for the default lease (30 s) and idle poll (0.5 s).
    fn default() -> Self {
        WorkerMetrics::new(liveness_limit(30_000, Duration::from_millis(500)))
    }
}

impl WorkerMetrics {
    /// Metrics for a worker whose loop is unhealthy once it has not come around for `stale_after`
    /// (`liveness_limit`).
    pub fn new(stale_after: Duration) -> WorkerMetrics {
        // prometheus-client ends each help text with a period.
        let mut registry = Registry::default();
        vint_telemetry::register_build_info(&mut registry, "worker", env!("CARGO_PKG_VERSION"));
        let tasks = Family::default();
        registry.register(
            "vint_worker_tasks",
            "Tasks this worker finished, by stage and outcome (completed, retryable_failure, \
             permanent_failure, lease_lost, refused, unreported)",
            Family::clone(&tasks),
        );
        let histogram = |registry: &mut Registry, name: &str, help: &str| {
            let family = HistogramFamily::new_with_constructor(task_histogram as fn() -> Histogram);
            registry.register(name, help, family.clone());
            family
        };
        let engine_seconds = histogram(
            &mut registry,
            "vint_worker_engine_seconds",
            "Time a task spent in its engine (the package stage: packaging), by stage",
        );
        let fetch_seconds =
            histogram(&mut registry, "vint_worker_fetch_seconds", "Time staging a task's inputs, by stage");
        let upload_seconds =
            histogram(&mut registry, "vint_worker_upload_seconds", "Time uploading a task's outputs, by stage");
        let downloaded_bytes = Counter::default();
        registry.register(
            "vint_worker_downloaded_bytes",
            "Artifact bytes read from the object store",
            downloaded_bytes.clone(),
        );
        let uploaded_bytes = Counter::default();
        registry.register(
            "vint_worker_uploaded_bytes",
            "Artifact bytes written to the object store",
            uploaded_bytes.clone(),
        );
        let engine_restarts = Family::default();
        registry.register(
            "vint_worker_engine_restarts",
            "Engine processes replaced, by stage and reason (crash, protocol, timeout, max_tasks, max_rss)",
            Family::clone(&engine_restarts),
        );
        let leases_lost = Counter::default();
        registry.register(
            "vint_worker_leases_lost",
            "Leases a heartbeat found lost (expired, cancelled or taken over) while this worker held them",
            leases_lost.clone(),
        );
        let metrics = WorkerMetrics {
            registry: Arc::new(registry),
            liveness: Liveness::new("worker loop", stale_after),
            tasks,
            engine_seconds,
            fetch_seconds,
            upload_seconds,
            downloaded_bytes,
            uploaded_bytes,
            engine_restarts,
            leases_lost,
        };
        for stage in Stage::ALL {
            for outcome in TaskOutcome::ALL {
                let _ = metrics.tasks.get_or_create(&TaskLabels { stage: stage.as_str(), outcome: outcome.as_str() });
            }
        }
        metrics
    }

    /// `/metrics` and `/healthz` for this worker.
    pub fn router(&self) -> vint_telemetry::Router {
        vint_telemetry::router(self.registry.clone(), self.liveness.clone())
    }

    /// The registry `/metrics` encodes.
    pub fn registry(&self) -> Arc<Registry> {
        self.registry.clone()
    }

    /// Creates the per-stage series of `stages` at zero, so a scrape (and a dashboard query) sees
    /// every stage this worker serves before its first task, and a stage with no engine runs yet
    /// reads as none rather than as missing.
    pub fn serving(&self, stages: &[Stage]) {
        for stage in stages {
            let labels = StageLabels { stage: stage.as_str() };
            drop(self.engine_seconds.get_or_create(&labels));
            drop(self.fetch_seconds.get_or_create(&labels));
            drop(self.upload_seconds.get_or_create(&labels));
            for reason in RestartReason::ALL {
                drop(
                    self.engine_restarts
                        .get_or_create(&RestartLabels { stage: stage.as_str(), reason: reason.as_str() }),
                );
            }
        }
    }

    /// The worker's loop came around (a lease poll, a heartbeat).
    pub fn beat(&self) {
        self.liveness.beat();
    }

    pub fn task_finished(&self, stage: Stage, outcome: TaskOutcome) {
        self.tasks.get_or_create(&TaskLabels { stage: stage.as_str(), outcome: outcome.as_str() }).inc();
    }

    pub fn engine_ran(&self, stage: Stage, took: Duration) {
        self.engine_seconds.get_or_create(&StageLabels { stage: stage.as_str() }).observe(took.as_secs_f64());
    }

    pub fn fetched(&self, stage: Stage, bytes: u64, took: Duration) {
        self.downloaded_bytes.inc_by(bytes);
        self.fetch_seconds.get_or_create(&StageLabels { stage: stage.as_str() }).observe(took.as_secs_f64());
    }

    pub fn uploaded(&self, stage: Stage, bytes: u64, took: Duration) {
        self.uploaded_bytes.inc_by(bytes);
        self.upload_seconds.get_or_create(&StageLabels { stage: stage.as_str() }).observe(took.as_secs_f64());
    }

    /// Bytes moved outside a timed fetch or upload (the package stage's reads and writes, the
    /// timing-only worker's payloads).
    pub fn moved_bytes(&self, downloaded: u64, uploaded: u64) {
        self.downloaded_bytes.inc_by(downloaded);
        self.uploaded_bytes.inc_by(uploaded);
    }

    pub fn engine_restarted(&self, stage: Stage, reason: RestartReason) {
        self.engine_restarts.get_or_create(&RestartLabels { stage: stage.as_str(), reason: reason.as_str() }).inc();
    }

    pub fn leases_lost(&self, n: u64) {
        self.leases_lost.inc_by(n);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn exposition(metrics: &WorkerMetrics) -> String {
        let mut text = String::new();
        prometheus_client::encoding::text::encode(&mut text, &metrics.registry()).unwrap();
        text
    }

    #[test]
    fn recorded_work_shows_in_the_exposition() {
        let metrics = WorkerMetrics::default();
        let before = exposition(&metrics);
        assert!(before.contains("vint_worker_tasks_total{stage=\"render\",outcome=\"completed\"} 0\n"), "{before}");
        let build = format!("vint_build_info{{component=\"worker\",version=\"{}\"}} 1\n", env!("CARGO_PKG_VERSION"));
        assert!(before.contains(&build), "{before}");
        metrics.task_finished(Stage::Render, TaskOutcome::Completed);
        metrics.task_finished(Stage::Render, TaskOutcome::Completed);
        metrics.task_finished(Stage::Grasp, TaskOutcome::LeaseLost);
        metrics.fetched(Stage::Render, 1_000, Duration::from_millis(30));
        metrics.uploaded(Stage::Render, 5_000, Duration::from_millis(20));
        metrics.moved_bytes(24, 6);
        metrics.engine_ran(Stage::Render, Duration::from_secs(3));
        metrics.engine_restarted(Stage::Render, RestartReason::MaxRss);
        metrics.leases_lost(2);
        let after = exposition(&metrics);
        for line in [
            "vint_worker_tasks_total{stage=\"render\",outcome=\"completed\"} 2\n",
            "vint_worker_tasks_total{stage=\"grasp\",outcome=\"lease_lost\"} 1\n",
            "vint_worker_downloaded_bytes_total 1024\n",
            "vint_worker_uploaded_bytes_total 5006\n",
            "vint_worker_engine_seconds_count{stage=\"render\"} 1\n",
            "vint_worker_engine_seconds_bucket{le=\"2.56\",stage=\"render\"} 0\n",
            "vint_worker_engine_seconds_bucket{le=\"5.12\",stage=\"render\"} 1\n",
            "vint_worker_engine_restarts_total{stage=\"render\",reason=\"max_rss\"} 1\n",
            "vint_worker_leases_lost_total 2\n",
        ] {
            assert!(after.contains(line), "missing {line:?} in\n{after}");
        }
    }

    #[test]
    fn the_liveness_limit_covers_a_heartbeat_and_a_report_through_an_outage() {
        assert_eq!(liveness_limit(30_000, Duration::from_millis(500)), Duration::from_secs(120));
        assert_eq!(liveness_limit(1_000, Duration::from_secs(10)), Duration::from_secs(200));
    }
}
