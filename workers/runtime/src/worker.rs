//! The worker loop: lease a batch of tasks, and for each one stage its inputs, run it (engine or
//! in-process package stage), upload its outputs, and complete or fail it; one heartbeat renews
//! every lease the worker holds, those waiting their turn in the batch included. With a batch of
//! more than one task the next lease is already in flight while the batch's last task runs
//! (prefetch), so a worker of short tasks (noise, package) does not wait for a lease between them.
//!
//! A worker keeps one engine per stage it has served, alive between tasks. It survives a
//! coordinator restart (RPCs are retried with backoff) and never completes a task whose lease it
//! has lost. It holds no durable state: kill it at any moment and its task is leased again. Asked
//! to stop (SIGTERM), it does not wait for a task that may run for half an hour: it kills the
//! engine and gives the lease back (`ReleaseTasks`), so the task is queued again at once.

use std::collections::{HashMap, HashSet};
use std::future::Future;
use std::path::{Path, PathBuf};
use std::sync::Arc;
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
    /// Tasks per lease (at least 1). Above 1, the next lease goes out when a batch's last task
    /// starts.
    pub batch: u32,
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
    held: Arc<HeldLeases>,
}

impl Worker {
    pub fn new(config: WorkerConfig, store: ArtifactStore) -> Result<Worker, WorkerError> {
        let endpoint = config.coordinator.endpoint()?.connect_timeout(Duration::from_secs(5));
        let client = WorkServiceClient::new(config.coordinator.lazy_channel(endpoint)?);
        Ok(Worker { config, client, store, engines: HashMap::new(), identities: HashMap::new(), held: Arc::default() })
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
    /// killed) and its lease given back, with those of the batch it has not started and of a
    /// prefetched lease; one already being reported is reported first.
    pub async fn run(mut self, shutdown: impl Future<Output = ()>) {
        tokio::pin!(shutdown);
        let stages: Vec<String> = self.config.stages.iter().map(|s| s.as_str().to_string()).collect();
        self.identities = self.read_identities().await;
        let engines: HashMap<String, String> =
            self.identities.iter().map(|(s, id)| (s.as_str().to_string(), id.clone())).collect();
        tracing::info!(worker = %self.config.worker_id, engines = ?engines, batch = self.config.batch, "engine identities");
        let request = pb::LeaseTasksRequest {
            worker_id: self.config.worker_id.clone(),
            stages,
            capacity: self.config.batch.max(1),
            lease_ms: self.config.lease_ms,
            engines,
            timing_only: false,
        };
        let heartbeat = tokio::spawn(heartbeat_loop(
            self.client.clone(),
            self.config.worker_id.clone(),
            self.held.clone(),
            self.config.lease_ms,
            self.config.metrics.clone(),
        ));
        let mut idle = Duration::from_millis(50);
        let mut prefetched: Option<tokio::task::JoinHandle<Result<Vec<pb::LeasedTask>, Status>>> = None;
        loop {
            self.config.metrics.beat();
            // The prefetched lease, or a new one: in a task of its own either way, so that what
            // it grants is held (heartbeated) as soon as it arrives.
            let lease = prefetched
                .take()
                .unwrap_or_else(|| tokio::spawn(lease_batch(self.client.clone(), request.clone(), self.held.clone())));
            let lease =
                async move { lease.await.unwrap_or_else(|e| Err(Status::internal(format!("lease task: {e}")))) };
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
                if let Ok(tasks) = leased {
                    self.release(&tasks).await;
                }
                break;
            }
            match leased {
                Ok(tasks) if !tasks.is_empty() => {
                    idle = Duration::from_millis(50);
                    let last = tasks.len() - 1;
                    let mut tasks = tasks.into_iter().enumerate();
                    let mut stopped = false;
                    for (i, task) in tasks.by_ref() {
                        if i == last && self.config.batch > 1 {
                            let next = lease_batch(self.client.clone(), request.clone(), self.held.clone());
                            prefetched = Some(tokio::spawn(next));
                        }
                        if self.serve(task, shutdown.as_mut()).await == Served::Stopped {
                            stopped = true;
                            break;
                        }
                    }
                    if stopped {
                        let rest: Vec<pb::LeasedTask> = tasks.map(|(_, t)| t).collect();
                        self.release(&rest).await;
                        if let Some(handle) = prefetched.take()
                            && let Ok(Ok(Ok(tasks))) = tokio::time::timeout(RELEASE_TIMEOUT, handle).await
                        {
                            self.release(&tasks).await;
                        }
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
        heartbeat.abort();
        for (_, engine) in self.engines.drain() {
            engine.shutdown().await;
        }
        tracing::info!(worker = %self.config.worker_id, "worker stopped");
    }

    /// Runs one task and reports it, unless `shutdown` resolves while it runs: then its engines
    /// are killed and the lease is given back. A task whose lease was lost while it waited its
    /// turn in the batch is not run.
    async fn serve(&mut self, task: pb::LeasedTask, shutdown: std::pin::Pin<&mut impl Future<Output = ()>>) -> Served {
        let span = tracing::info_span!("task", job = %task.job_id, task = %task.key, stage = %task.stage, attempt = task.attempt);
        async {
            let attempt = (task.task_id.clone(), task.attempt);
            if self.held.lost(&attempt) {
                tracing::warn!("lease lost before the task's turn; not run");
                self.held.forget(&attempt);
                self.record(&task, TaskOutcome::LeaseLost);
                return Served::Done;
            }
            let dir = self.config.scratch.join(format!("{}-a{}", sanitize(&task.task_id), task.attempt));
            let outcome = tokio::select! {
                outcome = self.execute(&task, &dir) => Some(outcome),
                () = shutdown => None,
            };
            let Some(outcome) = outcome else {
                // The engine may be mid-task: its protocol state is unknown, and a new process
                // takes it up wherever the task is leased next. Killed and waited for, so that no
                // engine outlives the worker.
                for (_, engine) in self.engines.drain() {
                    engine.kill().await;
                }
                let _ = tokio::fs::remove_dir_all(&dir).await;
                self.release(std::slice::from_ref(&task)).await;
                return Served::Stopped;
            };
            let _ = tokio::fs::remove_dir_all(&dir).await;
            if self.held.lost(&attempt) {
                tracing::warn!("lease lost while running; result discarded");
                self.held.forget(&attempt);
                self.record(&task, TaskOutcome::LeaseLost);
                return Served::Done;
            }
            // Reported from here on, not renewed: a heartbeat racing the report would find the
            // row locked by it and read the lease as lost.
            self.held.forget(&attempt);
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
        let sent = with_retries(|| {
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

    /// Gives the leases of `tasks` back.
    async fn release(&self, tasks: &[pb::LeasedTask]) {
        release(&self.client, &self.config.worker_id, &self.held, tasks).await;
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
        let sent = with_retries(|| {
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

/// The leases a worker holds (leased, not yet reported or given back) and those of them the
/// coordinator said were lost.
#[derive(Debug, Default)]
pub(crate) struct HeldLeases {
    held: std::sync::Mutex<HashSet<(String, u32)>>,
    lost: std::sync::Mutex<HashSet<(String, u32)>>,
}

impl HeldLeases {
    pub(crate) fn hold(&self, tasks: &[pb::LeasedTask]) {
        let mut held = self.held.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        held.extend(tasks.iter().map(|t| (t.task_id.clone(), t.attempt)));
    }

    fn forget(&self, attempt: &(String, u32)) {
        self.held.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).remove(attempt);
        self.lost.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).remove(attempt);
    }

    /// Forgets every lease of `tasks` (reported or given back).
    pub(crate) fn forget_all(&self, tasks: &[pb::LeasedTask]) {
        let mut held = self.held.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        let mut lost = self.lost.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        for t in tasks {
            let attempt = (t.task_id.clone(), t.attempt);
            held.remove(&attempt);
            lost.remove(&attempt);
        }
    }

    fn lost(&self, attempt: &(String, u32)) -> bool {
        self.lost.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).contains(attempt)
    }

    fn snapshot(&self) -> Vec<pb::TaskAttempt> {
        let held = self.held.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        held.iter().map(|(task_id, attempt)| pb::TaskAttempt { task_id: task_id.clone(), attempt: *attempt }).collect()
    }

    /// Marks `lost` lost, of those still held; returns how many were.
    fn mark_lost(&self, lost: &[pb::TaskAttempt]) -> usize {
        let held = self.held.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        let mut marked = self.lost.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        let mut n = 0;
        for l in lost {
            let attempt = (l.task_id.clone(), l.attempt);
            if held.contains(&attempt) && marked.insert(attempt) {
                n += 1;
            }
        }
        n
    }
}

/// One lease call; the tasks it grants are held (heartbeated) from the moment they arrive, so a
/// prefetched batch waiting for its turn keeps its leases.
async fn lease_batch(
    mut client: WorkServiceClient<AuthChannel>,
    request: pb::LeaseTasksRequest,
    held: Arc<HeldLeases>,
) -> Result<Vec<pb::LeasedTask>, Status> {
    let tasks = client.lease_tasks(request).await?.into_inner().tasks;
    held.hold(&tasks);
    Ok(tasks)
}

/// Renews every lease the worker holds, every third of a lease, for as long as the worker runs
/// (the timing-only worker's too). A lease reported while a heartbeat was in flight is no longer
/// held, so it is not counted lost.
pub(crate) async fn heartbeat_loop(
    mut client: WorkServiceClient<AuthChannel>,
    worker_id: String,
    held: Arc<HeldLeases>,
    lease_ms: u32,
    metrics: WorkerMetrics,
) {
    let every = Duration::from_millis(u64::from(lease_ms / 3).max(200));
    loop {
        tokio::time::sleep(every).await;
        let attempts = held.snapshot();
        if attempts.is_empty() {
            continue;
        }
        // A task that runs for long keeps the worker live: its heartbeats are the loop's beat.
        metrics.beat();
        let request = pb::HeartbeatRequest { worker_id: worker_id.clone(), held: attempts, lease_ms };
        match client.heartbeat(request).await {
            Ok(resp) => {
                let lost = held.mark_lost(&resp.get_ref().lost);
                if lost > 0 {
                    metrics.leases_lost(lost as u64);
                    tracing::warn!(lost, "leases lost; their results will be discarded or refused");
                }
            }
            Err(s) => tracing::warn!(error = %s.message(), "heartbeat failed"),
        }
    }
}

/// Longest a hand-back may take: the worker is shutting down within its grace period, and a
/// lease not given back still expires.
const RELEASE_TIMEOUT: Duration = Duration::from_secs(5);

/// Gives back the leases of `tasks` that `worker_id` holds (one RPC, bounded by `RELEASE_TIMEOUT`)
/// and stops holding them; logs what could not be given back.
pub(crate) async fn release(
    client: &WorkServiceClient<AuthChannel>,
    worker_id: &str,
    leases: &HeldLeases,
    tasks: &[pb::LeasedTask],
) {
    if tasks.is_empty() {
        return;
    }
    let held: Vec<pb::TaskAttempt> =
        tasks.iter().map(|t| pb::TaskAttempt { task_id: t.task_id.clone(), attempt: t.attempt }).collect();
    let request = pb::ReleaseTasksRequest { worker_id: worker_id.to_string(), tasks: held };
    match tokio::time::timeout(RELEASE_TIMEOUT, client.clone().release_tasks(request)).await {
        Ok(Ok(resp)) => {
            let released = resp.into_inner().released.len();
            tracing::info!(released, lost = tasks.len().saturating_sub(released), "leases given back");
        }
        Ok(Err(s)) => tracing::warn!(error = %s.message(), "could not give the leases back; they will expire instead"),
        Err(_) => tracing::warn!("the coordinator did not take the leases back in time; they will expire instead"),
    }
    leases.forget_all(tasks);
}

/// Retries a report (a completion or a failure) through a coordinator outage, every 2 s at most,
/// for up to `REPORT_RETRY_FOR`. Retrying is always safe and, for as long as the coordinator
/// cannot be reached, worth it: a lease stays its worker's until the reaper takes it, and a
/// coordinator that comes back (or whose database does) reaps no lease before its worker has
/// had a whole lease to be heard. Where the coordinator was up all along (only this worker was
/// cut off), the report is refused as lease lost, which ends the retries.
pub(crate) async fn with_retries<T, F, Fut>(call: F) -> Result<T, Status>
where
    F: FnMut() -> Fut,
    Fut: Future<Output = Result<T, Status>>,
{
    retry_for(REPORT_RETRY_FOR, call).await
}

/// How long a worker keeps retrying a report while the coordinator cannot be reached.
pub const REPORT_RETRY_FOR: Duration = Duration::from_secs(3_600);

async fn retry_for<T, F, Fut>(window: Duration, mut call: F) -> Result<T, Status>
where
    F: FnMut() -> Fut,
    Fut: Future<Output = Result<T, Status>>,
{
    let started = std::time::Instant::now();
    let mut wait = Duration::from_millis(100);
    loop {
        match call().await {
            Ok(answer) => return Ok(answer),
            Err(s)
                if matches!(s.code(), Code::Unavailable | Code::Unknown | Code::DeadlineExceeded | Code::Cancelled) =>
            {
                if started.elapsed() >= window {
                    return Err(s);
                }
                tracing::warn!(error = %s.message(), "coordinator unavailable; retrying the report");
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

#[cfg(test)]
mod tests {
    use std::sync::atomic::{AtomicU32, Ordering};

    use super::*;

    /// Retried through the outage while the window lasts; given up with the last error after it;
    /// any answer but a transient one ends the retries at once.
    #[tokio::test]
    async fn a_report_is_retried_through_an_outage_while_its_window_lasts() {
        let calls = AtomicU32::new(0);
        let flaky = || {
            let n = calls.fetch_add(1, Ordering::SeqCst);
            async move { if n < 2 { Err(Status::unavailable("coordinator restarting")) } else { Ok(n) } }
        };
        assert_eq!(retry_for(Duration::from_secs(60), flaky).await.map_err(|s| s.code()), Ok(2));
        assert_eq!(calls.swap(0, Ordering::SeqCst), 3);

        let down = || {
            calls.fetch_add(1, Ordering::SeqCst);
            async { Err::<(), _>(Status::unavailable("coordinator down")) }
        };
        let started = std::time::Instant::now();
        assert_eq!(retry_for(Duration::from_millis(300), down).await.map_err(|s| s.code()), Err(Code::Unavailable));
        assert!(started.elapsed() >= Duration::from_millis(300));
        assert!(calls.swap(0, Ordering::SeqCst) >= 3, "retried within the window");

        let lost = || {
            calls.fetch_add(1, Ordering::SeqCst);
            async { Err::<(), _>(Status::failed_precondition("lease lost")) }
        };
        assert_eq!(retry_for(Duration::from_secs(60), lost).await.map_err(|s| s.code()), Err(Code::FailedPrecondition));
        assert_eq!(calls.load(Ordering::SeqCst), 1);
    }
}
