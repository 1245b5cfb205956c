//! The worker API (`WorkService`): lease, heartbeat, complete, fail and release tasks.
//!
//! Every change is fenced in the store on (task, worker, attempt); this layer validates what a
//! worker reports (artifact keys must be the content keys of their hashes, names must be plain
//! relative paths) and asks the planner what a completion unlocks. With a tokens file, a call
//! acts for the worker id it claims under its token's name (`acting_worker`), and one token holds
//! at most `max_leases_per_token` leases.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use tonic::{Request, Response, Status};
use vint_core::Stage;
use vint_core::plan::{JobPlan, NewTask};
use vint_proto::v1 as pb;
use vint_proto::v1::completion_result::Outcome;
use vint_proto::v1::work_service_server::WorkService;
use vint_store::{Completion, Fence, NewArtifact, Store, TaskRecord};

use crate::auth::Caller;
use crate::convert::{self, status};
use crate::metrics::{Refusal, Rpc};
use crate::planner;
use crate::reuse;
use crate::{CoordinatorConfig, now_ms};

#[derive(Clone)]
pub struct WorkApi {
    pub(crate) store: Store,
    pub(crate) config: CoordinatorConfig,
    plans: Arc<Mutex<HashMap<String, Arc<JobPlan>>>>,
}

impl WorkApi {
    pub fn new(store: Store, config: CoordinatorConfig) -> WorkApi {
        WorkApi { store, config, plans: Arc::default() }
    }

    fn lease_ms(&self, asked: u32) -> i64 {
        if asked == 0 { self.config.default_lease_ms } else { i64::from(asked).clamp(1_000, 600_000) }
    }

    /// A job's plan, read once per coordinator: plans are fixed at submit.
    pub(crate) async fn plan_of(&self, job_id: &str) -> Result<Arc<JobPlan>, Status> {
        if let Some(plan) = self.plans.lock().map_err(|_| Status::internal("plan cache poisoned"))?.get(job_id) {
            return Ok(plan.clone());
        }
        let job = self
            .store
            .job(job_id)
            .await
            .map_err(status)?
            .ok_or_else(|| Status::not_found(format!("job {job_id} not found")))?;
        let plan = Arc::new(planner::job_plan(&self.store, &job).await?);
        let mut plans = self.plans.lock().map_err(|_| Status::internal("plan cache poisoned"))?;
        if plans.len() >= PLAN_CACHE_JOBS {
            plans.clear();
        }
        plans.insert(job_id.to_string(), plan.clone());
        Ok(plan)
    }

    /// Checks and plans each completion, then records all that passed in one store call (one
    /// transaction). The answer has one result per request, in order: a bad report or a lost
    /// lease refuses that task alone.
    async fn complete_many(&self, reqs: Vec<pb::CompleteTaskRequest>) -> Result<Vec<pb::CompletionResult>, Status> {
        let ids: Vec<String> = reqs.iter().map(|r| r.task_id.clone()).collect();
        let tasks: HashMap<String, TaskRecord> =
            self.store.tasks(&ids).await.map_err(status)?.into_iter().map(|t| (t.id.clone(), t)).collect();
        let mut results: Vec<pb::CompletionResult> = reqs
            .iter()
            .map(|r| pb::CompletionResult {
                task_id: r.task_id.clone(),
                attempt: r.attempt,
                outcome: Outcome::Completed as i32,
                message: String::new(),
            })
            .collect();
        let mut batch = Vec::with_capacity(reqs.len());
        let mut batch_index = Vec::with_capacity(reqs.len());
        for (i, req) in reqs.into_iter().enumerate() {
            let Some(task) = tasks.get(&req.task_id) else {
                self.config.metrics.completion_refused(Refusal::NotFound);
                results[i].outcome = Outcome::NotFound as i32;
                results[i].message = format!("task {} not found", req.task_id);
                continue;
            };
            match self.prepare(task, req).await {
                Ok(item) => {
                    batch.push(item);
                    batch_index.push(i);
                }
                Err(message) => {
                    self.config.metrics.completion_refused(Refusal::Invalid);
                    results[i].outcome = Outcome::Invalid as i32;
                    results[i].message = message;
                }
            }
        }
        let stored = self.store.complete_batch(&batch, now_ms()).await.map_err(status)?;
        for ((i, outcome), (completion, children)) in batch_index.into_iter().zip(stored).zip(&batch) {
            let task = &tasks[&completion.fence.task_id];
            match outcome {
                Ok(()) => {
                    self.config.metrics.task_completed(task.stage);
                    tracing::info!(
                        job = %task.job_id, task = %task.key, stage = %task.stage, attempt = completion.fence.attempt,
                        worker = %completion.fence.worker_id, children = children.len(), "completed"
                    )
                }
                Err(e) => {
                    // The store refuses outputs it cannot pack (the checks above come first, so
                    // this is a defence) as invalid; anything else per task is a lost lease.
                    let (refusal, outcome) = match e {
                        vint_store::StoreError::Invalid(_) => (Refusal::Invalid, Outcome::Invalid),
                        _ => (Refusal::LeaseLost, Outcome::LeaseLost),
                    };
                    self.config.metrics.completion_refused(refusal);
                    tracing::warn!(job = %task.job_id, task = %task.key, error = %e, "completion refused");
                    results[i].outcome = outcome as i32;
                    results[i].message = e.to_string();
                }
            }
        }
        Ok(results)
    }

    /// A worker's report checked and turned into a store completion plus the tasks it unlocks;
    /// `Err` says what is wrong with the report.
    async fn prepare(
        &self,
        task: &TaskRecord,
        req: pb::CompleteTaskRequest,
    ) -> Result<(Completion, Vec<NewTask>), String> {
        if req.outputs.len() > MAX_OUTPUTS {
            return Err(format!("at most {MAX_OUTPUTS} outputs per task"));
        }
        let outputs = req.outputs.iter().map(validate_output).collect::<Result<Vec<_>, _>>()?;
        // A task names each output once (the database no longer checks it: migration 0012).
        let mut names = std::collections::HashSet::with_capacity(outputs.len());
        if let Some(twice) = outputs.iter().find(|o| !names.insert(o.name.as_str())) {
            return Err(format!("output {:?}: named twice", twice.name));
        }
        // Only a grasp chunk unlocks tasks, planned from the job's plan: no other completion
        // reads the job.
        let plan = if task.stage == Stage::Grasp {
            Some(self.plan_of(&task.job_id).await.map_err(|s| s.message().to_string())?)
        } else {
            None
        };
        let unlocked = planner::on_complete(plan.as_deref(), task.into(), &req.result_json, &outputs)
            .map_err(|e| e.to_string())?;
        let timings = req.timings.map(|t| {
            serde_json::json!({"fetch_ms": t.fetch_ms, "engine_ms": t.engine_ms, "upload_ms": t.upload_ms, "total_ms": t.total_ms})
        });
        let completion = Completion {
            fence: Fence { task_id: req.task_id, worker_id: req.worker_id, attempt: req.attempt },
            outputs,
            engine_json: req.engine_json,
            timings_json: serde_json::to_string(&timings).unwrap_or_default(),
            result_json: req.result_json,
            samples: unlocked.samples,
            reused_from: None,
        };
        Ok((completion, unlocked.children))
    }
}

/// Longest worker id a call may claim.
const MAX_WORKER_ID_LEN: usize = 128;

/// The worker id a call acts as: the id it claims (1 to 128 of `A-Z a-z 0-9 . _ -`), under its
/// token's name when the coordinator checks tokens (`NAME/ID`). The fences compare it, and the
/// attempts record it, so the holder of one token acts on its own leases only.
fn acting_worker<T>(request: &Request<T>, claimed: &str) -> Result<String, Status> {
    let valid = !claimed.is_empty()
        && claimed.len() <= MAX_WORKER_ID_LEN
        && claimed.bytes().all(|b| b.is_ascii_alphanumeric() || matches!(b, b'.' | b'_' | b'-'));
    if !valid {
        let shown: String = claimed.chars().take(MAX_WORKER_ID_LEN).collect();
        return Err(Status::invalid_argument(format!(
            "worker_id {shown:?}: must be 1 to {MAX_WORKER_ID_LEN} of A-Z, a-z, 0-9, '.', '_' and '-'"
        )));
    }
    Ok(match request.extensions().get::<Caller>() {
        Some(caller) => format!("{}/{claimed}", caller.name),
        None => claimed.to_string(),
    })
}

/// Longest accepted artifact name, and most outputs per task.
const MAX_NAME_LEN: usize = 256;
const MAX_OUTPUTS: usize = 10_000;
/// Most completions in one `CompleteTasks` call.
const MAX_BATCH: usize = 1_024;
/// Jobs whose plans the coordinator keeps in memory; past it the cache starts over.
const PLAN_CACHE_JOBS: usize = 256;

fn validate_output(a: &pb::ArtifactRef) -> Result<NewArtifact, String> {
    let bad = |why: &str| format!("output {:?}: {why}", a.name);
    if a.name.is_empty()
        || a.name.len() > MAX_NAME_LEN
        || a.name.starts_with('/')
        || a.name.split('/').any(|part| part.is_empty() || part == "." || part == "..")
    {
        return Err(bad("name must be a relative path without empty, '.' or '..' parts"));
    }
    // A key of a bad shape (a path out of the store) is refused whatever the digest says.
    vint_artifacts::check_key(&a.key).map_err(|e| bad(&e.to_string()))?;
    let key = vint_artifacts::key_for(&a.sha256).map_err(|e| bad(&e.to_string()))?;
    if a.key != key {
        return Err(bad(&format!("key must be the content key {key}, got {:?}", a.key)));
    }
    Ok(NewArtifact {
        name: a.name.clone(),
        sha256: a.sha256.clone(),
        size: a.size,
        media_type: a.media_type.clone(),
        object_key: key,
    })
}

#[tonic::async_trait]
impl WorkService for WorkApi {
    async fn lease_tasks(
        &self,
        request: Request<pb::LeaseTasksRequest>,
    ) -> Result<Response<pb::LeaseTasksResponse>, Status> {
        let _timer = self.config.metrics.time_rpc(Rpc::LeaseTasks);
        let worker_id = acting_worker(&request, &request.get_ref().worker_id)?;
        let caller = request.extensions().get::<Caller>().cloned();
        let req = request.into_inner();
        let stages = req
            .stages
            .iter()
            .map(|s| s.parse::<Stage>().map_err(|e| Status::invalid_argument(e.to_string())))
            .collect::<Result<Vec<_>, _>>()?;
        let identities = reuse::identities(&req.engines, &stages)?;
        let mut capacity = req.capacity.clamp(1, 256) as usize;
        if let Some(caller) = caller {
            let cap = self.config.max_leases_per_token;
            let held = self.store.leases_held_by(&format!("{}/", caller.name)).await.map_err(status)?;
            let room = cap.saturating_sub(held);
            if room == 0 {
                return Err(Status::resource_exhausted(format!(
                    "token {} holds {held} leases, the most one token may hold (--max-leases-per-token {cap}); \
                     report or give back some first",
                    caller.name
                )));
            }
            capacity = capacity.min(usize::try_from(room).unwrap_or(usize::MAX));
        }
        let started = std::time::Instant::now();
        let mut leased = Vec::new();
        loop {
            let (room, lease_ms) = ((capacity - leased.len()) as u32, self.lease_ms(req.lease_ms));
            let batch = if req.timing_only {
                self.store.lease_timing_only(&worker_id, &stages, room, lease_ms, now_ms).await
            } else {
                self.store.lease(&worker_id, &stages, room, lease_ms, now_ms).await
            }
            .map_err(status)?;
            if batch.is_empty() {
                break;
            }
            let (hand_out, reused) = self.reuse_leased(&worker_id, batch, &identities).await?;
            leased.extend(hand_out);
            // What a reuse unlocked may be leasable at once: lease again while there is room.
            if reused == 0 || leased.len() >= capacity || started.elapsed() >= reuse::REUSE_BUDGET {
                break;
            }
        }
        let tasks = leased
            .into_iter()
            .map(|t| {
                self.config.metrics.task_leased(t.stage);
                tracing::info!(job = %t.job_id, task = %t.key, stage = %t.stage, attempt = t.attempt, worker = %worker_id, "leased");
                pb::LeasedTask {
                    task_id: t.id,
                    job_id: t.job_id,
                    key: t.key,
                    stage: t.stage.as_str().to_string(),
                    attempt: t.attempt,
                    params_json: t.params_json,
                    inputs: t.inputs.iter().map(convert::artifact).collect(),
                    lease_deadline_ms: t.lease_deadline_ms,
                }
            })
            .collect();
        Ok(Response::new(pb::LeaseTasksResponse { tasks }))
    }

    async fn heartbeat(
        &self,
        request: Request<pb::HeartbeatRequest>,
    ) -> Result<Response<pb::HeartbeatResponse>, Status> {
        let _timer = self.config.metrics.time_rpc(Rpc::Heartbeat);
        let worker_id = acting_worker(&request, &request.get_ref().worker_id)?;
        let req = request.into_inner();
        let held: Vec<(String, u32)> = req.held.iter().map(|h| (h.task_id.clone(), h.attempt)).collect();
        let lease_ms = self.lease_ms(req.lease_ms);
        let beat = self.store.heartbeat(&worker_id, &held, lease_ms, now_ms).await.map_err(status)?;
        Ok(Response::new(pb::HeartbeatResponse {
            lost: beat.lost.into_iter().map(|(task_id, attempt)| pb::TaskAttempt { task_id, attempt }).collect(),
            lease_deadline_ms: beat.deadline_ms,
        }))
    }

    async fn complete_task(
        &self,
        request: Request<pb::CompleteTaskRequest>,
    ) -> Result<Response<pb::CompleteTaskResponse>, Status> {
        let _timer = self.config.metrics.time_rpc(Rpc::CompleteTask);
        let worker_id = acting_worker(&request, &request.get_ref().worker_id)?;
        let mut req = request.into_inner();
        req.worker_id = worker_id;
        let mut results = self.complete_many(vec![req]).await?;
        let r = results.pop().ok_or_else(|| Status::internal("a completion went unanswered"))?;
        match pb::completion_result::Outcome::try_from(r.outcome) {
            Ok(Outcome::Completed) => Ok(Response::new(pb::CompleteTaskResponse {})),
            Ok(Outcome::LeaseLost) => Err(Status::failed_precondition(r.message)),
            Ok(Outcome::NotFound) => Err(Status::not_found(r.message)),
            _ => Err(Status::invalid_argument(r.message)),
        }
    }

    async fn complete_tasks(
        &self,
        request: Request<pb::CompleteTasksRequest>,
    ) -> Result<Response<pb::CompleteTasksResponse>, Status> {
        let _timer = self.config.metrics.time_rpc(Rpc::CompleteTasks);
        let n = request.get_ref().tasks.len();
        if n > MAX_BATCH {
            return Err(Status::invalid_argument(format!("tasks: {n} completions in one call, at most {MAX_BATCH}")));
        }
        let acting: Vec<String> =
            request.get_ref().tasks.iter().map(|t| acting_worker(&request, &t.worker_id)).collect::<Result<_, _>>()?;
        let mut tasks = request.into_inner().tasks;
        for (task, worker_id) in tasks.iter_mut().zip(acting) {
            task.worker_id = worker_id;
        }
        let results = self.complete_many(tasks).await?;
        Ok(Response::new(pb::CompleteTasksResponse { results }))
    }

    async fn fail_task(&self, request: Request<pb::FailTaskRequest>) -> Result<Response<pb::FailTaskResponse>, Status> {
        let _timer = self.config.metrics.time_rpc(Rpc::FailTask);
        let worker_id = acting_worker(&request, &request.get_ref().worker_id)?;
        let req = request.into_inner();
        let fence = Fence { task_id: req.task_id.clone(), worker_id, attempt: req.attempt };
        let will_retry = self.store.fail(&fence, req.retryable, &req.message, now_ms()).await.map_err(status)?;
        // The report names no stage; failures are rare enough for one more read. The failure is
        // recorded whether or not the metric can be.
        if let Ok(Some(task)) = self.store.task(&req.task_id).await {
            self.config.metrics.task_failed(task.stage, will_retry);
        }
        tracing::warn!(task = %req.task_id, attempt = req.attempt, retryable = req.retryable, will_retry, message = %req.message, "task failed");
        Ok(Response::new(pb::FailTaskResponse { will_retry }))
    }

    async fn release_tasks(
        &self,
        request: Request<pb::ReleaseTasksRequest>,
    ) -> Result<Response<pb::ReleaseTasksResponse>, Status> {
        let worker_id = acting_worker(&request, &request.get_ref().worker_id)?;
        let req = request.into_inner();
        if req.tasks.len() > MAX_BATCH {
            return Err(Status::invalid_argument(format!(
                "tasks: {} leases in one call, at most {MAX_BATCH}",
                req.tasks.len()
            )));
        }
        let held: Vec<(String, u32)> = req.tasks.iter().map(|t| (t.task_id.clone(), t.attempt)).collect();
        let released = self.store.release(&worker_id, &held, now_ms()).await.map_err(status)?;
        tracing::info!(worker = %worker_id, asked = held.len(), released = released.len(), "leases given back");
        Ok(Response::new(pb::ReleaseTasksResponse {
            released: released.into_iter().map(|(task_id, attempt)| pb::TaskAttempt { task_id, attempt }).collect(),
        }))
    }
}
