//! Leasing ready tasks with their inputs, and heartbeats that keep leases alive.

use std::collections::{HashMap, HashSet};

use sqlx::Row;
use vint_core::{Stage, TaskState};

use super::Clock;
use crate::jobs::json_text;
use crate::sql::sql;
use crate::{ArtifactRecord, Backend, LeasedTask, Result, Store, StoreError, outputs, parse, to_u32};

impl Store {
    /// Leases up to `capacity` ready tasks of `stages` to `worker_id` for `lease_ms` from the
    /// `clock`'s time once a connection is held (`Clock`).
    pub async fn lease(
        &self,
        worker_id: &str,
        stages: &[Stage],
        capacity: u32,
        lease_ms: i64,
        clock: impl Clock,
    ) -> Result<Vec<LeasedTask>> {
        self.lease_with("lease_tasks", worker_id, stages, capacity, lease_ms, clock).await
    }

    /// `lease` for a timing-only worker: only tasks of jobs submitted with `timing_only`.
    pub async fn lease_timing_only(
        &self,
        worker_id: &str,
        stages: &[Stage],
        capacity: u32,
        lease_ms: i64,
        clock: impl Clock,
    ) -> Result<Vec<LeasedTask>> {
        self.lease_with("lease_tasks_timing_only", worker_id, stages, capacity, lease_ms, clock).await
    }

    async fn lease_with(
        &self,
        statement: &'static str,
        worker_id: &str,
        stages: &[Stage],
        capacity: u32,
        lease_ms: i64,
        clock: impl Clock,
    ) -> Result<Vec<LeasedTask>> {
        if stages.is_empty() || capacity == 0 {
            return Ok(Vec::new());
        }
        let mut conn = self.pool.acquire().await?;
        let now_ms = clock.now_ms();
        let deadline = now_ms + lease_ms;
        let stages_seen = stages.iter().map(|s| s.as_str()).collect::<Vec<_>>().join(",");
        let backend = self.backend;
        if backend == Backend::Sqlite {
            for statement in ["worker_seen_update", "worker_seen_insert"] {
                sqlx::query(sql(backend, statement)?)
                    .bind(worker_id)
                    .bind(&stages_seen)
                    .bind(now_ms)
                    .execute(&mut *conn)
                    .await?;
            }
        }
        let rows = sqlx::query(sql(backend, statement)?)
            .bind(TaskState::Running.as_str())
            .bind(worker_id)
            .bind(deadline)
            .bind(now_ms)
            .bind(i64::from(capacity))
            .bind(&stages_seen)
            .fetch_all(&mut *conn)
            .await?;
        drop(conn);
        let mut leased = rows.iter().map(leased_from_row).collect::<Result<Vec<_>>>()?;
        match backend {
            // The lease statement read every leased task's inputs.
            Backend::Postgres => {
                for (task, row) in leased.iter_mut().zip(&rows) {
                    let inputs: Vec<InputRow> = serde_json::from_str(&row.try_get::<String, _>("inputs_json")?)
                        .map_err(|e| StoreError::Corrupt(format!("inputs of task {}: {e}", task.id)))?;
                    for input in inputs {
                        task.inputs.extend(input.into_records()?);
                    }
                }
            }
            Backend::Sqlite if !leased.is_empty() => {
                let ids: Vec<&str> = leased.iter().map(|t| t.id.as_str()).collect();
                let mut inputs = self.lease_inputs(&ids).await?;
                for t in &mut leased {
                    t.inputs = inputs.remove(&t.id).unwrap_or_default();
                }
            }
            Backend::Sqlite => {}
        }
        leased.sort_by(|a, b| a.id.cmp(&b.id));
        Ok(leased)
    }

    /// Extends for `lease_ms` from the `clock`'s time (read once a connection is held, `Clock`)
    /// the leases `worker_id` still holds, returning the ones it has lost and the new deadline. A
    /// heartbeat never waits for a lock (`sql/postgres/lease.sql`, `heartbeat`).
    pub async fn heartbeat(
        &self,
        worker_id: &str,
        held: &[(String, u32)],
        lease_ms: i64,
        clock: impl Clock,
    ) -> Result<Heartbeat> {
        if held.is_empty() {
            return Ok(Heartbeat { lost: Vec::new(), deadline_ms: clock.now_ms() + lease_ms });
        }
        let rows: Vec<serde_json::Value> =
            held.iter().map(|(id, attempt)| serde_json::json!({"id": id, "attempt": attempt})).collect();
        let mut conn = self.pool.acquire().await?;
        let now_ms = clock.now_ms();
        // The worker's last heartbeat (Postgres: in the same statement).
        if self.backend == Backend::Sqlite {
            sqlx::query(sql(self.backend, "worker_heartbeat")?)
                .bind(worker_id)
                .bind(now_ms)
                .execute(&mut *conn)
                .await?;
        }
        let kept: HashSet<(String, i64)> = sqlx::query(sql(self.backend, "heartbeat")?)
            .bind(now_ms + lease_ms)
            .bind(now_ms)
            .bind(TaskState::Running.as_str())
            .bind(worker_id)
            .bind(json_text(&rows)?)
            .fetch_all(&mut *conn)
            .await?
            .iter()
            .map(|row| Ok((row.try_get::<String, _>("id")?, row.try_get::<i64, _>("attempt")?)))
            .collect::<Result<_>>()?;
        let lost =
            held.iter().filter(|(id, attempt)| !kept.contains(&(id.clone(), i64::from(*attempt)))).cloned().collect();
        Ok(Heartbeat { lost, deadline_ms: now_ms + lease_ms })
    }

    /// The artifacts produced by the dependencies of each of `task_ids`: their inputs, by task
    /// (SQLite; Postgres reads them in the lease statement).
    async fn lease_inputs(&self, task_ids: &[&str]) -> Result<HashMap<String, Vec<ArtifactRecord>>> {
        let rows =
            sqlx::query(sql(self.backend, "lease_inputs")?).bind(json_text(task_ids)?).fetch_all(&self.pool).await?;
        let mut by_task: HashMap<String, Vec<ArtifactRecord>> = HashMap::new();
        for row in &rows {
            let consumer: String = row.try_get("consumer")?;
            by_task.entry(consumer).or_default().extend(crate::lineage::outputs_from_row(row)?);
        }
        Ok(by_task)
    }
}

/// What a heartbeat did: the leases the worker no longer holds, and the deadline of those it kept.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Heartbeat {
    pub lost: Vec<(String, u32)>,
    pub deadline_ms: i64,
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
