//! The worker API (`WorkService`): lease, heartbeat, complete and fail tasks.
//!
//! Every change is fenced in the store on (task, worker, attempt); this layer validates what a
//! worker reports (artifact keys must be the content keys of their hashes, names must be plain
//! relative paths) and asks the planner what a completion unlocks.

use tonic::{Request, Response, Status};
use tracing::Instrument;
use vint_core::Stage;
use vint_proto::v1 as pb;
use vint_proto::v1::work_service_server::WorkService;
use vint_store::{Completion, Fence, NewArtifact, Store};

use crate::convert::{self, status};
use crate::planner;
use crate::{CoordinatorConfig, now_ms};

#[derive(Clone)]
pub struct WorkApi {
    store: Store,
    config: CoordinatorConfig,
}

impl WorkApi {
    pub fn new(store: Store, config: CoordinatorConfig) -> WorkApi {
        WorkApi { store, config }
    }

    fn lease_ms(&self, asked: u32) -> i64 {
        if asked == 0 { self.config.default_lease_ms } else { i64::from(asked).clamp(1_000, 600_000) }
    }
}

/// Longest accepted artifact name, and most outputs per task.
const MAX_NAME_LEN: usize = 256;
const MAX_OUTPUTS: usize = 10_000;

fn validate_output(a: &pb::ArtifactRef) -> Result<NewArtifact, Status> {
    let bad = |why: &str| Status::invalid_argument(format!("output {:?}: {why}", a.name));
    if a.name.is_empty()
        || a.name.len() > MAX_NAME_LEN
        || a.name.starts_with('/')
        || a.name.split('/').any(|part| part.is_empty() || part == "." || part == "..")
    {
        return Err(bad("name must be a relative path without empty, '.' or '..' parts"));
    }
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
        let req = request.into_inner();
        let stages = req
            .stages
            .iter()
            .map(|s| s.parse::<Stage>().map_err(|e| Status::invalid_argument(e.to_string())))
            .collect::<Result<Vec<_>, _>>()?;
        let capacity = req.capacity.clamp(1, 256);
        let leased = self
            .store
            .lease(&req.worker_id, &stages, capacity, self.lease_ms(req.lease_ms), now_ms())
            .await
            .map_err(status)?;
        let tasks = leased
            .into_iter()
            .map(|t| {
                tracing::info!(job = %t.job_id, task = %t.key, stage = %t.stage, attempt = t.attempt, worker = %req.worker_id, "leased");
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
        let req = request.into_inner();
        let held: Vec<(String, u32)> = req.held.iter().map(|h| (h.task_id.clone(), h.attempt)).collect();
        let lease_ms = self.lease_ms(req.lease_ms);
        let now = now_ms();
        let lost = self.store.heartbeat(&req.worker_id, &held, lease_ms, now).await.map_err(status)?;
        Ok(Response::new(pb::HeartbeatResponse {
            lost: lost.into_iter().map(|(task_id, attempt)| pb::TaskAttempt { task_id, attempt }).collect(),
            lease_deadline_ms: now + lease_ms,
        }))
    }

    async fn complete_task(
        &self,
        request: Request<pb::CompleteTaskRequest>,
    ) -> Result<Response<pb::CompleteTaskResponse>, Status> {
        let req = request.into_inner();
        if req.outputs.len() > MAX_OUTPUTS {
            return Err(Status::invalid_argument(format!("at most {MAX_OUTPUTS} outputs per task")));
        }
        let outputs = req.outputs.iter().map(validate_output).collect::<Result<Vec<_>, _>>()?;
        let task = self
            .store
            .task(&req.task_id)
            .await
            .map_err(status)?
            .ok_or_else(|| Status::not_found(format!("task {} not found", req.task_id)))?;
        let span = tracing::info_span!("complete", job = %task.job_id, task = %task.key, stage = %task.stage, attempt = req.attempt);
        async {
            // Only a grasp chunk unlocks tasks, planned from the job's plan: no other completion
            // reads the job.
            let plan = if task.stage == Stage::Grasp {
                let job = self
                    .store
                    .job(&task.job_id)
                    .await
                    .map_err(status)?
                    .ok_or_else(|| Status::not_found(format!("job {} not found", task.job_id)))?;
                Some(planner::job_plan(&self.store, &job).await?)
            } else {
                None
            };
            let unlocked = planner::on_complete(plan.as_ref(), &task, &req.result_json, &outputs)
                .map_err(|e| Status::invalid_argument(e.to_string()))?;
            let completion = Completion {
                fence: Fence { task_id: req.task_id.clone(), worker_id: req.worker_id.clone(), attempt: req.attempt },
                outputs,
                engine_json: req.engine_json.clone(),
                timings_json: serde_json::to_string(&req.timings.map(|t| {
                    serde_json::json!({"fetch_ms": t.fetch_ms, "engine_ms": t.engine_ms, "upload_ms": t.upload_ms, "total_ms": t.total_ms})
                }))
                .unwrap_or_default(),
                result_json: req.result_json.clone(),
                samples: unlocked.samples,
            };
            self.store.complete(&completion, &unlocked.children, now_ms()).await.map_err(status)?;
            tracing::info!(children = unlocked.children.len(), worker = %req.worker_id, "completed");
            Ok(Response::new(pb::CompleteTaskResponse {}))
        }
        .instrument(span)
        .await
    }

    async fn fail_task(&self, request: Request<pb::FailTaskRequest>) -> Result<Response<pb::FailTaskResponse>, Status> {
        let req = request.into_inner();
        let fence = Fence { task_id: req.task_id.clone(), worker_id: req.worker_id.clone(), attempt: req.attempt };
        let will_retry = self.store.fail(&fence, req.retryable, &req.message, now_ms()).await.map_err(status)?;
        tracing::warn!(task = %req.task_id, attempt = req.attempt, retryable = req.retryable, will_retry, message = %req.message, "task failed");
        Ok(Response::new(pb::FailTaskResponse { will_retry }))
    }
}
