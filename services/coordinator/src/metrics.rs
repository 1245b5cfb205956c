//! What the coordinator measures, served at `/metrics` when it serves HTTP (`--http-listen`;
//! every metric is listed with its labels and meaning in docs/operations.md).
//!
//! Counters and latencies are recorded on the request path by the gRPC services; gauges of the
//! queue (`vint_queue_tasks`, what an autoscaler scales each worker stage on) and of jobs are
//! refreshed off it, by the reaper loop, from one store read (`Store::queue_depth`). Several
//! coordinators over one database each report the same queue: aggregate those with `max`, and
//! the counters with `sum`.

use std::sync::Arc;
use std::time::Instant;

use prometheus_client::encoding::EncodeLabelSet;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::Histogram;
use prometheus_client::registry::Registry;
use vint_core::{AttemptOutcome, JobState, Stage};
use vint_store::{LIVE_TASK_STATES, QueueDepth};

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct StageLabels {
    stage: &'static str,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct FailureLabels {
    stage: &'static str,
    /// `retry` (requeued after a backoff) or `failed` (for good): `AttemptOutcome`'s names.
    outcome: &'static str,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct RefusalLabels {
    reason: &'static str,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct RpcLabels {
    rpc: &'static str,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct QueueLabels {
    stage: &'static str,
    state: &'static str,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct JobLabels {
    state: &'static str,
}

type HistogramFamily<L> = Family<L, Histogram, fn() -> Histogram>;

fn rpc_histogram() -> Histogram {
    Histogram::new(vint_telemetry::rpc_seconds_buckets())
}

/// Why the coordinator refused a worker's completion.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refusal {
    /// The worker no longer held the lease (expired, cancelled or taken over).
    LeaseLost,
    /// The report broke a rule (an output key that is not its content key, a bad name, a result
    /// the planner cannot read).
    Invalid,
    /// No such task.
    NotFound,
}

impl Refusal {
    fn as_str(self) -> &'static str {
        match self {
            Refusal::LeaseLost => "lease_lost",
            Refusal::Invalid => "invalid",
            Refusal::NotFound => "not_found",
        }
    }
}

/// A worker API call, as `vint_rpc_duration_seconds` labels it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rpc {
    LeaseTasks,
    CompleteTask,
    CompleteTasks,
    Heartbeat,
    FailTask,
}

impl Rpc {
    const ALL: [Rpc; 5] = [Rpc::LeaseTasks, Rpc::CompleteTask, Rpc::CompleteTasks, Rpc::Heartbeat, Rpc::FailTask];

    fn as_str(self) -> &'static str {
        match self {
            Rpc::LeaseTasks => "lease_tasks",
            Rpc::CompleteTask => "complete_task",
            Rpc::CompleteTasks => "complete_tasks",
            Rpc::Heartbeat => "heartbeat",
            Rpc::FailTask => "fail_task",
        }
    }
}

/// The coordinator's metrics and the registry that exports them. Clones share the metrics.
#[derive(Clone, Debug)]
pub struct Metrics {
    registry: Arc<Registry>,
    tasks_leased: Family<StageLabels, Counter>,
    tasks_completed: Family<StageLabels, Counter>,
    tasks_reused: Family<StageLabels, Counter>,
    tasks_failed: Family<FailureLabels, Counter>,
    completions_refused: Family<RefusalLabels, Counter>,
    leases_expired: Counter,
    jobs_submitted: Counter,
    rpc_seconds: HistogramFamily<RpcLabels>,
    queue_tasks: Family<QueueLabels, Gauge>,
    jobs: Family<JobLabels, Gauge>,
    watch_streams: Gauge,
    database_up: Gauge,
}

/// One open `WatchJob` stream, counted in `vint_watch_streams` until it is dropped.
#[derive(Debug)]
pub(crate) struct OpenWatch(Gauge);

impl Drop for OpenWatch {
    fn drop(&mut self) {
        self.0.dec();
    }
}

impl Default for Metrics {
    fn default() -> Self {
        Metrics::new()
    }
}

impl Metrics {
    pub fn new() -> Metrics {
        // prometheus-client ends each help text with a period.
        let mut registry = Registry::default();
        vint_telemetry::register_build_info(&mut registry, "coordinator", env!("CARGO_PKG_VERSION"));
        let tasks_leased = Family::default();
        registry.register("vint_tasks_leased", "Tasks handed to workers, by stage", Family::clone(&tasks_leased));
        let tasks_completed = Family::default();
        registry.register(
            "vint_tasks_completed",
            "Task completions recorded, by stage",
            Family::clone(&tasks_completed),
        );
        let tasks_reused = Family::default();
        registry.register(
            "vint_tasks_reused",
            "Tasks completed from a finished task's result with the same reuse key instead of running, by stage",
            Family::clone(&tasks_reused),
        );
        let tasks_failed = Family::default();
        registry.register(
            "vint_tasks_failed",
            "Task failures workers reported, by stage and outcome: retry (requeued after a backoff) or \
             failed (for good: not retryable, or out of attempts)",
            Family::clone(&tasks_failed),
        );
        let completions_refused = Family::default();
        registry.register(
            "vint_completions_refused",
            "Completions refused, by reason: lease_lost, invalid (a report that breaks the rules), not_found",
            Family::clone(&completions_refused),
        );
        let leases_expired = Counter::default();
        registry.register(
            "vint_leases_expired",
            "Leases the reaper ended because the worker stopped heartbeating; each task was requeued (or \
             failed, out of attempts)",
            leases_expired.clone(),
        );
        let jobs_submitted = Counter::default();
        registry.register(
            "vint_jobs_submitted",
            "Jobs created (a resubmission is not counted)",
            jobs_submitted.clone(),
        );
        let rpc_seconds = HistogramFamily::new_with_constructor(rpc_histogram as fn() -> Histogram);
        registry.register(
            "vint_rpc_duration_seconds",
            "Worker API call latency in the coordinator, by rpc (lease_tasks, complete_task, complete_tasks, \
             heartbeat, fail_task)",
            rpc_seconds.clone(),
        );
        let queue_tasks = Family::default();
        registry.register(
            "vint_queue_tasks",
            "Live tasks by stage and state (waiting: on dependencies; queued: ready to lease; running: leased), \
             refreshed every few seconds. Scale each worker stage on it",
            Family::clone(&queue_tasks),
        );
        let jobs = Family::default();
        registry.register("vint_jobs", "Jobs by state, refreshed every few seconds", Family::clone(&jobs));
        let watch_streams = Gauge::default();
        registry.register(
            "vint_watch_streams",
            "WatchJob streams open, each polling the store; one ends with its job or when its client leaves",
            watch_streams.clone(),
        );
        let database_up = Gauge::default();
        registry.register(
            "vint_database_up",
            "1 while the database answered the reaper's last call (every reap interval), 0 after it failed to connect",
            database_up.clone(),
        );
        database_up.set(1);
        let metrics = Metrics {
            registry: Arc::new(registry),
            tasks_leased,
            tasks_completed,
            tasks_reused,
            tasks_failed,
            completions_refused,
            leases_expired,
            jobs_submitted,
            rpc_seconds,
            queue_tasks,
            jobs,
            watch_streams,
            database_up,
        };
        // Every series exists from the start, at 0: a rate or an autoscaler query needs no
        // special case for a stage that has not run yet.
        for stage in Stage::ALL {
            let s = stage.as_str();
            let _ = metrics.tasks_leased.get_or_create(&StageLabels { stage: s });
            let _ = metrics.tasks_completed.get_or_create(&StageLabels { stage: s });
            let _ = metrics.tasks_reused.get_or_create(&StageLabels { stage: s });
            for outcome in [AttemptOutcome::Retry, AttemptOutcome::Failed] {
                let _ = metrics.tasks_failed.get_or_create(&FailureLabels { stage: s, outcome: outcome.as_str() });
            }
        }
        for reason in [Refusal::LeaseLost, Refusal::Invalid, Refusal::NotFound] {
            let _ = metrics.completions_refused.get_or_create(&RefusalLabels { reason: reason.as_str() });
        }
        for rpc in Rpc::ALL {
            let _ = metrics.rpc_seconds.get_or_create(&RpcLabels { rpc: rpc.as_str() });
        }
        metrics.set_queue_depth(&QueueDepth::default());
        metrics
    }

    /// The registry `/metrics` encodes.
    pub fn registry(&self) -> Arc<Registry> {
        self.registry.clone()
    }

    /// Whether the database answered the reaper's last call (`vint_database_up`).
    pub(crate) fn set_database_up(&self, up: bool) {
        self.database_up.set(i64::from(up));
    }

    /// A `WatchJob` stream opened; it counts until the returned guard is dropped.
    pub(crate) fn watch_opened(&self) -> OpenWatch {
        self.watch_streams.inc();
        OpenWatch(self.watch_streams.clone())
    }

    pub(crate) fn task_leased(&self, stage: Stage) {
        self.tasks_leased.get_or_create(&StageLabels { stage: stage.as_str() }).inc();
    }

    pub(crate) fn task_completed(&self, stage: Stage) {
        self.tasks_completed.get_or_create(&StageLabels { stage: stage.as_str() }).inc();
    }

    pub(crate) fn task_reused(&self, stage: Stage) {
        self.tasks_reused.get_or_create(&StageLabels { stage: stage.as_str() }).inc();
    }

    /// A reported failure, by what became of the task.
    pub(crate) fn task_failed(&self, stage: Stage, will_retry: bool) {
        let outcome = if will_retry { AttemptOutcome::Retry } else { AttemptOutcome::Failed };
        self.tasks_failed.get_or_create(&FailureLabels { stage: stage.as_str(), outcome: outcome.as_str() }).inc();
    }

    pub(crate) fn completion_refused(&self, reason: Refusal) {
        self.completions_refused.get_or_create(&RefusalLabels { reason: reason.as_str() }).inc();
    }

    pub(crate) fn leases_expired(&self, n: u64) {
        self.leases_expired.inc_by(n);
    }

    pub(crate) fn job_submitted(&self) {
        self.jobs_submitted.inc();
    }

    /// Times a worker API call: the latency is observed when the returned guard drops, so every
    /// return of the handler counts, errors too.
    pub(crate) fn time_rpc(&self, rpc: Rpc) -> RpcTimer {
        let histogram = self.rpc_seconds.get_or_create_owned(&RpcLabels { rpc: rpc.as_str() });
        RpcTimer { histogram, started: Instant::now() }
    }

    /// Sets the queue and job gauges to `depth`, every (stage, live state) and job state included.
    pub(crate) fn set_queue_depth(&self, depth: &QueueDepth) {
        for stage in Stage::ALL {
            for state in LIVE_TASK_STATES {
                let n = i64::try_from(depth.tasks_in(stage, state)).unwrap_or(i64::MAX);
                self.queue_tasks.get_or_create(&QueueLabels { stage: stage.as_str(), state: state.as_str() }).set(n);
            }
        }
        for state in JobState::ALL {
            let n = i64::try_from(depth.jobs_in(state)).unwrap_or(i64::MAX);
            self.jobs.get_or_create(&JobLabels { state: state.as_str() }).set(n);
        }
    }
}

/// Observes the time since it was made into its histogram when dropped.
pub(crate) struct RpcTimer {
    histogram: Histogram,
    started: Instant,
}

impl Drop for RpcTimer {
    fn drop(&mut self) {
        self.histogram.observe(self.started.elapsed().as_secs_f64());
    }
}
