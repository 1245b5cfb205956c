//! Leases handed back by a worker that stops: queued again at once, costing no attempt.

use sqlx::Row;
use vint_core::{AttemptOutcome, TaskState};

use crate::jobs::json_text;
use crate::sql::sql;
use crate::{Result, Store, to_u32};

impl Store {
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
        // (task id, attempt, when it was leased)
        let mut released: Vec<(String, i64, i64)> = sqlx::query(sql(self.backend, "release_leases")?)
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
        sqlx::query(sql(self.backend, "insert_released_attempts")?)
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
}
