//! `vint-worker --engine-mode timing-only`: a worker that runs no engine, for measuring the
//! system around the engines — coordinator, planner, database, lineage and object store — at
//! the scale of a real dataset (`benches/dispatch.sh` drives 2 M samples through it).
//!
//! It is never the default and its output is not data. Each task answers what its engine would:
//! a result of the stage's contract and output files of the real names and sizes (each stage's
//! own `fake` in `vint_core::contract`, from the sizes measured on real runs). The bytes of a file
//! are a constant payload per (kind, size), stored once in the object store and referenced by its
//! hash, so the object store sees every put and content addressing dedupes the rest; a package
//! task references its render and noise inputs by hash exactly as the real stage does. A grasp
//! trial is accepted when its seed (derived from the job seed and the trial's identity) falls
//! below `accept_rate`, so a run is deterministic. Every completion's `engine_json` names the mode, so lineage says which
//! artifacts came from it.
//!
//! Tasks go in batches both ways: one `LeaseTasks` for up to `batch` tasks and one
//! `CompleteTasks` for all of them, with the next lease already in flight (prefetch) while a
//! batch is answered, and `concurrency` such loops per process. One heartbeat renews every lease
//! the process holds. Asked to stop, it answers the batches it is answering and gives back the
//! leases of those it has not started (the prefetched ones).

use std::collections::{BTreeSet, HashMap};
use std::future::Future;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use bytes::Bytes;
use serde_json::Value;
use tokio::sync::{Mutex, watch};
use tracing::Instrument;
use vint_artifacts::{ArtifactStore, StoredObject};
use vint_connect::AuthChannel;
use vint_core::contract::package::{
    self, GRASP_RECORD_BYTES, GRASP_RECORD_FILE, META_FILE, META_JSON_BYTES, PackageResult,
};
use vint_core::contract::{self, FakeInput, FileKind};
use vint_core::{SampleId, Stage};
use vint_proto::v1 as pb;
use vint_proto::v1::completion_result::Outcome;
use vint_proto::v1::work_service_client::WorkServiceClient;

use crate::metrics::{TaskOutcome, WorkerMetrics};
use crate::package::{Inputs, PackageInput, referenced_files};
use crate::worker::{HeldLeases, WorkerError, heartbeat_loop, ms};

/// Largest lease answer read, and largest completion call sent: a batch's completions go in as
/// many `CompleteTasks` calls as keep each under the coordinator's limit (8 MiB).
const MAX_MESSAGE_BYTES: usize = 64 << 20;
const MAX_COMPLETION_CALL_BYTES: usize = 6 << 20;

/// What `engine_json` says of every task this mode completes.
pub const ENGINE_MODE: &str = contract::TIMING_ONLY;

#[derive(Clone, Debug)]
pub struct TimingOnlyConfig {
    pub coordinator: vint_connect::Remote,
    pub worker_id: String,
    pub stages: Vec<Stage>,
    pub lease_ms: u32,
    /// Share of grasp trials accepted (by their seeds), within each chunk's quota.
    pub accept_rate: f64,
    /// Tasks per lease and per completion call.
    pub batch: u32,
    /// Lease-and-complete loops in flight in this process.
    pub concurrency: u32,
    /// Longest pause between lease polls when there is no work.
    pub max_idle_poll: Duration,
    /// Where to append one CSV line per batch: `unix_ms,slot,tasks,lease_ms,complete_ms` (the
    /// lease and completion RPCs' round trips), for the lease latency curve of a long run.
    pub latency_log: Option<std::path::PathBuf>,
    /// Where the worker records what it does (the same task counters as an engine worker).
    pub metrics: WorkerMetrics,
}

/// What a timing-only worker did, for its closing log line and for tests.
#[derive(Debug, Default)]
pub struct Tally {
    pub completed: AtomicU64,
    pub refused: AtomicU64,
    pub failed: AtomicU64,
}

/// The constant payloads, each stored once and then referenced by hash.
struct Payloads {
    store: ArtifactStore,
    stored: Mutex<HashMap<(FileKind, u64), StoredObject>>,
    metrics: WorkerMetrics,
}

impl Payloads {
    async fn get(&self, kind: FileKind, size: u64) -> Result<StoredObject, vint_artifacts::ArtifactError> {
        let mut stored = self.stored.lock().await;
        if let Some(object) = stored.get(&(kind, size)) {
            return Ok(object.clone());
        }
        let line = format!("vint timing-only payload ({}): not data\n", kind.as_str());
        let bytes: Vec<u8> = line.bytes().cycle().take(size as usize).collect();
        let object = self.store.put_bytes(Bytes::from(bytes)).await?;
        self.metrics.moved_bytes(0, object.size);
        stored.insert((kind, size), object.clone());
        Ok(object)
    }

    async fn file(&self, name: String, kind: FileKind, size: u64, task_key: &str) -> Result<pb::ArtifactRef, String> {
        let object = self.get(kind, size).await.map_err(|e| format!("storing a {} payload: {e}", kind.as_str()))?;
        Ok(pb::ArtifactRef {
            name,
            sha256: object.sha256,
            size: object.size,
            media_type: kind.media_type().to_string(),
            key: object.key,
            task_key: task_key.to_string(),
        })
    }
}

/// Why a task could not be answered: its parameters do not follow the contract (permanent), or
/// the object store failed (retryable).
struct Refusal {
    retryable: bool,
    message: String,
}

fn permanent(message: impl Into<String>) -> Refusal {
    Refusal { retryable: false, message: message.into() }
}

/// The result and output files of one task, as its stage's engine would answer: the stage's own
/// timing-only answer (`vint_core::contract::fake`), or for the package stage, which moves no
/// pixels, its files referenced as the real stage references them.
async fn answer(
    task: &pb::LeasedTask,
    payloads: &Payloads,
    accept_rate: f64,
) -> Result<(Value, Vec<pb::ArtifactRef>), Refusal> {
    let stage: Stage = task.stage.parse().map_err(|e: vint_core::stage::UnknownStage| permanent(e.to_string()))?;
    let params: Value =
        serde_json::from_str(&task.params_json).map_err(|e| permanent(format!("task params are not JSON: {e}")))?;
    let store = |message: String| Refusal { retryable: true, message };
    let key = task.key.as_str();
    let inputs: Vec<FakeInput<'_>> = task.inputs.iter().map(|a| FakeInput { name: &a.name, size: a.size }).collect();
    if let Some(fake) = contract::fake(stage, &params, &inputs, accept_rate).map_err(|e| permanent(e.to_string()))? {
        let mut files = Vec::with_capacity(fake.files.len());
        for f in fake.files {
            files.push(payloads.file(f.name, f.kind, f.size, key).await.map_err(store)?);
        }
        return Ok((fake.result, files));
    }
    let p: package::Params = serde_json::from_value(params)
        .map_err(|e| permanent(format!("{stage} params do not follow the contract: {e}")))?;
    let inputs: Vec<PackageInput> = task.inputs.iter().map(PackageInput::from).collect();
    let by_origin = Inputs::new(&inputs);
    let mut result = PackageResult::default();
    let mut files = Vec::new();
    let mut grasps = BTreeSet::new();
    for s in &p.samples {
        let id: SampleId = s.sample_id.parse().map_err(|e: vint_core::sample::BadSampleId| permanent(e.to_string()))?;
        for f in
            referenced_files(&by_origin, &id, &p.modalities, p.depth_format).map_err(|e| permanent(e.to_string()))?
        {
            files.push(pb::ArtifactRef {
                name: f.name,
                sha256: f.sha256,
                size: f.size,
                media_type: f.media_type,
                key: f.key,
                task_key: key.to_string(),
            });
        }
        let meta = format!("{}/{META_FILE}", s.sample_id);
        files.push(payloads.file(meta, FileKind::Json, META_JSON_BYTES as u64, key).await.map_err(store)?);
        grasps.insert(id.grasp().to_string());
        result.samples.push(s.sample_id.clone());
    }
    for grasp in &grasps {
        let record = format!("{grasp}/{GRASP_RECORD_FILE}");
        files.push(payloads.file(record, FileKind::Json, GRASP_RECORD_BYTES as u64, key).await.map_err(store)?);
    }
    result.grasps = grasps.into_iter().collect();
    let result = serde_json::to_value(result).map_err(|e| permanent(format!("{stage} result: {e}")))?;
    Ok((result, files))
}

/// The worker's shared state: its coordinator client, payloads, held leases and tally.
struct Shared {
    config: TimingOnlyConfig,
    client: WorkServiceClient<AuthChannel>,
    payloads: Payloads,
    held: Arc<HeldLeases>,
    tally: Arc<Tally>,
    engine_json: String,
    latency_log: Option<std::sync::Mutex<std::io::BufWriter<std::fs::File>>>,
}

impl Shared {
    /// Counts how a task ended (a task of no known stage is not counted: it failed permanently).
    fn record(&self, task: &pb::LeasedTask, outcome: TaskOutcome) {
        if let Ok(stage) = task.stage.parse::<Stage>() {
            self.config.metrics.task_finished(stage, outcome);
        }
    }

    fn log_batch(&self, slot: u32, tasks: usize, lease_ms: f64, complete_ms: f64) {
        if let Some(log) = &self.latency_log {
            use std::io::Write;
            let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
            let mut log = log.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
            let _ = writeln!(log, "{},{slot},{tasks},{lease_ms:.3},{complete_ms:.3}", now.as_millis());
        }
    }
}

/// Serves tasks until `shutdown` resolves; the batches being answered are answered first, the
/// leases of the others given back.
pub async fn run(
    config: TimingOnlyConfig,
    store: ArtifactStore,
    shutdown: impl Future<Output = ()>,
) -> Result<Arc<Tally>, WorkerError> {
    let endpoint = config.coordinator.endpoint()?.connect_timeout(Duration::from_secs(5));
    let channel = config.coordinator.lazy_channel(endpoint)?;
    let engine_json = serde_json::json!({
        "name": "vint-timing-only",
        "version": env!("CARGO_PKG_VERSION"),
        "mode": ENGINE_MODE,
        "accept_rate": config.accept_rate,
    })
    .to_string();
    let latency_log = match &config.latency_log {
        None => None,
        Some(path) => {
            let file = std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(path)
                .map_err(|source| WorkerError::LatencyLog { path: path.clone(), source })?;
            Some(std::sync::Mutex::new(std::io::BufWriter::new(file)))
        }
    };
    let tally = Arc::new(Tally::default());
    let shared = Arc::new(Shared {
        // A package task's lease carries every file of its chunk's renders: a batch of them is
        // tens of MiB.
        client: WorkServiceClient::new(channel).max_decoding_message_size(MAX_MESSAGE_BYTES),
        payloads: Payloads { store, stored: Mutex::default(), metrics: config.metrics.clone() },
        held: Arc::default(),
        tally: tally.clone(),
        engine_json,
        latency_log,
        config,
    });
    let (stop_tx, stop_rx) = watch::channel(false);
    let heartbeat = tokio::spawn(heartbeat_loop(
        shared.client.clone(),
        shared.config.worker_id.clone(),
        shared.held.clone(),
        shared.config.lease_ms,
        shared.config.metrics.clone(),
    ));
    let loops: Vec<_> = (0..shared.config.concurrency.max(1))
        .map(|slot| tokio::spawn(serve_loop(shared.clone(), slot, stop_rx.clone())))
        .collect();
    shutdown.await;
    let _ = stop_tx.send(true);
    for l in loops {
        let _ = l.await;
    }
    heartbeat.abort();
    if let Some(log) = &shared.latency_log {
        use std::io::Write;
        let _ = log.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).flush();
    }
    tracing::info!(
        worker = %shared.config.worker_id,
        completed = tally.completed.load(Ordering::Relaxed),
        refused = tally.refused.load(Ordering::Relaxed),
        failed = tally.failed.load(Ordering::Relaxed),
        "timing-only worker stopped"
    );
    Ok(tally)
}

/// Leases a batch: its tasks and the RPC's round trip in milliseconds.
async fn lease(shared: Arc<Shared>) -> (Vec<pb::LeasedTask>, f64) {
    let started = Instant::now();
    let tasks = lease_batch(&shared).await;
    (tasks, ms(started.elapsed()))
}

async fn lease_batch(shared: &Shared) -> Vec<pb::LeasedTask> {
    let request = pb::LeaseTasksRequest {
        worker_id: shared.config.worker_id.clone(),
        stages: shared.config.stages.iter().map(|s| s.as_str().to_string()).collect(),
        capacity: shared.config.batch,
        lease_ms: shared.config.lease_ms,
        // Constant bytes are no engine's outputs: never reused into a job, nor reusable.
        engines: Default::default(),
        // Only jobs submitted for timing-only workers.
        timing_only: true,
    };
    match shared.client.clone().lease_tasks(request).await {
        Ok(resp) => {
            let tasks = resp.into_inner().tasks;
            shared.held.hold(&tasks);
            tasks
        }
        Err(status) => {
            crate::worker::log_lease_failure(&status);
            Vec::new()
        }
    }
}

async fn serve_loop(shared: Arc<Shared>, slot: u32, mut stop: watch::Receiver<bool>) {
    let mut idle = Duration::from_millis(20);
    let mut next = tokio::spawn(lease(shared.clone()));
    loop {
        shared.config.metrics.beat();
        let (tasks, lease_ms) = next.await.unwrap_or_default();
        let stopping = *stop.borrow();
        if stopping {
            give_back(&shared, &tasks).await;
            return;
        }
        if tasks.is_empty() {
            tokio::select! {
                _ = stop.changed() => return,
                _ = tokio::time::sleep(idle) => {}
            }
            idle = (idle * 2).min(shared.config.max_idle_poll);
            next = tokio::spawn(lease(shared.clone()));
            continue;
        }
        idle = Duration::from_millis(20);
        // Prefetch: the next batch is leased while this one is answered.
        next = tokio::spawn(lease(shared.clone()));
        let n = tasks.len();
        let span = tracing::debug_span!("batch", worker = %shared.config.worker_id, slot, tasks = n);
        let complete_ms = answer_batch(&shared, tasks).instrument(span).await;
        shared.log_batch(slot, n, lease_ms, complete_ms);
    }
}

/// Gives back the leases of a batch not started.
async fn give_back(shared: &Shared, tasks: &[pb::LeasedTask]) {
    crate::worker::release(&shared.client, &shared.config.worker_id, &shared.held, tasks).await;
}

/// Answers a batch; returns the completion RPC's round trip in milliseconds.
async fn answer_batch(shared: &Shared, tasks: Vec<pb::LeasedTask>) -> f64 {
    let mut complete_ms = 0.0;
    let mut completions = Vec::with_capacity(tasks.len());
    for task in &tasks {
        let started = Instant::now();
        match answer(task, &shared.payloads, shared.config.accept_rate).await {
            Ok((result, outputs)) => {
                let total_ms = ms(started.elapsed());
                completions.push(pb::CompleteTaskRequest {
                    worker_id: shared.config.worker_id.clone(),
                    task_id: task.task_id.clone(),
                    attempt: task.attempt,
                    outputs,
                    engine_json: shared.engine_json.clone(),
                    timings: Some(pb::Timings { fetch_ms: 0.0, engine_ms: 0.0, upload_ms: total_ms, total_ms }),
                    result_json: result.to_string(),
                });
            }
            Err(refusal) => {
                tracing::warn!(task = %task.key, retryable = refusal.retryable, error = %refusal.message, "task failed");
                shared.tally.failed.fetch_add(1, Ordering::Relaxed);
                let outcome =
                    if refusal.retryable { TaskOutcome::RetryableFailure } else { TaskOutcome::PermanentFailure };
                shared.record(task, outcome);
                let request = pb::FailTaskRequest {
                    worker_id: shared.config.worker_id.clone(),
                    task_id: task.task_id.clone(),
                    attempt: task.attempt,
                    retryable: refusal.retryable,
                    message: refusal.message,
                };
                if let Err(s) = shared.client.clone().fail_task(request).await {
                    tracing::warn!(error = %s.message(), "could not report the failure; the lease will expire instead");
                }
            }
        }
    }
    let by_id: HashMap<&str, &pb::LeasedTask> = tasks.iter().map(|t| (t.task_id.as_str(), t)).collect();
    for calls in split_by_size(completions) {
        let request = pb::CompleteTasksRequest { tasks: calls };
        let client = shared.client.clone();
        let started = Instant::now();
        let sent = crate::worker::with_retries(|| {
            let mut c = client.clone();
            let r = request.clone();
            async move { c.complete_tasks(r).await.map(tonic::Response::into_inner) }
        })
        .await;
        complete_ms += ms(started.elapsed());
        match sent {
            Ok(resp) => {
                for r in resp.results {
                    let outcome = if r.outcome == Outcome::Completed as i32 {
                        shared.tally.completed.fetch_add(1, Ordering::Relaxed);
                        TaskOutcome::Completed
                    } else {
                        shared.tally.refused.fetch_add(1, Ordering::Relaxed);
                        tracing::warn!(task = %r.task_id, outcome = r.outcome, error = %r.message, "completion refused");
                        if r.outcome == Outcome::LeaseLost as i32 {
                            TaskOutcome::LeaseLost
                        } else {
                            TaskOutcome::Refused
                        }
                    };
                    if let Some(task) = by_id.get(r.task_id.as_str()) {
                        shared.record(task, outcome);
                    }
                }
            }
            Err(s) => {
                tracing::error!(error = %s.message(), "completion failed; these tasks will be leased again");
                for c in &request.tasks {
                    if let Some(task) = by_id.get(c.task_id.as_str()) {
                        shared.record(task, TaskOutcome::Unreported);
                    }
                }
            }
        }
    }
    shared.held.forget_all(&tasks);
    complete_ms
}

/// Completions in calls of at most `MAX_COMPLETION_CALL_BYTES` each (one alone may be larger).
fn split_by_size(completions: Vec<pb::CompleteTaskRequest>) -> Vec<Vec<pb::CompleteTaskRequest>> {
    use prost::Message;
    let mut calls: Vec<Vec<pb::CompleteTaskRequest>> = Vec::new();
    let mut bytes = 0;
    for c in completions {
        let len = c.encoded_len() + 8;
        match calls.last_mut() {
            Some(call) if bytes + len <= MAX_COMPLETION_CALL_BYTES => {
                call.push(c);
                bytes += len;
            }
            _ => {
                calls.push(vec![c]);
                bytes = len;
            }
        }
    }
    calls
}
