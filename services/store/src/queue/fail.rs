//! Attempts that end without success: reported failures and expired leases (the reaper), with
//! retries after a backoff and, when none is left, the task's dependents failed with it.

use sqlx::{Any, Row, Transaction};
use vint_core::state::retry_backoff_ms;
use vint_core::{AttemptOutcome, TaskState};

use super::{end_attempt, lease_lost};
use crate::sql::sql;
use crate::{Backend, Fence, Result, Store, StoreError, to_u32};

/// Why an attempt ends without success.
#[derive(Clone, Copy, Debug)]
enum Failure {
    /// The worker reported it; fenced on the worker's lease (past its deadline too, until the
    /// reaper has taken it).
    Reported { retryable: bool },
    /// The worker stopped heartbeating and its lease ran out (the reaper); always retryable.
    /// `counted` is false when it ran out while no coordinator could hear its heartbeats: then
    /// the attempt does not count against `max_attempts`.
    LeaseExpired { counted: bool },
}

impl Store {
    /// Fails an attempt. A retryable failure with attempts left requeues the task after a backoff
    /// and returns `true`; otherwise the task fails permanently (keeping `message`), its waiting
    /// dependents fail with it, and this returns `false`.
    pub async fn fail(&self, f: &Fence, retryable: bool, message: &str, now_ms: i64) -> Result<bool> {
        self.fail_attempt(f, Failure::Reported { retryable }, message, now_ms).await
    }

    /// Returns tasks whose lease expired before `now_ms` to the queue (or fails them when out of
    /// attempts). `heard_since_ms` is when the coordinator could last start hearing heartbeats
    /// (it started, or its database came back): a lease is reaped only once its worker has had
    /// a whole lease of its own length since then to heartbeat. A lease last renewed before
    /// then does not count against `max_attempts`: its worker went quiet while no coordinator
    /// could hear it, and a worker that died in the outage cannot be told from one the outage
    /// stopped. A worker heard since, that then went quiet, costs its task an attempt.
    pub async fn reap_expired(&self, now_ms: i64, heard_since_ms: i64) -> Result<u64> {
        let rows = sqlx::query(sql(self.backend, "expired_leases")?)
            .bind(now_ms)
            .bind(heard_since_ms)
            .fetch_all(&self.pool)
            .await?;
        let mut reaped = 0;
        for row in rows {
            let owner: Option<String> = row.try_get("lease_owner")?;
            let fence = Fence {
                task_id: row.try_get("id")?,
                worker_id: owner.unwrap_or_default(),
                attempt: to_u32("attempt", row.try_get("attempt")?)?,
            };
            let last_heard: i64 = row.try_get("updated_ms")?;
            let counted = last_heard >= heard_since_ms;
            let msg = if counted {
                format!("lease expired (worker {} stopped heartbeating)", fence.worker_id)
            } else {
                format!(
                    "lease expired; worker {} was last heard before the coordinator could hear it (not counted against max_attempts)",
                    fence.worker_id
                )
            };
            match self.fail_attempt(&fence, Failure::LeaseExpired { counted }, &msg, now_ms).await {
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
        // The reaper fails a lease only while its deadline is still past: a heartbeat may have
        // revived it since the reaper read it.
        let reaping = matches!(failure, Failure::LeaseExpired { .. });
        let fence = if reaping { "fence_expired_lease" } else { "fence_reported_failure" };
        let mut q = sqlx::query(sql(self.backend, fence)?)
            .bind(&f.task_id)
            .bind(TaskState::Running.as_str())
            .bind(&f.worker_id)
            .bind(i64::from(f.attempt));
        if reaping {
            q = q.bind(now_ms);
        }
        let Some(row) = q.fetch_optional(&mut *tx).await? else {
            tx.rollback().await?;
            return Err(lease_lost(f));
        };
        let attempts = to_u32("attempt", row.try_get("attempt")?)?;
        let max_attempts = to_u32("max_attempts", row.try_get("max_attempts")?)?;
        let (retryable, uncounted) = match failure {
            Failure::Reported { retryable } => (retryable, 0),
            Failure::LeaseExpired { counted } => (true, i64::from(!counted)),
        };
        let will_retry = retryable && (uncounted > 0 || attempts < max_attempts);
        let outcome = match failure {
            Failure::LeaseExpired { .. } => AttemptOutcome::LeaseExpired,
            Failure::Reported { .. } if will_retry => AttemptOutcome::Retry,
            Failure::Reported { .. } => AttemptOutcome::Failed,
        };
        end_attempt(&mut tx, self.backend, f, now_ms, outcome, Some(message), None).await?;
        if will_retry {
            // An attempt that does not count was no fault of the task's: it goes again at once.
            let backoff = if uncounted > 0 {
                0
            } else {
                retry_backoff_ms(attempts, self.retry.backoff_base_ms, self.retry.backoff_cap_ms)
            };
            sqlx::query(sql(self.backend, "requeue_task")?)
                .bind(TaskState::Queued.as_str())
                .bind(message)
                .bind(now_ms + backoff)
                .bind(now_ms)
                .bind(&f.task_id)
                .bind(uncounted)
                .execute(&mut *tx)
                .await?;
        } else {
            sqlx::query(sql(self.backend, "fail_task")?)
                .bind(TaskState::Failed.as_str())
                .bind(message)
                .bind(now_ms)
                .bind(&f.task_id)
                .execute(&mut *tx)
                .await?;
            fail_dependents(&mut tx, self.backend, &f.task_id, now_ms).await?;
        }
        tx.commit().await?;
        if !will_retry {
            self.finalize_jobs(now_ms).await?;
        }
        Ok(will_retry)
    }
}

/// Fails, transitively, every waiting task that depends on `task_id`.
async fn fail_dependents(
    tx: &mut Transaction<'static, Any>,
    backend: Backend,
    task_id: &str,
    now_ms: i64,
) -> Result<()> {
    let mut frontier = vec![task_id.to_string()];
    while let Some(failed) = frontier.pop() {
        let rows = sqlx::query(sql(backend, "fail_waiting_dependents")?)
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
