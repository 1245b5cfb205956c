//! The task queue: lease, heartbeat, complete, fail and reap expired leases.
//!
//! Leasing is one `UPDATE … WHERE id IN (SELECT … LIMIT n FOR UPDATE SKIP LOCKED) RETURNING …`,
//! so concurrent coordinators never hand out the same task. Completion and failure are fenced:
//! they change a task only while it is `running`, leased by the caller, at the caller's attempt
//! and (for completion and heartbeats) before the lease deadline.

use sqlx::{Any, Row, Transaction};
use vint_core::plan::NewTask;
use vint_core::state::retry_backoff_ms;
use vint_core::{AttemptOutcome, Stage, TaskState};

use crate::jobs::task_from_row;
use crate::{
    ArtifactRecord, Completion, Fence, LeasedTask, Result, Store, StoreError, literal, parse, to_u32, trusted,
};

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
        let sql = format!(
            "UPDATE tasks SET state = $1, attempt = attempt + 1, lease_owner = $2, lease_deadline_ms = $3, \
             updated_ms = $4 WHERE id IN (SELECT id FROM tasks WHERE state = {queued} AND not_before_ms <= $4 \
             AND stage IN ({stage_list}) ORDER BY priority, created_ms, id LIMIT $5 {skip_locked}) \
             RETURNING id, job_id, key, stage, attempt, params_json, lease_deadline_ms",
            queued = literal(TaskState::Queued.as_str()),
            skip_locked = self.backend.skip_locked(),
        );
        let deadline = now_ms + lease_ms;
        let mut tx = self.pool.begin().await?;
        let rows = sqlx::query(trusted(sql))
            .bind(TaskState::Running.as_str())
            .bind(worker_id)
            .bind(deadline)
            .bind(now_ms)
            .bind(i64::from(capacity))
            .fetch_all(&mut *tx)
            .await?;
        let mut leased = Vec::with_capacity(rows.len());
        for row in rows {
            let id: String = row.try_get("id")?;
            let attempt = to_u32("attempt", row.try_get("attempt")?)?;
            sqlx::query("INSERT INTO attempts (task_id, attempt, worker_id, started_ms) VALUES ($1, $2, $3, $4)")
                .bind(&id)
                .bind(i64::from(attempt))
                .bind(worker_id)
                .bind(now_ms)
                .execute(&mut *tx)
                .await?;
            let inputs = dependency_outputs(&mut tx, &id).await?;
            leased.push(LeasedTask {
                job_id: row.try_get("job_id")?,
                key: row.try_get("key")?,
                stage: parse("stage", &row.try_get::<String, _>("stage")?)?,
                attempt,
                params_json: row.try_get("params_json")?,
                inputs,
                lease_deadline_ms: row.try_get("lease_deadline_ms")?,
                id,
            });
        }
        tx.commit().await?;
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
        let mut lost = Vec::new();
        for (task_id, attempt) in held {
            let n = sqlx::query(
                "UPDATE tasks SET lease_deadline_ms = $1, updated_ms = $2 WHERE id = $3 AND state = $4 \
                 AND lease_owner = $5 AND attempt = $6 AND lease_deadline_ms >= $2",
            )
            .bind(now_ms + lease_ms)
            .bind(now_ms)
            .bind(task_id)
            .bind(TaskState::Running.as_str())
            .bind(worker_id)
            .bind(i64::from(*attempt))
            .execute(&self.pool)
            .await?
            .rows_affected();
            if n == 0 {
                lost.push((task_id.clone(), *attempt));
            }
        }
        Ok(lost)
    }

    /// Completes a task: records its outputs, lineage and attempt, unblocks its dependents and
    /// inserts the tasks the planner derived from it, all in one transaction. Refused with
    /// `LeaseLost` unless the caller holds an unexpired lease on this attempt.
    pub async fn complete(&self, c: &Completion, children: &[NewTask], now_ms: i64) -> Result<()> {
        let f = &c.fence;
        let mut tx = self.pool.begin().await?;
        let row = sqlx::query(
            "UPDATE tasks SET state = $1, lease_owner = NULL, lease_deadline_ms = NULL, engine_json = $3, \
             result_json = $4, updated_ms = $5 WHERE id = $6 AND state = $2 AND lease_owner = $7 \
             AND attempt = $8 AND lease_deadline_ms >= $5 RETURNING job_id",
        )
        .bind(TaskState::Succeeded.as_str())
        .bind(TaskState::Running.as_str())
        .bind(&c.engine_json)
        .bind(&c.result_json)
        .bind(now_ms)
        .bind(&f.task_id)
        .bind(&f.worker_id)
        .bind(i64::from(f.attempt))
        .fetch_optional(&mut *tx)
        .await?;
        let Some(row) = row else {
            tx.rollback().await?;
            return Err(lease_lost(f));
        };
        let job_id: String = row.try_get("job_id")?;
        for a in &c.outputs {
            sqlx::query(
                "INSERT INTO artifacts (task_id, name, sha256, size, media_type, object_key, created_ms) \
                 VALUES ($1, $2, $3, $4, $5, $6, $7)",
            )
            .bind(&f.task_id)
            .bind(&a.name)
            .bind(&a.sha256)
            .bind(a.size as i64)
            .bind(&a.media_type)
            .bind(&a.object_key)
            .bind(now_ms)
            .execute(&mut *tx)
            .await?;
        }
        sqlx::query(
            "INSERT INTO lineage_edges (task_id, input_task_id, input_name, input_sha256) \
             SELECT d.task_id, a.task_id, a.name, a.sha256 FROM task_deps d JOIN artifacts a ON a.task_id = d.depends_on \
             WHERE d.task_id = $1",
        )
        .bind(&f.task_id)
        .execute(&mut *tx)
        .await?;
        let timings = Some((c.engine_json.as_str(), c.timings_json.as_str()));
        end_attempt(&mut tx, f, now_ms, AttemptOutcome::Succeeded, None, timings).await?;
        unblock_dependents(&mut tx, &f.task_id, now_ms).await?;
        self.insert_tasks(&mut tx, &job_id, children, now_ms).await?;
        for sample in &c.samples {
            sqlx::query(
                "INSERT INTO samples (job_id, sample_id, package_task_id) VALUES ($1, $2, $3) \
                 ON CONFLICT (job_id, sample_id) DO NOTHING",
            )
            .bind(&job_id)
            .bind(sample)
            .bind(&f.task_id)
            .execute(&mut *tx)
            .await?;
        }
        tx.commit().await?;
        self.finalize_jobs(now_ms).await?;
        Ok(())
    }

    /// Completes many tasks in one call. Fenced per task: the result for a completion whose lease
    /// was lost is `Err(LeaseLost)` and the others still complete. An error of the database itself
    /// fails the whole call (and changes nothing).
    pub async fn complete_batch(
        &self,
        items: &[(Completion, Vec<NewTask>)],
        now_ms: i64,
    ) -> Result<Vec<std::result::Result<(), StoreError>>> {
        let mut results = Vec::with_capacity(items.len());
        for (c, children) in items {
            match self.complete(c, children, now_ms).await {
                Ok(()) => results.push(Ok(())),
                Err(e @ StoreError::LeaseLost { .. }) => results.push(Err(e)),
                Err(e) => return Err(e),
            }
        }
        Ok(results)
    }

    /// Fails an attempt. A retryable failure with attempts left requeues the task after a backoff
    /// and returns `true`; otherwise the task fails permanently (keeping `message`), its waiting
    /// dependents fail with it, and this returns `false`.
    pub async fn fail(&self, f: &Fence, retryable: bool, message: &str, now_ms: i64) -> Result<bool> {
        self.fail_attempt(f, Failure::Reported { retryable }, message, now_ms).await
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
        let rows = sqlx::query(
            "SELECT task_id, attempt, worker_id, started_ms, ended_ms, outcome, error FROM attempts \
             WHERE task_id = $1 ORDER BY attempt",
        )
        .bind(task_id)
        .fetch_all(&self.pool)
        .await?;
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
    sqlx::query(
        "UPDATE attempts SET ended_ms = $1, outcome = $2, error = $3, engine_json = $4, timings_json = $5 \
         WHERE task_id = $6 AND attempt = $7",
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

/// Counts the success of `task_id` in its dependents and queues those with no dependency left.
async fn unblock_dependents(tx: &mut Transaction<'static, Any>, task_id: &str, now_ms: i64) -> Result<()> {
    sqlx::query(
        "UPDATE tasks SET deps_pending = deps_pending - 1 \
         WHERE id IN (SELECT task_id FROM task_deps WHERE depends_on = $1)",
    )
    .bind(task_id)
    .execute(&mut **tx)
    .await?;
    sqlx::query(
        "UPDATE tasks SET state = $1, updated_ms = $2 WHERE state = $3 AND deps_pending = 0 \
         AND id IN (SELECT task_id FROM task_deps WHERE depends_on = $4)",
    )
    .bind(TaskState::Queued.as_str())
    .bind(now_ms)
    .bind(TaskState::Waiting.as_str())
    .bind(task_id)
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

/// The artifacts produced by the dependencies of `task_id`: the task's inputs.
async fn dependency_outputs(tx: &mut Transaction<'static, Any>, task_id: &str) -> Result<Vec<ArtifactRecord>> {
    let rows = sqlx::query(
        "SELECT a.task_id, t.key, a.name, a.sha256, a.size, a.media_type, a.object_key FROM task_deps d \
         JOIN artifacts a ON a.task_id = d.depends_on JOIN tasks t ON t.id = a.task_id \
         WHERE d.task_id = $1 ORDER BY t.key, a.name",
    )
    .bind(task_id)
    .fetch_all(&mut **tx)
    .await?;
    rows.iter().map(crate::lineage::artifact_from_row).collect()
}
