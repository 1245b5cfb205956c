//! The task queue: lease, heartbeat, complete, fail, release and reap expired leases.
//!
//! Leasing is one `UPDATE … WHERE id IN (SELECT … LIMIT n FOR UPDATE SKIP LOCKED) RETURNING …`,
//! so concurrent coordinators never hand out the same task. Completion and failure are fenced:
//! they change a task only while it is `running`, leased by the caller, at the caller's attempt
//! and (for completion and heartbeats) before the lease deadline.

use std::collections::{BTreeMap, BTreeSet, HashMap, HashSet};

use sqlx::{Any, Row, Transaction};
use vint_core::plan::NewTask;
use vint_core::state::retry_backoff_ms;
use vint_core::{AttemptOutcome, Stage, TaskState};

use crate::jobs::{json_text, task_from_row};
use crate::{
    ArtifactRecord, Backend, Completion, Fence, LeasedTask, Result, Store, StoreError, literal, outputs, parse, to_u32,
    trusted,
};

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

/// Why an attempt ends without success.
#[derive(Clone, Copy, Debug)]
enum Failure {
    /// The worker reported it; fenced on the worker's unexpired lease.
    Reported { retryable: bool },
    /// The worker stopped heartbeating and its lease ran out (the reaper); always retryable.
    LeaseExpired,
}

impl Store {
    /// Leases up to `capacity` ready tasks of `stages` to `worker_id` until `now_ms + lease_ms`.
    pub async fn lease(
        &self,
        worker_id: &str,
        stages: &[Stage],
        capacity: u32,
        lease_ms: i64,
        now_ms: i64,
    ) -> Result<Vec<LeasedTask>> {
        if stages.is_empty() || capacity == 0 {
            return Ok(Vec::new());
        }
        let stage_list = stages.iter().map(|s| literal(s.as_str())).collect::<Vec<_>>().join(", ");
        let update = format!(
            "UPDATE tasks SET state = $1, attempt = attempt + 1, lease_owner = $2, lease_deadline_ms = $3, \
             leased_ms = $4, updated_ms = $4 WHERE id IN (SELECT id FROM tasks WHERE state = {queued} AND not_before_ms <= $4 \
             AND stage IN ({stage_list}) ORDER BY priority, created_ms, id LIMIT $5 {skip_locked}) \
             RETURNING id, job_id, key, stage, attempt, params_json, lease_deadline_ms",
            queued = literal(TaskState::Queued.as_str()),
            skip_locked = self.backend.skip_locked(),
        );
        let deadline = now_ms + lease_ms;
        let stages_seen = stages.iter().map(|s| s.as_str()).collect::<Vec<_>>().join(",");
        let mut leased = match self.backend {
            // One statement: the worker's row, the lease and every leased task's inputs. The
            // attempt is written when it ends; until then the task's row is its record.
            Backend::Postgres => {
                let seen_pg = worker_seen("$2", "$6", "$4");
                let sql = format!(
                    "WITH seen AS ({seen}), new_worker AS ({new_worker}), leased AS ({update}) \
                     SELECT leased.*, (SELECT COALESCE(json_agg(json_build_object('task_id', o.task_id, \
                     'key', t.key, 'files', encode(o.files, 'hex')) ORDER BY t.key), '[]')::text FROM task_deps d \
                     JOIN outputs o ON o.task_id = d.depends_on JOIN tasks t ON t.id = o.task_id \
                     WHERE d.task_id = leased.id) AS inputs_json FROM leased",
                    seen = seen_pg[0],
                    new_worker = seen_pg[1],
                );
                let rows = sqlx::query(trusted(sql))
                    .bind(TaskState::Running.as_str())
                    .bind(worker_id)
                    .bind(deadline)
                    .bind(now_ms)
                    .bind(i64::from(capacity))
                    .bind(&stages_seen)
                    .fetch_all(&self.pool)
                    .await?;
                let mut leased = Vec::with_capacity(rows.len());
                for row in &rows {
                    let mut task = leased_from_row(row)?;
                    let inputs: Vec<InputRow> = serde_json::from_str(&row.try_get::<String, _>("inputs_json")?)
                        .map_err(|e| StoreError::Corrupt(format!("inputs of task {}: {e}", task.id)))?;
                    for input in inputs {
                        task.inputs.extend(input.into_records()?);
                    }
                    leased.push(task);
                }
                leased
            }
            Backend::Sqlite => {
                for sql in worker_seen("$1", "$2", "$3") {
                    sqlx::query(trusted(sql))
                        .bind(worker_id)
                        .bind(&stages_seen)
                        .bind(now_ms)
                        .execute(&self.pool)
                        .await?;
                }
                let rows = sqlx::query(trusted(update))
                    .bind(TaskState::Running.as_str())
                    .bind(worker_id)
                    .bind(deadline)
                    .bind(now_ms)
                    .bind(i64::from(capacity))
                    .fetch_all(&self.pool)
                    .await?;
                if rows.is_empty() {
                    return Ok(Vec::new());
                }
                let mut leased = rows.iter().map(leased_from_row).collect::<Result<Vec<_>>>()?;
                // Inputs are outputs of succeeded tasks, which never change: read after the lease.
                let ids: Vec<&str> = leased.iter().map(|t| t.id.as_str()).collect();
                let mut inputs = self.dependency_outputs(&ids).await?;
                for t in &mut leased {
                    t.inputs = inputs.remove(&t.id).unwrap_or_default();
                }
                leased
            }
        };
        leased.sort_by(|a, b| a.id.cmp(&b.id));
        Ok(leased)
    }

    /// Extends the leases `worker_id` still holds; returns the ones it has lost.
    pub async fn heartbeat(
        &self,
        worker_id: &str,
        held: &[(String, u32)],
        lease_ms: i64,
        now_ms: i64,
    ) -> Result<Vec<(String, u32)>> {
        if held.is_empty() {
            return Ok(Vec::new());
        }
        let rows: Vec<serde_json::Value> =
            held.iter().map(|(id, attempt)| serde_json::json!({"id": id, "attempt": attempt})).collect();
        // A heartbeat never waits: a held row another statement has locked (its completion in
        // flight, the reaper expiring it) is not renewed and reads as lost. Waiting instead could
        // deadlock with a completion of the same leases locking them in another order.
        // The worker's last heartbeat (Postgres: in the same statement).
        let seen = match self.backend {
            Backend::Postgres => format!("seen AS ({}), ", worker_heartbeat(self.backend, "$4", "$2")),
            Backend::Sqlite => {
                sqlx::query(trusted(worker_heartbeat(self.backend, "$1", "$2")))
                    .bind(worker_id)
                    .bind(now_ms)
                    .execute(&self.pool)
                    .await?;
                String::new()
            }
        };
        let sql = format!(
            "WITH {seen}h AS (SELECT * FROM {held}), \
             kept AS (SELECT t.id FROM tasks t JOIN h ON h.id = t.id WHERE t.state = $3 AND t.lease_owner = $4 \
               AND t.attempt = h.attempt AND t.lease_deadline_ms >= $2 {lock}) \
             UPDATE tasks SET lease_deadline_ms = $1, updated_ms = $2 FROM kept WHERE tasks.id = kept.id \
             RETURNING tasks.id, tasks.attempt",
            held = self.backend.json_rows("$5", "h", &[("id", "text"), ("attempt", "bigint")]),
            lock = self.backend.skip_locked_of("t"),
        );
        let kept: HashSet<(String, i64)> = sqlx::query(trusted(sql))
            .bind(now_ms + lease_ms)
            .bind(now_ms)
            .bind(TaskState::Running.as_str())
            .bind(worker_id)
            .bind(json_text(&rows)?)
            .fetch_all(&self.pool)
            .await?
            .iter()
            .map(|row| Ok((row.try_get::<String, _>("id")?, row.try_get::<i64, _>("attempt")?)))
            .collect::<Result<_>>()?;
        Ok(held.iter().filter(|(id, attempt)| !kept.contains(&(id.clone(), i64::from(*attempt)))).cloned().collect())
    }

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

    /// Fails an attempt. A retryable failure with attempts left requeues the task after a backoff
    /// and returns `true`; otherwise the task fails permanently (keeping `message`), its waiting
    /// dependents fail with it, and this returns `false`.
    pub async fn fail(&self, f: &Fence, retryable: bool, message: &str, now_ms: i64) -> Result<bool> {
        self.fail_attempt(f, Failure::Reported { retryable }, message, now_ms).await
    }

    /// Gives back leases `worker_id` holds without finishing them (the worker is shutting down):
    /// each task is queued again at once, with no backoff, and its attempt ends `released`.
    /// Fenced like a completion, task by task: only the holder of an unexpired lease on that
    /// attempt can release it. Returns the leases released; the others were already lost.
    ///
    /// A release does not bring a task closer to failing for good: it raises the task's
    /// `max_attempts` by one, so the attempts a failure or an expiry may still use are as many as
    /// before the lease (a task handed back ten times can still be retried as often as a fresh one).
    pub async fn release(&self, worker_id: &str, held: &[(String, u32)], now_ms: i64) -> Result<Vec<(String, u32)>> {
        if held.is_empty() {
            return Ok(Vec::new());
        }
        let rows: Vec<serde_json::Value> =
            held.iter().map(|(id, attempt)| serde_json::json!({"id": id, "attempt": attempt})).collect();
        let mut tx = self.pool.begin().await?;
        let sql = format!(
            "UPDATE tasks SET state = $1, lease_owner = NULL, lease_deadline_ms = NULL, not_before_ms = $2, \
             max_attempts = max_attempts + 1, updated_ms = $2 FROM {held} WHERE tasks.id = r.id AND tasks.state = $3 \
             AND tasks.lease_owner = $4 AND tasks.attempt = r.attempt AND tasks.lease_deadline_ms >= $2 \
             RETURNING tasks.id, tasks.attempt, tasks.leased_ms",
            held = self.backend.json_rows("$5", "r", &[("id", "text"), ("attempt", "bigint")]),
        );
        // (task id, attempt, when it was leased)
        let mut released: Vec<(String, i64, i64)> = sqlx::query(trusted(sql))
            .bind(TaskState::Queued.as_str())
            .bind(now_ms)
            .bind(TaskState::Running.as_str())
            .bind(worker_id)
            .bind(json_text(&rows)?)
            .fetch_all(&mut *tx)
            .await?
            .iter()
            .map(|row| {
                let leased_ms: Option<i64> = row.try_get("leased_ms")?;
                Ok((row.try_get("id")?, row.try_get("attempt")?, leased_ms.unwrap_or(now_ms)))
            })
            .collect::<Result<_>>()?;
        if released.is_empty() {
            tx.rollback().await?;
            return Ok(Vec::new());
        }
        released.sort();
        let ended: Vec<serde_json::Value> = released
            .iter()
            .map(|(id, attempt, started)| serde_json::json!({"id": id, "attempt": attempt, "started": started}))
            .collect();
        let sql = format!(
            "INSERT INTO attempts (task_id, attempt, worker_id, started_ms, ended_ms, outcome, error) \
             SELECT r.id, r.attempt, $1, r.started, $2, $3, $4 FROM {}",
            self.backend.json_rows("$5", "r", &[("id", "text"), ("attempt", "bigint"), ("started", "bigint")]),
        );
        sqlx::query(trusted(sql))
            .bind(worker_id)
            .bind(now_ms)
            .bind(AttemptOutcome::Released.as_str())
            .bind(format!("released by worker {worker_id}"))
            .bind(json_text(&ended)?)
            .execute(&mut *tx)
            .await?;
        tx.commit().await?;
        released.into_iter().map(|(id, attempt, _)| Ok((id, to_u32("attempt", attempt)?))).collect()
    }

    /// Keeps the planner's statistics of the tables a running job grows (Postgres): analyzes each
    /// one that holds twice the rows its last analysis counted (or was never analyzed),
    /// returning their names. A job grows `outputs` from nothing to millions of rows in
    /// minutes, faster than autovacuum's analyze follows (seen: none in the first 3 minutes of a
    /// 2 M-sample job), and a plan made with no statistics scans the whole table for each leased
    /// task's inputs. An analysis also replaces the cached plans of the statements that read the
    /// table. Updates do not count: they leave the row counts, and the plans, as they were.
    pub async fn refresh_statistics(&self) -> Result<Vec<String>> {
        if self.backend != Backend::Postgres {
            return Ok(Vec::new());
        }
        let stale: Vec<String> = sqlx::query(
            "SELECT s.relname::text AS relname FROM pg_stat_user_tables s JOIN pg_class c ON c.oid = s.relid \
             WHERE s.relname IN ('tasks', 'task_deps', 'attempts', 'outputs') \
             AND s.n_live_tup > 1000 + 2 * greatest(c.reltuples, 0) ORDER BY s.relname",
        )
        .fetch_all(&self.pool)
        .await?
        .iter()
        .map(|row| row.try_get::<String, _>("relname"))
        .collect::<std::result::Result<_, _>>()?;
        for table in &stale {
            // The names come from the fixed list above.
            sqlx::query(trusted(format!("ANALYZE {table}"))).execute(&self.pool).await?;
        }
        Ok(stale)
    }

    /// Returns tasks whose lease expired to the queue (or fails them when out of attempts).
    pub async fn reap_expired(&self, now_ms: i64) -> Result<u64> {
        let sql = format!(
            "SELECT id, lease_owner, attempt FROM tasks WHERE state = {running} AND lease_deadline_ms < $1",
            running = literal(TaskState::Running.as_str()),
        );
        let rows = sqlx::query(trusted(sql)).bind(now_ms).fetch_all(&self.pool).await?;
        let mut reaped = 0;
        for row in rows {
            let owner: Option<String> = row.try_get("lease_owner")?;
            let fence = Fence {
                task_id: row.try_get("id")?,
                worker_id: owner.unwrap_or_default(),
                attempt: to_u32("attempt", row.try_get("attempt")?)?,
            };
            let msg = format!("lease expired (worker {} stopped heartbeating)", fence.worker_id);
            match self.fail_attempt(&fence, Failure::LeaseExpired, &msg, now_ms).await {
                Ok(_) => reaped += 1,
                Err(StoreError::LeaseLost { .. }) => {} // finished or reaped concurrently
                Err(e) => return Err(e),
            }
        }
        if reaped > 0 {
            self.finalize_jobs(now_ms).await?;
        }
        Ok(reaped)
    }

    /// Ends a running attempt that did not succeed: requeues the task after a backoff when the
    /// failure is retryable and attempts are left (returns `true`), else fails it and its
    /// dependents. Refused with `LeaseLost` unless the fence still holds.
    async fn fail_attempt(&self, f: &Fence, failure: Failure, message: &str, now_ms: i64) -> Result<bool> {
        let mut tx = self.pool.begin().await?;
        // The reaper fails a lease precisely because its deadline passed.
        let reported = matches!(failure, Failure::Reported { .. });
        let sql = format!(
            "SELECT attempt, max_attempts FROM tasks WHERE id = $1 AND state = $2 AND lease_owner = $3 \
             AND attempt = $4{deadline} {lock_row}",
            deadline = if reported { " AND lease_deadline_ms >= $5" } else { "" },
            lock_row = self.backend.lock_row(),
        );
        let mut q = sqlx::query(trusted(sql))
            .bind(&f.task_id)
            .bind(TaskState::Running.as_str())
            .bind(&f.worker_id)
            .bind(i64::from(f.attempt));
        if reported {
            q = q.bind(now_ms);
        }
        let Some(row) = q.fetch_optional(&mut *tx).await? else {
            tx.rollback().await?;
            return Err(lease_lost(f));
        };
        let attempts = to_u32("attempt", row.try_get("attempt")?)?;
        let max_attempts = to_u32("max_attempts", row.try_get("max_attempts")?)?;
        let retryable = match failure {
            Failure::Reported { retryable } => retryable,
            Failure::LeaseExpired => true,
        };
        let will_retry = retryable && attempts < max_attempts;
        let outcome = match failure {
            Failure::LeaseExpired => AttemptOutcome::LeaseExpired,
            Failure::Reported { .. } if will_retry => AttemptOutcome::Retry,
            Failure::Reported { .. } => AttemptOutcome::Failed,
        };
        end_attempt(&mut tx, f, now_ms, outcome, Some(message), None).await?;
        if will_retry {
            let backoff = retry_backoff_ms(attempts, self.retry.backoff_base_ms, self.retry.backoff_cap_ms);
            sqlx::query(
                "UPDATE tasks SET state = $1, lease_owner = NULL, lease_deadline_ms = NULL, last_error = $2, \
                 not_before_ms = $3, updated_ms = $4 WHERE id = $5",
            )
            .bind(TaskState::Queued.as_str())
            .bind(message)
            .bind(now_ms + backoff)
            .bind(now_ms)
            .bind(&f.task_id)
            .execute(&mut *tx)
            .await?;
        } else {
            sqlx::query(
                "UPDATE tasks SET state = $1, lease_owner = NULL, lease_deadline_ms = NULL, last_error = $2, \
                 updated_ms = $3 WHERE id = $4",
            )
            .bind(TaskState::Failed.as_str())
            .bind(message)
            .bind(now_ms)
            .bind(&f.task_id)
            .execute(&mut *tx)
            .await?;
            fail_dependents(&mut tx, &f.task_id, now_ms).await?;
        }
        tx.commit().await?;
        if !will_retry {
            self.finalize_jobs(now_ms).await?;
        }
        Ok(will_retry)
    }

    /// The task's attempts, oldest first.
    pub async fn attempts(&self, task_id: &str) -> Result<Vec<crate::AttemptRecord>> {
        // Ended attempts are rows of `attempts`; a running one is its task's row.
        let sql = format!(
            "SELECT task_id, attempt, worker_id, started_ms, ended_ms, outcome, error FROM attempts \
             WHERE task_id = $1 UNION ALL SELECT id, attempt, lease_owner, COALESCE(leased_ms, updated_ms), NULL, \
             NULL, NULL FROM tasks WHERE id = $1 AND state = {running} ORDER BY attempt",
            running = literal(TaskState::Running.as_str()),
        );
        let rows = sqlx::query(trusted(sql)).bind(task_id).fetch_all(&self.pool).await?;
        rows.iter()
            .map(|r| {
                Ok(crate::AttemptRecord {
                    task_id: r.try_get("task_id")?,
                    attempt: to_u32("attempt", r.try_get("attempt")?)?,
                    worker_id: r.try_get("worker_id")?,
                    started_ms: r.try_get("started_ms")?,
                    ended_ms: r.try_get("ended_ms")?,
                    outcome: r
                        .try_get::<Option<String>, _>("outcome")?
                        .map(|o| parse("attempt outcome", &o))
                        .transpose()?,
                    error: r.try_get("error")?,
                })
            })
            .collect()
    }

    /// Running tasks, for tests and operators.
    pub async fn running_tasks(&self) -> Result<Vec<crate::TaskRecord>> {
        let sql = format!("SELECT {} FROM tasks WHERE state = $1 ORDER BY id", crate::jobs::TASK_COLUMNS);
        let rows = sqlx::query(trusted(sql)).bind(TaskState::Running.as_str()).fetch_all(&self.pool).await?;
        rows.iter().map(task_from_row).collect()
    }
}

/// Records that `worker` (a parameter) asked for tasks of `stages` (comma-separated) at `now_ms`,
/// for the dashboard's `workers` view (migration 0008): an update, then an insert of a worker not
/// seen before. An idle worker polls twice a second: its row is written at most once a second
/// (`WORKER_SEEN_RESOLUTION_MS`) or when its stages change, and a poll that writes nothing locks
/// nothing (an upsert would lock the row, and make every empty poll a commit that waits for WAL).
fn worker_seen(worker: &str, stages: &str, now_ms: &str) -> [String; 2] {
    [
        format!(
            "UPDATE workers SET stages = {stages}, last_seen_ms = {now_ms} WHERE id = {worker} \
             AND (last_seen_ms <= {now_ms} - {WORKER_SEEN_RESOLUTION_MS} OR stages <> {stages})"
        ),
        format!(
            "INSERT INTO workers (id, stages, first_seen_ms, last_seen_ms) SELECT {worker}, {stages}, {now_ms}, {now_ms} \
             WHERE NOT EXISTS (SELECT 1 FROM workers WHERE id = {worker}) ON CONFLICT (id) DO NOTHING"
        ),
    ]
}

/// How stale a worker's `last_seen_ms` may be before a lease request writes it again.
const WORKER_SEEN_RESOLUTION_MS: i64 = 1_000;

/// Records that `worker` heartbeated at `now_ms` (its stages stay those of its last lease). Its row
/// exists since its lease; like the rest of a heartbeat it never waits for a lock: a lease of the
/// same worker updating the row that instant has just recorded it as seen.
fn worker_heartbeat(backend: Backend, worker: &str, now_ms: &str) -> String {
    format!(
        "UPDATE workers SET last_seen_ms = {now_ms}, last_heartbeat_ms = {now_ms} \
         WHERE id = (SELECT id FROM workers WHERE id = {worker} {skip_locked})",
        skip_locked = backend.skip_locked(),
    )
}

/// A leased task as the lease statement returns it, without its inputs.
fn leased_from_row(row: &sqlx::any::AnyRow) -> Result<LeasedTask> {
    Ok(LeasedTask {
        id: row.try_get("id")?,
        job_id: row.try_get("job_id")?,
        key: row.try_get("key")?,
        stage: parse("stage", &row.try_get::<String, _>("stage")?)?,
        attempt: to_u32("attempt", row.try_get("attempt")?)?,
        params_json: row.try_get("params_json")?,
        inputs: Vec::new(),
        lease_deadline_ms: row.try_get("lease_deadline_ms")?,
    })
}

/// A dependency's packed outputs as Postgres's lease statement aggregates them
/// (`json_build_object`, the bytes as hex).
#[derive(serde::Deserialize)]
struct InputRow {
    task_id: String,
    key: String,
    files: String,
}

impl InputRow {
    fn into_records(self) -> Result<Vec<ArtifactRecord>> {
        let bytes = hex::decode(&self.files)
            .map_err(|e| StoreError::Corrupt(format!("outputs of task {}: {e}", self.task_id)))?;
        outputs::unpack(&self.task_id, &self.key, &bytes)
    }
}

fn lease_lost(f: &Fence) -> StoreError {
    StoreError::LeaseLost { task_id: f.task_id.clone(), attempt: f.attempt, worker_id: f.worker_id.clone() }
}

async fn end_attempt(
    tx: &mut Transaction<'static, Any>,
    f: &Fence,
    now_ms: i64,
    outcome: AttemptOutcome,
    error: Option<&str>,
    engine_and_timings: Option<(&str, &str)>,
) -> Result<()> {
    let (engine, timings) = engine_and_timings.unzip();
    // Before the task's row leaves `running`: it holds when the attempt started.
    sqlx::query(
        "INSERT INTO attempts (task_id, attempt, worker_id, started_ms, ended_ms, outcome, error, engine_json, \
         timings_json) SELECT id, attempt, lease_owner, COALESCE(leased_ms, $1), $1, $2, $3, $4, $5 FROM tasks \
         WHERE id = $6 AND attempt = $7",
    )
    .bind(now_ms)
    .bind(outcome.as_str())
    .bind(error)
    .bind(engine)
    .bind(timings)
    .bind(&f.task_id)
    .bind(i64::from(f.attempt))
    .execute(&mut **tx)
    .await?;
    Ok(())
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

/// Postgres: fences the completions and records what every accepted one made — task, attempt,
/// outputs, unblocked dependents, samples — in ONE statement of data-modifying
/// CTEs keyed on the fenced rows. Returns the accepted tasks' ids with their jobs.
/// Each item's outcome: completed when it was the first of its task in the batch and its fence
/// held (`done`), its lease lost otherwise.
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

/// Fails, transitively, every waiting task that depends on `task_id`.
async fn fail_dependents(tx: &mut Transaction<'static, Any>, task_id: &str, now_ms: i64) -> Result<()> {
    let mut frontier = vec![task_id.to_string()];
    while let Some(failed) = frontier.pop() {
        let rows = sqlx::query(
            "UPDATE tasks SET state = $1, last_error = $2, updated_ms = $3 WHERE state = $4 \
             AND id IN (SELECT task_id FROM task_deps WHERE depends_on = $5) RETURNING id",
        )
        .bind(TaskState::Failed.as_str())
        .bind(format!("upstream task {failed} failed"))
        .bind(now_ms)
        .bind(TaskState::Waiting.as_str())
        .bind(&failed)
        .fetch_all(&mut **tx)
        .await?;
        for row in rows {
            frontier.push(row.try_get("id")?);
        }
    }
    Ok(())
}

impl Store {
    /// The artifacts produced by the dependencies of each of `task_ids`: their inputs, by task.
    async fn dependency_outputs(&self, task_ids: &[&str]) -> Result<HashMap<String, Vec<ArtifactRecord>>> {
        let sql = format!(
            "SELECT d.task_id AS consumer, o.task_id, t.key, o.files \
             FROM task_deps d JOIN outputs o ON o.task_id = d.depends_on JOIN tasks t ON t.id = o.task_id \
             WHERE d.task_id IN ({}) ORDER BY d.task_id, t.key",
            self.backend.json_text_array("$1"),
        );
        let rows = sqlx::query(trusted(sql)).bind(json_text(task_ids)?).fetch_all(&self.pool).await?;
        let mut by_task: HashMap<String, Vec<ArtifactRecord>> = HashMap::new();
        for row in &rows {
            let consumer: String = row.try_get("consumer")?;
            by_task.entry(consumer).or_default().extend(crate::lineage::outputs_from_row(row)?);
        }
        Ok(by_task)
    }
}
