//! Completing tasks: fenced, batched, with their outputs, attempts and what they unlock.

use std::collections::{BTreeMap, BTreeSet, HashMap, HashSet};

use sqlx::{Any, Row, Transaction};
use vint_core::plan::NewTask;
use vint_core::{AttemptOutcome, TaskState};

use super::lease_lost;
use crate::jobs::json_text;
use crate::{Backend, Completion, Result, Store, StoreError, outputs, trusted};

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
    /// What a completion of this kind sets on the task's row besides its result.
    fn set_clause(self) -> &'static str {
        match self {
            Kind::Ran => "",
            Kind::Reused => "reused_from = c.reused, attempt = tasks.attempt - 1, ",
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
            Backend::Sqlite => record_completions(&mut tx, self.backend, candidates, kind, now_ms).await?,
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

const FENCE_COLUMNS: &[(&str, &str)] = &[
    ("id", "text"),
    ("worker", "text"),
    ("attempt", "bigint"),
    ("engine", "text"),
    ("result", "text"),
    ("timings", "text"),
    ("reused", "text"),
];
pub(crate) const OUTPUT_COLUMNS: &[(&str, &str)] =
    &[("task", "text"), ("files", "text"), ("count", "bigint"), ("bytes", "bigint"), ("samples", "bigint")];

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
    let pg = Backend::Postgres;
    let sql = format!(
        "WITH c AS (SELECT * FROM {fences}), \
         done AS (UPDATE tasks SET state = $1, lease_owner = NULL, lease_deadline_ms = NULL, engine_json = c.engine, \
           result_json = c.result, {reuse}updated_ms = $3 FROM c WHERE tasks.id = c.id AND tasks.state = $2 \
           AND tasks.lease_owner = c.worker AND tasks.attempt = c.attempt AND tasks.lease_deadline_ms >= $3 \
           RETURNING tasks.id, tasks.job_id, tasks.attempt, tasks.leased_ms), \
         {ended}
         outputs AS (INSERT INTO outputs (task_id, files, count, bytes, samples) \
           SELECT o.task, decode(o.files, 'hex'), o.count, o.bytes, o.samples FROM {outputs} \
           JOIN done ON done.id = o.task), \
         finished AS (SELECT d.task_id, COUNT(*) AS n FROM done JOIN task_deps d ON d.depends_on = done.id \
           GROUP BY d.task_id), \
         waiting AS (SELECT t.id, finished.n FROM tasks t JOIN finished ON finished.task_id = t.id ORDER BY t.id \
           FOR UPDATE OF t), \
         unblocked AS (UPDATE tasks SET deps_pending = tasks.deps_pending - w.n, \
           state = CASE WHEN tasks.state = $7 AND tasks.deps_pending - w.n = 0 THEN $8 ELSE tasks.state END, \
           updated_ms = $3 FROM waiting w WHERE tasks.id = w.id) \
         SELECT id, job_id FROM done",
        fences = pg.json_rows("$4", "c", FENCE_COLUMNS),
        outputs = pg.json_rows("$6", "o", OUTPUT_COLUMNS),
        reuse = kind.set_clause(),
        ended = match kind {
            Kind::Ran =>
                "ended AS (INSERT INTO attempts (task_id, attempt, worker_id, started_ms, ended_ms, outcome, \
                engine_json, timings_json) SELECT done.id, done.attempt, c.worker, COALESCE(done.leased_ms, $3), $3, $5, \
                c.engine, c.timings FROM done JOIN c ON c.id = done.id), ",
            // $5 is still bound: a statement may leave a parameter unused only if it is typed.
            Kind::Reused => "ended AS (SELECT CAST($5 AS TEXT) AS outcome), ",
        },
    );
    let rows = sqlx::query(trusted(sql))
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
    backend: Backend,
    candidates: &[&(Completion, Vec<NewTask>)],
    kind: Kind,
    now_ms: i64,
) -> Result<HashMap<String, String>> {
    // The fence: only running tasks leased to the caller, at this attempt, before the deadline.
    let sql = format!(
        "UPDATE tasks SET state = $1, lease_owner = NULL, lease_deadline_ms = NULL, engine_json = c.engine, \
         result_json = c.result, {reuse}updated_ms = $3 FROM {rows} WHERE tasks.id = c.id AND tasks.state = $2 \
         AND tasks.lease_owner = c.worker AND tasks.attempt = c.attempt AND tasks.lease_deadline_ms >= $3 \
         RETURNING tasks.id, tasks.job_id",
        rows = backend.json_rows("$4", "c", FENCE_COLUMNS),
        reuse = kind.set_clause(),
    );
    let done: HashMap<String, String> = sqlx::query(trusted(sql))
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
        let sql = format!(
            "INSERT INTO outputs (task_id, files, count, bytes, samples) SELECT o.task, {}, o.count, o.bytes, \
             o.samples FROM {}",
            backend.bytes_from_hex("o.files"),
            backend.json_rows("$1", "o", OUTPUT_COLUMNS),
        );
        let outputs = output_rows(accepted.iter().map(|(c, _)| c))?;
        sqlx::query(trusted(sql)).bind(outputs).execute(&mut **tx).await?;
    }
    // The attempts, written once now that they end (the task's row still holds leased_ms).
    if kind == Kind::Ran {
        let sql = format!(
            "INSERT INTO attempts (task_id, attempt, worker_id, started_ms, ended_ms, outcome, engine_json, \
             timings_json) SELECT e.id, e.attempt, e.worker, COALESCE(t.leased_ms, $1), $1, $2, e.engine, e.timings \
             FROM {} JOIN tasks t ON t.id = e.id",
            backend.json_rows("$3", "e", FENCE_COLUMNS),
        );
        sqlx::query(trusted(sql))
            .bind(now_ms)
            .bind(AttemptOutcome::Succeeded.as_str())
            .bind(fence_rows(&accepted)?)
            .execute(&mut **tx)
            .await?;
    }
    unblock_dependents(tx, backend, &ids_json, now_ms).await?;
    Ok(done)
}

/// Counts the success of the tasks in `ids_json` (a JSON array of ids) in their dependents, and
/// queues those with no dependency left: one statement for a batch.
async fn unblock_dependents(
    tx: &mut Transaction<'static, Any>,
    backend: Backend,
    ids_json: &str,
    now_ms: i64,
) -> Result<()> {
    let sql = format!(
        "UPDATE tasks SET deps_pending = deps_pending - n.done, \
         state = CASE WHEN state = $1 AND deps_pending - n.done = 0 THEN $2 ELSE state END, updated_ms = $3 \
         FROM (SELECT task_id, COUNT(*) AS done FROM task_deps WHERE depends_on IN ({}) GROUP BY task_id) AS n \
         WHERE tasks.id = n.task_id",
        backend.json_text_array("$4"),
    );
    sqlx::query(trusted(sql))
        .bind(TaskState::Waiting.as_str())
        .bind(TaskState::Queued.as_str())
        .bind(now_ms)
        .bind(ids_json)
        .execute(&mut **tx)
        .await?;
    Ok(())
}
