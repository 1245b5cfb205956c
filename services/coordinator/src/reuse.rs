//! Task reuse at lease time (`vint_core::reuse`).
//!
//! A worker names the engine identity of each stage it runs. When it leases tasks of such a
//! stage, the coordinator keys each task by content — stage, identity, parameters, and the content
//! hashes of the inputs the lease statement has just read — and records the key (`task_keys`).
//! A task whose key a succeeded task already holds (this job's or any earlier one's) is completed
//! at once from that task's result and outputs, through the same fenced completion and planner as
//! a worker's report, and is not handed out; the worker gets the rest. The coordinator keeps
//! leasing until it has tasks to hand out, the queue is empty, or `REUSE_BUDGET` is spent, so a
//! job that reuses most of its work finishes at the speed of the database, not of worker polls.
//!
//! Nothing here reads artifact bytes: reused outputs are the same content-addressed objects.

use std::collections::HashMap;

use tonic::Status;
use vint_core::Stage;
use vint_core::plan::NewTask;
use vint_core::reuse::{self, Input};
use vint_store::{Completion, Fence, LeasedTask, StoredResult};

use crate::convert::status;
use crate::now_ms;
use crate::planner;
use crate::work_api::WorkApi;

/// How long one `LeaseTasks` call may go on completing reusable tasks before it answers.
pub(crate) const REUSE_BUDGET: std::time::Duration = std::time::Duration::from_secs(2);

/// The engine identities a worker declared, by stage; a stage it does not lease, or an identity
/// that is not a short plain token, is refused naming the entry.
pub(crate) fn identities(
    declared: &HashMap<String, String>,
    stages: &[Stage],
) -> Result<HashMap<Stage, String>, Status> {
    let mut out = HashMap::new();
    for (name, identity) in declared {
        let stage: Stage = name
            .parse()
            .map_err(|e: vint_core::stage::UnknownStage| Status::invalid_argument(format!("engines[{name:?}]: {e}")))?;
        if !stages.contains(&stage) {
            return Err(Status::invalid_argument(format!(
                "engines[{name:?}]: names a stage the request does not lease ({})",
                stages.iter().map(|s| s.as_str()).collect::<Vec<_>>().join(", ")
            )));
        }
        if !reuse::valid_identity(identity) {
            return Err(Status::invalid_argument(format!(
                "engines[{name:?}]: {identity:?} is not an engine identity (1 to {} characters of \
                 [A-Za-z0-9._:+-])",
                reuse::MAX_IDENTITY_LEN
            )));
        }
        out.insert(stage, identity.clone());
    }
    Ok(out)
}

/// The reuse key of a leased task run by an engine of `identity`.
pub(crate) fn key_of(task: &LeasedTask, identity: &str) -> String {
    let inputs: Vec<Input<'_>> =
        task.inputs.iter().map(|a| Input { task_key: &a.task_key, name: &a.name, sha256: &a.sha256 }).collect();
    reuse::task_key(task.stage, identity, &task.params_json, &inputs)
}

/// A leased task as the planner reads it.
fn done(task: &LeasedTask) -> planner::Done<'_> {
    planner::Done {
        id: &task.id,
        job_id: &task.job_id,
        key: &task.key,
        stage: task.stage,
        params_json: &task.params_json,
    }
}

impl WorkApi {
    /// Keys the leased tasks whose stage has a declared identity, completes those whose key has a
    /// stored result, and returns the others (to hand out) with the number reused.
    pub(crate) async fn reuse_leased(
        &self,
        worker_id: &str,
        leased: Vec<LeasedTask>,
        identities: &HashMap<Stage, String>,
    ) -> Result<(Vec<LeasedTask>, usize), Status> {
        let keys: Vec<(String, u32, String)> = leased
            .iter()
            .filter_map(|t| identities.get(&t.stage).map(|id| (t.id.clone(), t.attempt, key_of(t, id))))
            .collect();
        if keys.is_empty() {
            return Ok((leased, 0));
        }
        self.store.set_content_keys(&keys).await.map_err(status)?;
        let wanted: Vec<String> = keys.iter().map(|(_, _, k)| k.clone()).collect();
        let found = self.store.stored_results(&wanted).await.map_err(status)?;
        let key_by_task: HashMap<&str, &str> = keys.iter().map(|(id, _, k)| (id.as_str(), k.as_str())).collect();
        let mut hand_out = Vec::new();
        let mut batch: Vec<(Completion, Vec<NewTask>)> = Vec::new();
        let mut reused_tasks: Vec<LeasedTask> = Vec::new();
        for task in leased {
            let hit = key_by_task.get(task.id.as_str()).and_then(|k| found.get(*k)).filter(|r| r.task_id != task.id);
            let Some(stored) = hit else {
                hand_out.push(task);
                continue;
            };
            match self.reused_completion(worker_id, &task, stored).await {
                Ok(item) => {
                    batch.push(item);
                    reused_tasks.push(task);
                }
                Err(message) => {
                    // The stored result does not plan here (it cannot, for the same key, unless the
                    // store was edited): the task runs instead.
                    tracing::warn!(job = %task.job_id, task = %task.key, from = %stored.task_id, %message, "not reused");
                    hand_out.push(task);
                }
            }
        }
        if batch.is_empty() {
            return Ok((hand_out, 0));
        }
        let outcomes = self.store.complete_batch(&batch, now_ms()).await.map_err(status)?;
        let mut reused = 0;
        for ((outcome, task), (completion, children)) in outcomes.into_iter().zip(reused_tasks).zip(&batch) {
            let from = completion.reused_from.as_deref().unwrap_or_default();
            match outcome {
                Ok(()) => {
                    reused += 1;
                    self.config.metrics.task_completed(task.stage);
                    self.config.metrics.task_reused(task.stage);
                    tracing::info!(
                        job = %task.job_id, task = %task.key, stage = %task.stage, from, children = children.len(), "reused"
                    );
                }
                // Only the reaper or a cancel can have taken the lease in these milliseconds.
                Err(e) => tracing::warn!(job = %task.job_id, task = %task.key, error = %e, "reuse refused"),
            }
        }
        Ok((hand_out, reused))
    }

    /// The completion that takes `stored` as `task`'s result, with what it unlocks.
    async fn reused_completion(
        &self,
        worker_id: &str,
        task: &LeasedTask,
        stored: &StoredResult,
    ) -> Result<(Completion, Vec<NewTask>), String> {
        let plan = if task.stage == Stage::Grasp {
            Some(self.plan_of(&task.job_id).await.map_err(|s| s.message().to_string())?)
        } else {
            None
        };
        let unlocked = planner::on_complete(plan.as_deref(), done(task), &stored.result_json, &stored.outputs)
            .map_err(|e| e.to_string())?;
        let completion = Completion {
            fence: Fence { task_id: task.id.clone(), worker_id: worker_id.to_string(), attempt: task.attempt },
            outputs: stored.outputs.clone(),
            engine_json: stored.engine_json.clone(),
            timings_json: "null".into(),
            result_json: stored.result_json.clone(),
            samples: unlocked.samples,
            reused_from: Some(stored.task_id.clone()),
        };
        Ok((completion, unlocked.children))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn declared(pairs: &[(&str, &str)]) -> HashMap<String, String> {
        pairs.iter().map(|(s, id)| (s.to_string(), id.to_string())).collect()
    }

    #[test]
    fn declared_identities_are_checked_entry_by_entry() {
        let stages = [Stage::Render, Stage::Package];
        let ok = identities(&declared(&[("render", "abc123"), ("package", "vint-package-format-1")]), &stages).unwrap();
        assert_eq!(ok[&Stage::Render], "abc123");
        let unknown = identities(&declared(&[("paint", "x")]), &stages).unwrap_err();
        assert!(unknown.message().contains("engines[\"paint\"]"), "{}", unknown.message());
        let not_leased = identities(&declared(&[("grasp", "x")]), &stages).unwrap_err();
        assert!(not_leased.message().contains("does not lease"), "{}", not_leased.message());
        let bad = identities(&declared(&[("render", "a b")]), &stages).unwrap_err();
        assert!(bad.message().contains("is not an engine identity"), "{}", bad.message());
        assert!(identities(&HashMap::new(), &stages).unwrap().is_empty());
    }
}
