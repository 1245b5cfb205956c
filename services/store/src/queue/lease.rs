//! Leasing ready tasks with their inputs, and heartbeats that keep leases alive.

use std::collections::{HashMap, HashSet};

use sqlx::Row;
use vint_core::{Stage, TaskState};

use crate::jobs::json_text;
use crate::{ArtifactRecord, Backend, LeasedTask, Result, Store, StoreError, literal, outputs, parse, to_u32, trusted};

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
