//! Attempts that end without success: reported failures and expired leases (the reaper), with
//! retries after a backoff and, when none is left, the task's dependents failed with it.

use sqlx::{Any, Row, Transaction};
use vint_core::state::retry_backoff_ms;
use vint_core::{AttemptOutcome, TaskState};

use super::{end_attempt, lease_lost};
use crate::{Fence, Result, Store, StoreError, literal, to_u32, trusted};

/// Why an attempt ends without success.
#[derive(Clone, Copy, Debug)]
enum Failure {
    /// The worker reported it; fenced on the worker's unexpired lease.
    Reported { retryable: bool },
    /// The worker stopped heartbeating and its lease ran out (the reaper); always retryable.
    LeaseExpired,
}

impl Store {
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
