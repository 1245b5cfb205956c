//! Leases handed back by a worker that stops: queued again at once, costing no attempt.

use sqlx::Row;
use vint_core::{AttemptOutcome, TaskState};

use crate::jobs::json_text;
use crate::{Result, Store, to_u32, trusted};

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
}
