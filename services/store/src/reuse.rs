//! Task reuse by content (`vint_core::reuse`): the reuse keys of leased tasks, and the finished
//! results already stored under a key.
//!
//! A key is written (table `task_keys`, migration 0011) when a worker that declares its engine
//! leases the task, before the worker runs anything, so a task that later succeeds is findable by
//! its key from any job. A reused task gets the key too, so its result serves later jobs even when
//! the job it was first made in is gone.

use std::collections::HashMap;

use sqlx::Row;
use vint_core::TaskState;

use crate::jobs::json_text;
use crate::sql::sql;
use crate::{NewArtifact, Result, Store};

/// A finished task's result under a reuse key: what a task with the same key takes instead of
/// running.
#[derive(Clone, Debug, PartialEq)]
pub struct StoredResult {
    /// The succeeded task that made (or itself reused) the result.
    pub task_id: String,
    pub result_json: String,
    pub engine_json: String,
    pub outputs: Vec<NewArtifact>,
}

impl Store {
    /// Records the reuse key of each leased task `(id, attempt, key)`, replacing the key of an
    /// earlier attempt (another worker's engine); a task no longer running at that attempt is left
    /// alone.
    pub async fn set_content_keys(&self, keys: &[(String, u32, String)]) -> Result<()> {
        if keys.is_empty() {
            return Ok(());
        }
        let rows: Vec<serde_json::Value> = keys
            .iter()
            .map(|(id, attempt, key)| serde_json::json!({"id": id, "attempt": attempt, "key": key}))
            .collect();
        sqlx::query(sql(self.backend, "set_content_keys")?)
            .bind(json_text(&rows)?)
            .bind(TaskState::Running.as_str())
            .execute(&self.pool)
            .await?;
        Ok(())
    }

    /// For each of `keys` that a succeeded task holds, that task's result and outputs (of several
    /// such tasks, the one with the smallest id, so every caller picks the same).
    pub async fn stored_results(&self, keys: &[String]) -> Result<HashMap<String, StoredResult>> {
        if keys.is_empty() {
            return Ok(HashMap::new());
        }
        let rows = sqlx::query(sql(self.backend, "tasks_with_keys")?)
            .bind(json_text(keys)?)
            .bind(TaskState::Succeeded.as_str())
            .fetch_all(&self.pool)
            .await?;
        let mut by_key: HashMap<String, StoredResult> = HashMap::new();
        for row in &rows {
            let key: String = row.try_get("content_key")?;
            if by_key.contains_key(&key) {
                continue;
            }
            let result_json: Option<String> = row.try_get("result_json")?;
            let engine_json: Option<String> = row.try_get("engine_json")?;
            by_key.insert(
                key,
                StoredResult {
                    task_id: row.try_get("id")?,
                    result_json: result_json.unwrap_or_default(),
                    engine_json: engine_json.unwrap_or_default(),
                    outputs: Vec::new(),
                },
            );
        }
        if by_key.is_empty() {
            return Ok(by_key);
        }
        let ids: Vec<&str> = by_key.values().map(|r| r.task_id.as_str()).collect();
        let rows =
            sqlx::query(sql(self.backend, "outputs_of_tasks")?).bind(json_text(&ids)?).fetch_all(&self.pool).await?;
        let mut outputs: HashMap<String, Vec<NewArtifact>> = HashMap::new();
        for row in &rows {
            for a in crate::lineage::outputs_from_row(row)? {
                outputs.entry(a.task_id).or_default().push(NewArtifact {
                    name: a.name,
                    sha256: a.sha256,
                    size: a.size,
                    media_type: a.media_type,
                    object_key: a.object_key,
                });
            }
        }
        for result in by_key.values_mut() {
            result.outputs = outputs.remove(&result.task_id).unwrap_or_default();
        }
        Ok(by_key)
    }

    /// The object keys some job still references: its tasks' outputs and its submitted files.
    /// An object of the store outside this set belongs to no job (an upload whose completion was
    /// refused, a crashed attempt's outputs) and may be collected.
    pub async fn referenced_object_keys(&self) -> Result<std::collections::HashSet<String>> {
        let mut keys = std::collections::HashSet::new();
        for row in sqlx::query(sql(self.backend, "asset_object_keys")?).fetch_all(&self.pool).await? {
            keys.insert(row.try_get::<String, _>("object_key")?);
        }
        // Read in pages by task id: the packed files of a 2 M-sample job are ~1.4 GB. (Only the
        // hashes are wanted: the task's id stands in for its key.)
        let mut after = String::new();
        loop {
            let rows = sqlx::query(sql(self.backend, "outputs_page")?).bind(&after).fetch_all(&self.pool).await?;
            let Some(last) = rows.last() else { break };
            after = last.try_get("task_id")?;
            for row in &rows {
                keys.extend(crate::lineage::outputs_from_row(row)?.into_iter().map(|a| a.object_key));
            }
        }
        Ok(keys)
    }

    /// A task's reuse key, if a lease wrote one.
    pub async fn content_key(&self, task_id: &str) -> Result<Option<String>> {
        let row = sqlx::query(sql(self.backend, "content_key")?).bind(task_id).fetch_optional(&self.pool).await?;
        row.map(|r| r.try_get::<String, _>("content_key")).transpose().map_err(Into::into)
    }
}
