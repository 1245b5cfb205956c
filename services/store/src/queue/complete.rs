//! Completing tasks: fenced, batched, with their outputs, attempts and what they unlock.

use std::collections::{BTreeMap, BTreeSet, HashMap, HashSet};

use sqlx::{Any, Row, Transaction};
use vint_core::plan::NewTask;
use vint_core::{AttemptOutcome, TaskState};

use super::lease_lost;
use crate::jobs::json_text;
use crate::sql::sql;
use crate::{Backend, Completion, Result, Store, StoreError, outputs};

/// How completed tasks came by their outputs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    /// A worker ran the attempt: it is recorded in `attempts`.
    Ran,
    /// Taken from another task's result (`Completion::reused_from`): no attempt ran, none is
    /// recorded, and the attempt the lease counted is given back.
    Reused,
}

impl Kind {
    /// The Postgres statement that completes a batch of this kind, and the SQLite fence.
    fn statements(self) -> (&'static str, &'static str) {
        match self {
            Kind::Ran => ("complete_ran", "fence_ran"),
            Kind::Reused => ("complete_reused", "fence_reused"),
        }
    }
}

impl Store {
    /// Completes a task: records its outputs and attempt, unblocks its dependents and
    /// inserts the tasks the planner derived from it, all in one transaction. Refused with
    /// `LeaseLost` unless the caller holds an unexpired lease on this attempt.
    pub async fn complete(&self, c: &Completion, children: &[NewTask], now_ms: i64) -> Result<()> {
        let item = [(c.clone(), children.to_vec())];
        let mut results = self.complete_batch(&item, now_ms).await?;
        results.pop().unwrap_or_else(|| Err(lease_lost(&c.fence)))
    }

    /// Completes many tasks in one transaction of a few set-based statements, whatever the batch's
    /// size. Fenced per task: the result for a completion whose lease was lost (or that repeats a
    /// task earlier in the batch) is `Err(LeaseLost)`, and the others still complete. An error of
    /// the database itself fails the whole call and changes nothing.
    pub async fn complete_batch(
        &self,
        items: &[(Completion, Vec<NewTask>)],
        now_ms: i64,
    ) -> Result<Vec<std::result::Result<(), StoreError>>> {
        let mut seen = HashSet::new();
        let first: Vec<bool> = items.iter().map(|(c, _)| seen.insert(c.fence.task_id.as_str())).collect();
        // Outputs the store cannot pack (a name twice, a digest or key of the wrong shape: the
        // coordinator refuses them first) fail their own completion, not the batch.
        let mut refused: HashMap<String, StoreError> = HashMap::new();
        for ((c, _), first) in items.iter().zip(&first) {
            if *first && let Err(e) = outputs::pack(&c.fence.task_id, &c.outputs) {
                refused.insert(c.fence.task_id.clone(), e);
            }
        }
        let candidates: Vec<&(Completion, Vec<NewTask>)> = items
            .iter()
            .zip(&first)
            .filter(|((c, _), first)| **first && !refused.contains_key(&c.fence.task_id))
            .map(|(item, _)| item)
            .collect();
        if candidates.is_empty() && !refused.is_empty() {
            return Ok(completion_outcomes(items, &first, &HashMap::new(), refused));
        }
        if candidates.is_empty() {
            return Ok(Vec::new());
        }
        // Reused completions record no attempt: they take statements of their own, so that the
        // completions of tasks that ran keep theirs as lean as they were (a `reused_from` and an
        // attempt adjustment in the shared statement cost ~17 % of the batch-256 rate).
        let (reused, ran): (Vec<_>, Vec<_>) = candidates.into_iter().partition(|(c, _)| c.reused_from.is_some());
        let mut done = HashMap::new();
        for (part, kind) in [(ran, Kind::Ran), (reused, Kind::Reused)] {
            if !part.is_empty() {
                done.extend(self.record_batch(&part, kind, now_ms).await?);
            }
        }
        let jobs: BTreeSet<&str> = done.values().map(String::as_str).collect();
        self.finalize_jobs_among(&jobs, now_ms).await?;
        Ok(completion_outcomes(items, &first, &done, refused))
    }

    /// Records the completions whose fence holds, with the tasks they unlock, atomically; returns
    /// the completed task ids with their jobs.
    async fn record_batch(
        &self,
        candidates: &[&(Completion, Vec<NewTask>)],
        kind: Kind,
        now_ms: i64,
    ) -> Result<HashMap<String, String>> {
        if self.backend == Backend::Postgres && candidates.iter().all(|(_, children)| children.is_empty()) {
            // Nothing to insert after the completions: their one statement is a transaction of its
            // own, without the round trips of BEGIN and COMMIT (render, noise and package tasks,
            // most of a job's).
            let mut conn = self.pool.acquire().await?;
            return record_completions_pg(&mut conn, candidates, kind, now_ms).await;
        }
        let mut tx = self.pool.begin().await?;
        let done = match self.backend {
            Backend::Postgres => record_completions_pg(&mut tx, candidates, kind, now_ms).await?,
            Backend::Sqlite => record_completions(&mut tx, candidates, kind, now_ms).await?,
        };
        if done.is_empty() {
            tx.rollback().await?;
            return Ok(done);
        }
        let mut children_by_job: BTreeMap<&str, Vec<NewTask>> = BTreeMap::new();
        for (c, children) in candidates.iter().filter(|(c, _)| done.contains_key(&c.fence.task_id)) {
            children_by_job.entry(done[&c.fence.task_id].as_str()).or_default().extend(children.iter().cloned());
        }
        for (job_id, children) in &children_by_job {
            self.insert_tasks(&mut tx, job_id, children, now_ms).await?;
        }
        tx.commit().await?;
        Ok(done)
    }
}

/// The fence of each completion (`id`, `worker`, `attempt`) with what it records on the task and
/// its attempt, as JSON rows.
fn fence_rows(candidates: &[&(Completion, Vec<NewTask>)]) -> Result<String> {
    let rows: Vec<serde_json::Value> = candidates
        .iter()
        .map(|(c, _)| {
            serde_json::json!({
                "id": c.fence.task_id, "worker": c.fence.worker_id, "attempt": c.fence.attempt,
                "engine": c.engine_json, "result": c.result_json, "timings": c.timings_json,
                "reused": c.reused_from,
            })
        })
        .collect();
    json_text(&rows)
}

/// The outputs of the completions that made any, packed one row a task (`outputs.rs`; the bytes
/// as hex, which each dialect decodes), as JSON rows.
fn output_rows<'a>(completions: impl Iterator<Item = &'a Completion>) -> Result<String> {
    let mut rows = Vec::new();
    for c in completions.filter(|c| !c.outputs.is_empty()) {
        let files = outputs::pack(&c.fence.task_id, &c.outputs)?;
        rows.push(serde_json::json!({
            "task": c.fence.task_id, "files": hex::encode(files), "count": c.outputs.len(),
            "bytes": outputs::total_size(&c.outputs), "samples": c.samples.len(),
        }));
    }
    json_text(&rows)
}

/// Each item's outcome: completed when it was the first of its task in the batch and its fence
/// held (`done`), refused when the store could not pack its outputs (`refused`), its lease lost
/// otherwise.
fn completion_outcomes(
    items: &[(Completion, Vec<NewTask>)],
    first: &[bool],
    done: &HashMap<String, String>,
    mut refused: HashMap<String, StoreError>,
) -> Vec<std::result::Result<(), StoreError>> {
    items
        .iter()
        .zip(first)
        .map(|((c, _), first)| {
            if !*first {
                return Err(lease_lost(&c.fence));
            }
            if let Some(e) = refused.remove(&c.fence.task_id) {
                return Err(e);
            }
            if done.contains_key(&c.fence.task_id) { Ok(()) } else { Err(lease_lost(&c.fence)) }
        })
        .collect()
}

/// Postgres: fences the completions and records what every accepted one made — task, attempt,
/// outputs, unblocked dependents — in ONE statement of data-modifying CTEs keyed on the fenced
/// rows. Returns the accepted tasks' ids with their jobs.
async fn record_completions_pg(
    conn: &mut sqlx::AnyConnection,
    candidates: &[&(Completion, Vec<NewTask>)],
    kind: Kind,
    now_ms: i64,
) -> Result<HashMap<String, String>> {
    let rows = sqlx::query(sql(Backend::Postgres, kind.statements().0)?)
        .bind(TaskState::Succeeded.as_str())
        .bind(TaskState::Running.as_str())
        .bind(now_ms)
        .bind(fence_rows(candidates)?)
        .bind(AttemptOutcome::Succeeded.as_str())
        .bind(output_rows(candidates.iter().map(|(c, _)| c))?)
        .bind(TaskState::Waiting.as_str())
        .bind(TaskState::Queued.as_str())
        .fetch_all(&mut *conn)
        .await?;
    rows.iter().map(|row| Ok((row.try_get::<String, _>("id")?, row.try_get::<String, _>("job_id")?))).collect()
}

/// SQLite (no data-modifying CTEs): the same records as `record_completions_pg`, one set-based
/// statement each.
async fn record_completions(
    tx: &mut Transaction<'static, Any>,
    candidates: &[&(Completion, Vec<NewTask>)],
    kind: Kind,
    now_ms: i64,
) -> Result<HashMap<String, String>> {
    let lite = Backend::Sqlite;
    let done: HashMap<String, String> = sqlx::query(sql(lite, kind.statements().1)?)
        .bind(TaskState::Succeeded.as_str())
        .bind(TaskState::Running.as_str())
        .bind(now_ms)
        .bind(fence_rows(candidates)?)
        .fetch_all(&mut **tx)
        .await?
        .iter()
        .map(|row| Ok((row.try_get::<String, _>("id")?, row.try_get::<String, _>("job_id")?)))
        .collect::<Result<_>>()?;
    if done.is_empty() {
        return Ok(done);
    }
    let accepted: Vec<&(Completion, Vec<NewTask>)> =
        candidates.iter().copied().filter(|(c, _)| done.contains_key(&c.fence.task_id)).collect();
    let ids: Vec<&str> = accepted.iter().map(|(c, _)| c.fence.task_id.as_str()).collect();
    let ids_json = json_text(&ids)?;
    if accepted.iter().any(|(c, _)| !c.outputs.is_empty()) {
        let outputs = output_rows(accepted.iter().map(|(c, _)| c))?;
        sqlx::query(sql(lite, "insert_outputs")?).bind(outputs).execute(&mut **tx).await?;
    }
    // The attempts, written once now that they end (the task's row still holds leased_ms).
    if kind == Kind::Ran {
        sqlx::query(sql(lite, "insert_succeeded_attempts")?)
            .bind(now_ms)
            .bind(AttemptOutcome::Succeeded.as_str())
            .bind(fence_rows(&accepted)?)
            .execute(&mut **tx)
            .await?;
    }
    unblock_dependents(tx, &ids_json, now_ms).await?;
    Ok(done)
}

/// Counts the success of the tasks in `ids_json` (a JSON array of ids) in their dependents, and
/// queues those with no dependency left: one statement for a batch.
async fn unblock_dependents(tx: &mut Transaction<'static, Any>, ids_json: &str, now_ms: i64) -> Result<()> {
    sqlx::query(sql(Backend::Sqlite, "unblock_dependents")?)
        .bind(TaskState::Waiting.as_str())
        .bind(TaskState::Queued.as_str())
        .bind(now_ms)
        .bind(ids_json)
        .execute(&mut **tx)
        .await?;
    Ok(())
}
