//! The worker loop: lease a task, stage its inputs, run it (engine or in-process package stage),
//! upload its outputs, and complete or fail it, heartbeating all the while.
//!
//! A worker keeps one engine per stage it has served, alive between tasks. It survives a
//! coordinator restart (RPCs are retried with backoff) and never completes a task whose lease it
//! has lost. It holds no durable state: kill it at any moment and its task is leased again. Asked
//! to stop (SIGTERM), it does not wait for a task that may run for half an hour: it kills the
//! engine and gives the lease back (`ReleaseTasks`), so the task is queued again at once.

use std::collections::HashMap;
use std::future::Future;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use serde_json::Value;
use tonic::{Code, Status};
use tracing::Instrument;
use vint_artifacts::ArtifactStore;
use vint_connect::AuthChannel;
use vint_core::{Stage, contract};
use vint_proto::v1 as pb;
use vint_proto::v1::work_service_client::WorkServiceClient;

use crate::engine::{Engine, EngineCommand, EngineInput};
use crate::metrics::{RestartReason, TaskOutcome, WorkerMetrics};
use crate::package::{self, PackageInput};

#[derive(Clone, Debug)]
pub struct WorkerConfig {
    /// The coordinator (URL, e.g. `http://127.0.0.1:7700`, TLS trust and token).
    pub coordinator: vint_connect::Remote,
    pub worker_id: String,
    pub stages: Vec<Stage>,
    pub lease_ms: u32,
    /// Directory for staged inputs and engine outputs; one subdirectory per task attempt.
    pub scratch: PathBuf,
    pub engine: EngineCommand,
    /// Longest pause between lease polls when there is no work.
    pub max_idle_poll: Duration,
    /// Where the worker records what it does (`--metrics-listen` serves it).
    pub metrics: WorkerMetrics,
    /// Whether the worker declares its engines' identities when it leases, so that tasks whose
    /// result is already in the store are reused instead of run (`vint_core::reuse`). Off, every
    /// task it leases runs, and what it makes is not reusable.
    pub reuse: bool,
}

#[derive(Debug, thiserror::Error)]
pub enum WorkerError {
    #[error(transparent)]
    Connect(#[from] vint_connect::ConnectError),
    #[error("opening the latency log {path}: {source}")]
    LatencyLog { path: PathBuf, source: std::io::Error },
}

/// Why a task attempt did not complete.
#[derive(Debug)]
struct TaskFailure {
    retryable: bool,
    message: String,
}

impl TaskFailure {
    fn retryable(message: impl Into<String>) -> Self {
        TaskFailure { retryable: true, message: message.into() }
    }
    fn permanent(message: impl Into<String>) -> Self {
        TaskFailure { retryable: false, message: message.into() }
    }
}

/// How serving one task ended.
#[derive(Debug, PartialEq, Eq)]
enum Served {
    /// Reported (or found lost): the worker goes on.
    Done,
    /// Shutdown came first: the task was given back and the worker stops.
    Stopped,
}

struct Finished {
    outputs: Vec<pb::ArtifactRef>,
    engine_json: String,
    result_json: String,
    timings: pb::Timings,
}

pub struct Worker {
    config: WorkerConfig,
    client: WorkServiceClient<AuthChannel>,
    store: ArtifactStore,
    engines: HashMap<Stage, Engine>,
    /// The identity of the engine of each stage it declares (empty without reuse).
    identities: HashMap<Stage, String>,
}

impl Worker {
    pub fn new(config: WorkerConfig, store: ArtifactStore) -> Result<Worker, WorkerError> {
        let endpoint = config.coordinator.endpoint()?.connect_timeout(Duration::from_secs(5));
        let client = WorkServiceClient::new(config.coordinator.lazy_channel(endpoint)?);
        Ok(Worker { config, client, store, engines: HashMap::new(), identities: HashMap::new() })
    }

    /// The identities to declare: the package stage's constant and the Python engines' (read
    /// once, at start). An environment whose identities cannot be read declares none for its
    /// Python stages: their tasks then run, and are not reusable.
    async fn read_identities(&self) -> HashMap<Stage, String> {
        let mut out = HashMap::new();
        if !self.config.reuse {
            return out;
        }
        if self.config.stages.contains(&Stage::Package) {
            out.insert(Stage::Package, package::IDENTITY.to_string());
        }
        if self.config.stages.iter().any(|s| *s != Stage::Package) {
            match crate::engine::identities(&self.config.engine).await {
                Ok(found) => {
                    out.extend(found.into_iter().filter(|(s, _)| self.config.stages.contains(s)));
                }
                Err(e) => {
                    tracing::warn!(error = %e, "engine identities unknown: this worker's tasks run and are not reusable")
                }
            }
        }
        out
    }

    /// Serves tasks until `shutdown` resolves. A task still running then is stopped (its engine
    /// killed) and its lease given back; one already being reported is reported first.
    pub async fn run(mut self, shutdown: impl Future<Output = ()>) {
        tokio::pin!(shutdown);
        let stages: Vec<String> = self.config.stages.iter().map(|s| s.as_str().to_string()).collect();
        self.identities = self.read_identities().await;
        let engines: HashMap<String, String> =
            self.identities.iter().map(|(s, id)| (s.as_str().to_string(), id.clone())).collect();
        tracing::info!(worker = %self.config.worker_id, engines = ?engines, "engine identities");
        let mut idle = Duration::from_millis(50);
        loop {
            self.config.metrics.beat();
            let request = pb::LeaseTasksRequest {
                worker_id: self.config.worker_id.clone(),
                stages: stages.clone(),
                capacity: 1,
                lease_ms: self.config.lease_ms,
                engines: engines.clone(),
            };
            let mut client = self.client.clone();
            let lease = client.lease_tasks(request);
            tokio::pin!(lease);
            let (leased, stopping) = tokio::select! {
                r = &mut lease => (r, false),
                // The coordinator may have granted the lease in flight: take it, to give it back.
                () = &mut shutdown => {
                    let r = tokio::time::timeout(RELEASE_TIMEOUT, &mut lease).await;
                    (r.unwrap_or_else(|_| Err(Status::deadline_exceeded("lease in flight at shutdown"))), true)
                }
            };
            if stopping {
                if let Ok(resp) = leased {
                    for task in resp.into_inner().tasks {
                        self.release(&task).await;
                    }
                }
                break;
            }
            match leased {
                Ok(resp) if !resp.get_ref().tasks.is_empty() => {
                    idle = Duration::from_millis(50);
                    let mut stopped = false;
                    for task in resp.into_inner().tasks {
                        if stopped {
                            self.release(&task).await;
                        } else {
                            stopped = self.serve(task, shutdown.as_mut()).await == Served::Stopped;
                        }
                    }
                    if stopped {
                        break;
                    }
                    continue;
                }
                Ok(_) => {}
                Err(status) => log_lease_failure(&status),
            }
            tokio::select! {
                _ = &mut shutdown => break,
                _ = tokio::time::sleep(idle) => {}
            }
            idle = (idle * 2).min(self.config.max_idle_poll);
        }
        for (_, engine) in self.engines.drain() {
            engine.shutdown().await;
        }
        tracing::info!(worker = %self.config.worker_id, "worker stopped");
    }

    /// Runs one task and reports it, unless `shutdown` resolves while it runs: then its engines
    /// are killed and the lease is given back.
    async fn serve(&mut self, task: pb::LeasedTask, shutdown: std::pin::Pin<&mut impl Future<Output = ()>>) -> Served {
        let span = tracing::info_span!("task", job = %task.job_id, task = %task.key, stage = %task.stage, attempt = task.attempt);
        async {
            let lost = Arc::new(AtomicBool::new(false));
            let heartbeat = tokio::spawn(heartbeat_loop(
                self.client.clone(),
                self.config.worker_id.clone(),
                pb::TaskAttempt { task_id: task.task_id.clone(), attempt: task.attempt },
                self.config.lease_ms,
                lost.clone(),
                self.config.metrics.clone(),
            ));
            let dir = self.config.scratch.join(format!("{}-a{}", sanitize(&task.task_id), task.attempt));
            let outcome = tokio::select! {
                outcome = self.execute(&task, &dir) => Some(outcome),
                () = shutdown => None,
            };
            let Some(outcome) = outcome else {
                // The engine may be mid-task: its protocol state is unknown, and a new process
                // takes it up wherever the task is leased next.
                self.engines.clear();
                heartbeat.abort();
                let _ = tokio::fs::remove_dir_all(&dir).await;
                self.release(&task).await;
                return Served::Stopped;
            };
            heartbeat.abort();
            let _ = tokio::fs::remove_dir_all(&dir).await;
            if lost.load(Ordering::SeqCst) {
                tracing::warn!("lease lost while running; result discarded");
                self.record(&task, TaskOutcome::LeaseLost);
                return Served::Done;
            }
            match outcome {
                Ok(done) => self.complete(&task, done).await,
                Err(failure) => self.fail(&task, failure).await,
            }
            Served::Done
        }
        .instrument(span)
        .await
    }

    async fn execute(&mut self, task: &pb::LeasedTask, dir: &Path) -> Result<Finished, TaskFailure> {
        let started = Instant::now();
        let stage: Stage =
            task.stage.parse().map_err(|e: vint_core::stage::UnknownStage| TaskFailure::permanent(e.to_string()))?;
        let params: Value = serde_json::from_str(&task.params_json)
            .map_err(|e| TaskFailure::permanent(format!("task params are not JSON: {e}")))?;
        if stage == Stage::Package {
            let inputs: Vec<PackageInput> = task.inputs.iter().map(PackageInput::from).collect();
            let packaged = package::package(&params, &inputs, &self.store)
                .await
                .map_err(|e| TaskFailure { retryable: e.retryable(), message: e.to_string() })?;
            self.config.metrics.engine_ran(stage, started.elapsed());
            self.config.metrics.moved_bytes(packaged.bytes_read, packaged.bytes_written);
            let engine_ms = ms(started.elapsed());
            let result_json = serde_json::to_string(&packaged.result)
                .map_err(|e| TaskFailure::permanent(format!("package result: {e}")))?;
            let outputs = packaged
                .files
                .into_iter()
                .map(|f| pb::ArtifactRef {
                    name: f.name,
                    sha256: f.sha256,
                    size: f.size,
                    media_type: f.media_type,
                    key: f.key,
                    task_key: task.key.clone(),
                })
                .collect();
            let engine = serde_json::json!({
                "name": "vint-package", "version": env!("CARGO_PKG_VERSION"), "identity": package::IDENTITY,
            });
            return Ok(Finished {
                outputs,
                engine_json: engine.to_string(),
                result_json,
                timings: pb::Timings { fetch_ms: 0.0, engine_ms, upload_ms: 0.0, total_ms: engine_ms },
            });
        }

        let in_dir = dir.join("in");
        let out_dir = dir.join("out");
        tokio::fs::create_dir_all(&out_dir)
            .await
            .map_err(|e| TaskFailure::retryable(format!("creating scratch {}: {e}", out_dir.display())))?;
        let fetch_start = Instant::now();
        let mut inputs = Vec::new();
        let mut fetched_bytes = 0;
        for a in task.inputs.iter().filter(|a| contract::reads(stage, &a.name)) {
            let path = in_dir.join(sanitize(&a.task_key)).join(&a.name);
            self.store
                .get_to_file(&a.sha256, &path)
                .await
                .map_err(|e| TaskFailure::retryable(format!("fetching input {} of {}: {e}", a.name, a.task_key)))?;
            fetched_bytes += a.size;
            inputs.push(EngineInput { name: a.name.clone(), task_key: a.task_key.clone(), path });
        }
        for asset in task_assets(&params)? {
            let path = in_dir.join("assets").join(&asset.sha256).join(sanitize(asset.file_name()));
            self.store
                .get_to_file(&asset.sha256, &path)
                .await
                .map_err(|e| TaskFailure::retryable(format!("fetching asset {}: {e}", asset.path)))?;
            fetched_bytes += asset.size;
            inputs.push(EngineInput { name: asset.sha256, task_key: ASSET_INPUT_KEY.to_string(), path });
        }
        self.config.metrics.fetched(stage, fetched_bytes, fetch_start.elapsed());
        let fetch_ms = ms(fetch_start.elapsed());

        let engine_start = Instant::now();
        let engine = self.engine(stage).await?;
        let identity = engine.identity.to_string();
        let result = match engine.run(&task.task_id, &params, &inputs, &out_dir).await {
            Ok(r) => r,
            Err(e) => {
                // The engine is unusable: drop (and so kill) it; the next task starts a fresh one.
                self.engines.remove(&stage);
                self.config.metrics.engine_restarted(stage, RestartReason::of_error(&e));
                return Err(TaskFailure::retryable(e.to_string()));
            }
        };
        self.config.metrics.engine_ran(stage, engine_start.elapsed());
        let engine_ms = ms(engine_start.elapsed());
        if !result.ok {
            return Err(TaskFailure { retryable: result.retryable, message: format!("engine: {}", result.error) });
        }

        let upload_start = Instant::now();
        let mut outputs = Vec::with_capacity(result.outputs.len());
        let mut uploaded_bytes = 0;
        for o in &result.outputs {
            let stored = self
                .store
                .put_file(&o.path)
                .await
                .map_err(|e| TaskFailure::retryable(format!("uploading {}: {e}", o.name)))?;
            uploaded_bytes += stored.size;
            outputs.push(pb::ArtifactRef {
                name: o.name.clone(),
                sha256: stored.sha256,
                size: stored.size,
                media_type: o.media_type.clone(),
                key: stored.key,
                task_key: task.key.clone(),
            });
        }
        self.config.metrics.uploaded(stage, uploaded_bytes, upload_start.elapsed());
        let upload_ms = ms(upload_start.elapsed());
        let result_json = result.result.to_string();
        let mut engine_json: Value = serde_json::from_str(&identity).unwrap_or(Value::Null);
        if let Value::Object(map) = &mut engine_json {
            map.insert("metrics".into(), Value::Object(result.metrics.clone()));
            if let Some(id) = self.identities.get(&stage) {
                map.insert("identity".into(), Value::String(id.clone()));
            }
        }
        Ok(Finished {
            outputs,
            engine_json: engine_json.to_string(),
            result_json,
            timings: pb::Timings { fetch_ms, engine_ms, upload_ms, total_ms: ms(started.elapsed()) },
        })
    }

    /// The warm engine of `stage`, started on first use. A warm engine past its recycle limits
    /// (tasks served, resident memory) is shut down first and replaced by a fresh one.
    async fn engine(&mut self, stage: Stage) -> Result<&mut Engine, TaskFailure> {
        if let Some(reason) = self.engines.get(&stage).and_then(Engine::recycle_reason)
            && let Some(old) = self.engines.remove(&stage)
        {
            tracing::info!(stage = %stage, %reason, "recycling the engine");
            self.config.metrics.engine_restarted(stage, RestartReason::of_recycle(&reason));
            old.shutdown().await;
        }
        if !self.engines.contains_key(&stage) {
            // A missing interpreter or a crash at start-up may be a bad node: let another try.
            let engine =
                Engine::start(stage, &self.config.engine).await.map_err(|e| TaskFailure::retryable(e.to_string()))?;
            self.engines.insert(stage, engine);
        }
        self.engines.get_mut(&stage).ok_or_else(|| TaskFailure::retryable("engine vanished"))
    }

    async fn complete(&mut self, task: &pb::LeasedTask, done: Finished) {
        let request = pb::CompleteTaskRequest {
            worker_id: self.config.worker_id.clone(),
            task_id: task.task_id.clone(),
            attempt: task.attempt,
            outputs: done.outputs,
            engine_json: done.engine_json,
            timings: Some(done.timings),
            result_json: done.result_json,
        };
        let client = self.client.clone();
        let sent = with_retries(task.lease_deadline_ms, || {
            let mut c = client.clone();
            let r = request.clone();
            async move { c.complete_task(r).await.map(|_| ()) }
        })
        .await;
        let outcome = match sent {
            Ok(()) => {
                tracing::info!(total_ms = done.timings.total_ms, engine_ms = done.timings.engine_ms, "task completed");
                TaskOutcome::Completed
            }
            Err(s) if s.code() == Code::FailedPrecondition => {
                tracing::warn!(error = %s.message(), "completion refused: lease lost");
                TaskOutcome::LeaseLost
            }
            Err(s) if matches!(s.code(), Code::InvalidArgument | Code::NotFound) => {
                tracing::error!(error = %s.message(), code = ?s.code(), "completion refused");
                TaskOutcome::Refused
            }
            Err(s) => {
                tracing::error!(error = %s.message(), code = ?s.code(), "completion failed; the task will be leased again");
                TaskOutcome::Unreported
            }
        };
        self.record(task, outcome);
    }

    /// Gives `task`'s lease back.
    async fn release(&self, task: &pb::LeasedTask) {
        let held = [pb::TaskAttempt { task_id: task.task_id.clone(), attempt: task.attempt }];
        release(&self.client, &self.config.worker_id, &held).await;
    }

    async fn fail(&mut self, task: &pb::LeasedTask, failure: TaskFailure) {
        tracing::warn!(retryable = failure.retryable, error = %failure.message, "task failed");
        let request = pb::FailTaskRequest {
            worker_id: self.config.worker_id.clone(),
            task_id: task.task_id.clone(),
            attempt: task.attempt,
            retryable: failure.retryable,
            message: failure.message,
        };
        let client = self.client.clone();
        let sent = with_retries(task.lease_deadline_ms, || {
            let mut c = client.clone();
            let r = request.clone();
            async move { c.fail_task(r).await.map(|_| ()) }
        })
        .await;
        let outcome = match sent {
            Ok(()) if request.retryable => TaskOutcome::RetryableFailure,
            Ok(()) => TaskOutcome::PermanentFailure,
            Err(s) => {
                tracing::warn!(error = %s.message(), "could not report the failure; the lease will expire instead");
                TaskOutcome::Unreported
            }
        };
        self.record(task, outcome);
    }

    /// Counts how a task ended (a task of no known stage was failed permanently and is not counted).
    fn record(&self, task: &pb::LeasedTask, outcome: TaskOutcome) {
        if let Ok(stage) = task.stage.parse::<Stage>() {
            self.config.metrics.task_finished(stage, outcome);
        }
    }
}

/// The `task_key` of a staged user file: it comes with the job's submission, not from a task.
const ASSET_INPUT_KEY: &str = "asset";

/// The user files a task's parameters name (`params.assets`, written by the planner): each is
/// staged under its file name and handed to the engine as an input named by its SHA-256.
fn task_assets(params: &Value) -> Result<Vec<vint_core::asset::Asset>, TaskFailure> {
    match params.get("assets") {
        None => Ok(Vec::new()),
        Some(list) => {
            let assets: Vec<vint_core::asset::Asset> = serde_json::from_value(list.clone())
                .map_err(|e| TaskFailure::permanent(format!("params.assets: {e}")))?;
            match assets.iter().find(|a| vint_artifacts::key_for(&a.sha256).is_err()) {
                Some(bad) => Err(TaskFailure::permanent(format!("params.assets: {:?} is not a sha256", bad.sha256))),
                None => Ok(assets),
            }
        }
    }
}

/// A refused lease: a token the coordinator refuses is the operator's to fix (an error that says
/// how); anything else is most likely a coordinator being restarted.
pub(crate) fn log_lease_failure(status: &tonic::Status) {
    match status.code() {
        tonic::Code::Unauthenticated | tonic::Code::PermissionDenied => tracing::error!(
            error = %status.message(), code = ?status.code(),
            "the coordinator refuses this worker: give it a worker token (--token or VINT_TOKEN)"
        ),
        _ => tracing::warn!(error = %status.message(), code = ?status.code(), "lease failed; coordinator unreachable?"),
    }
}

async fn heartbeat_loop(
    mut client: WorkServiceClient<AuthChannel>,
    worker_id: String,
    held: pb::TaskAttempt,
    lease_ms: u32,
    lost: Arc<AtomicBool>,
    metrics: WorkerMetrics,
) {
    let every = Duration::from_millis(u64::from(lease_ms / 3).max(200));
    loop {
        tokio::time::sleep(every).await;
        metrics.beat();
        let request = pb::HeartbeatRequest { worker_id: worker_id.clone(), held: vec![held.clone()], lease_ms };
        match client.heartbeat(request).await {
            Ok(resp) if resp.get_ref().lost.iter().any(|l| l.task_id == held.task_id) => {
                metrics.leases_lost(1);
                lost.store(true, Ordering::SeqCst);
                return;
            }
            Ok(_) => {}
            Err(s) => tracing::warn!(error = %s.message(), "heartbeat failed"),
        }
    }
}

/// Longest a hand-back may take: the worker is shutting down within its grace period, and a
/// lease not given back still expires.
const RELEASE_TIMEOUT: Duration = Duration::from_secs(5);

/// Gives back `held` leases of `worker_id` (one RPC, bounded by `RELEASE_TIMEOUT`); logs what
/// could not be.
pub(crate) async fn release(client: &WorkServiceClient<AuthChannel>, worker_id: &str, held: &[pb::TaskAttempt]) {
    if held.is_empty() {
        return;
    }
    let request = pb::ReleaseTasksRequest { worker_id: worker_id.to_string(), tasks: held.to_vec() };
    match tokio::time::timeout(RELEASE_TIMEOUT, client.clone().release_tasks(request)).await {
        Ok(Ok(resp)) => {
            let released = resp.into_inner().released.len();
            tracing::info!(released, lost = held.len().saturating_sub(released), "leases given back");
        }
        Ok(Err(s)) => tracing::warn!(error = %s.message(), "could not give the leases back; they will expire instead"),
        Err(_) => tracing::warn!("the coordinator did not take the leases back in time; they will expire instead"),
    }
}

/// Retries an RPC through transient coordinator outages until the lease deadline has passed
/// (after which the coordinator would refuse it anyway).
pub(crate) async fn with_retries<T, F, Fut>(lease_deadline_ms: i64, mut call: F) -> Result<T, Status>
where
    F: FnMut() -> Fut,
    Fut: Future<Output = Result<T, Status>>,
{
    let mut wait = Duration::from_millis(100);
    loop {
        match call().await {
            Ok(answer) => return Ok(answer),
            Err(s)
                if matches!(s.code(), Code::Unavailable | Code::Unknown | Code::DeadlineExceeded | Code::Cancelled) =>
            {
                let now = std::time::SystemTime::now()
                    .duration_since(std::time::UNIX_EPOCH)
                    .map(|d| d.as_millis() as i64)
                    .unwrap_or(i64::MAX);
                if now > lease_deadline_ms + 60_000 {
                    return Err(s);
                }
                tracing::warn!(error = %s.message(), "coordinator unavailable; retrying");
                tokio::time::sleep(wait).await;
                wait = (wait * 2).min(Duration::from_secs(2));
            }
            Err(s) => return Err(s),
        }
    }
}

pub(crate) fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1_000.0
}

/// A path component from an id: keeps `[A-Za-z0-9._-]`, replaces the rest.
fn sanitize(s: &str) -> String {
    s.chars().map(|c| if c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-') { c } else { '_' }).collect()
}
