//! Why a job failed: its permanently failed tasks, the ones that failed themselves first.
//!
//! A task that fails permanently fails every task waiting on it (`fail_dependents`), and those
//! never run: they have no attempts, and their `last_error` names the upstream task. A user needs
//! the root causes first — the engine's message for the task that broke — and then how far the
//! failure spread, so the list is ordered that way and capped by the caller.

use sqlx::Row;
use vint_core::{Stage, TaskState};

use crate::{Result, Store, parse, to_u32};

/// A task that failed permanently, as a user reads it to learn why a job failed.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FailedTask {
    pub key: String,
    pub stage: Stage,
    /// Attempts it made; 0 when it never ran because a task it depends on failed.
    pub attempts: u32,
    /// The last attempt's error (the engine's message), or which upstream task failed.
    pub last_error: String,
}

impl FailedTask {
    /// Failed because a task it depends on failed, without running itself.
    pub fn failed_upstream(&self) -> bool {
        self.attempts == 0
    }
}

impl Store {
    /// Up to `limit` of a job's permanently failed tasks: those that ran and failed, by key, then
    /// those failed by an upstream task, by key. (`progress` counts them all.)
    pub async fn failed_tasks(&self, job_id: &str, limit: u32) -> Result<Vec<FailedTask>> {
        let rows = sqlx::query(crate::sql::sql(self.backend, "failed_tasks")?)
            .bind(job_id)
            .bind(TaskState::Failed.as_str())
            .bind(i64::from(limit))
            .fetch_all(&self.pool)
            .await?;
        rows.iter()
            .map(|row| {
                Ok(FailedTask {
                    key: row.try_get("key")?,
                    stage: parse("stage", &row.try_get::<String, _>("stage")?)?,
                    attempts: to_u32("attempt", row.try_get("attempt")?)?,
                    last_error: row.try_get::<Option<String>, _>("last_error")?.unwrap_or_default(),
                })
            })
            .collect()
    }
}
