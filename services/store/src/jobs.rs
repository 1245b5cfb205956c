//! Jobs: submit (idempotent), read, progress, cancel, finalize; and inserting planned tasks.

use std::collections::{BTreeSet, HashMap};

use serde_json::{Value, json};
use sqlx::any::AnyRow;
use sqlx::{Any, Row, Transaction};
use vint_core::plan::NewTask;
use vint_core::{AttemptOutcome, JobState, TaskState};

use crate::sql::sql;
use crate::{JobAsset, JobRecord, NewJob, Progress, Result, Store, StoreError, TaskRecord, parse, to_u32};

fn job_from_row(row: &AnyRow) -> Result<JobRecord> {
    Ok(JobRecord {
        id: row.try_get("id")?,
        name: row.try_get("name")?,
        seed: row.try_get::<i64, _>("seed")? as u64,
        spec_toml: row.try_get("spec_toml")?,
        plan_json: row.try_get("plan_json")?,
        state: parse("job state", &row.try_get::<String, _>("state")?)?,
        created_ms: row.try_get("created_ms")?,
        finished_ms: row.try_get("finished_ms")?,
        timing_only: row.try_get::<i64, _>("timing_only")? != 0,
    })
}

pub(crate) fn task_from_row(row: &AnyRow) -> Result<TaskRecord> {
    Ok(TaskRecord {
        id: row.try_get("id")?,
        job_id: row.try_get("job_id")?,
        key: row.try_get("key")?,
        stage: parse("stage", &row.try_get::<String, _>("stage")?)?,
        state: parse("task state", &row.try_get::<String, _>("state")?)?,
        params_json: row.try_get("params_json")?,
        attempt: to_u32("attempt", row.try_get("attempt")?)?,
        max_attempts: to_u32("max_attempts", row.try_get("max_attempts")?)?,
        not_before_ms: row.try_get("not_before_ms")?,
        lease_owner: row.try_get("lease_owner")?,
        lease_deadline_ms: row.try_get("lease_deadline_ms")?,
        last_error: row.try_get("last_error")?,
        engine_json: row.try_get("engine_json")?,
        result_json: row.try_get("result_json")?,
        reused_from: row.try_get("reused_from")?,
    })
}

/// The id of task `key` in job `job_id`: unique, stable, readable.
pub fn task_id(job_id: &str, key: &str) -> String {
    format!("{job_id}/{key}")
}

impl Store {
    /// How many of the jobs the token named `submitter` submitted are still running.
    pub async fn running_jobs_submitted_by(&self, submitter: &str) -> Result<u64> {
        let n: i64 = sqlx::query(sql(self.backend, "running_jobs_submitted_by")?)
            .bind(submitter)
            .fetch_one(&self.pool)
            .await?
            .try_get("n")?;
        Ok(u64::try_from(n).unwrap_or(0))
    }

    /// Creates a job and its initial tasks in one transaction. A job with the same idempotency key
    /// is returned instead, with `false`.
    pub async fn submit_job(&self, job: &NewJob, tasks: &[NewTask], now_ms: i64) -> Result<(JobRecord, bool)> {
        if let Some(existing) = self.job_by_idempotency_key(&job.idempotency_key).await? {
            return Ok((existing, false));
        }
        let mut tx = self.pool.begin().await?;
        let inserted = sqlx::query(sql(self.backend, "insert_job")?)
            .bind(&job.id)
            .bind(&job.name)
            .bind(job.seed as i64)
            .bind(&job.spec_toml)
            .bind(&job.plan_json)
            .bind(&job.idempotency_key)
            .bind(JobState::Running.as_str())
            .bind(now_ms)
            .bind(i64::from(job.timing_only))
            .bind(&job.submitted_by)
            .execute(&mut *tx)
            .await?
            .rows_affected();
        if inserted == 0 {
            // A concurrent submit with the same key won the race.
            tx.rollback().await?;
            let existing = self.job_by_idempotency_key(&job.idempotency_key).await?;
            return existing.map(|j| (j, false)).ok_or_else(|| StoreError::NotFound("job after conflict".into()));
        }
        for a in &job.assets {
            sqlx::query(sql(self.backend, "insert_job_asset")?)
                .bind(&job.id)
                .bind(&a.path)
                .bind(&a.sha256)
                .bind(a.size as i64)
                .bind(&a.media_type)
                .bind(&a.object_key)
                .execute(&mut *tx)
                .await?;
        }
        self.insert_tasks(&mut tx, &job.id, tasks, now_ms).await?;
        tx.commit().await?;
        let created = self.job(&job.id).await?.ok_or_else(|| StoreError::NotFound(format!("job {}", job.id)))?;
        Ok((created, true))
    }

    /// The job submitted with idempotency key `key`, if any.
    pub async fn job_by_idempotency_key(&self, key: &str) -> Result<Option<JobRecord>> {
        let row =
            sqlx::query(sql(self.backend, "job_by_idempotency_key")?).bind(key).fetch_optional(&self.pool).await?;
        row.as_ref().map(job_from_row).transpose()
    }

    /// The user files a job's spec names, by path.
    pub async fn job_assets(&self, job_id: &str) -> Result<Vec<JobAsset>> {
        let rows = sqlx::query(sql(self.backend, "job_assets")?).bind(job_id).fetch_all(&self.pool).await?;
        rows.iter().map(asset_from_row).collect()
    }

    /// Submitted user files with this content, as (job id, file), optionally within one job.
    pub async fn user_files_with(&self, sha256: &str, job_id: Option<&str>) -> Result<Vec<(String, JobAsset)>> {
        let rows = sqlx::query(sql(self.backend, "user_files_with")?)
            .bind(sha256)
            .bind(job_id.unwrap_or(""))
            .fetch_all(&self.pool)
            .await?;
        rows.iter().map(|row| Ok((row.try_get("job_id")?, asset_from_row(row)?))).collect()
    }

    pub async fn job(&self, job_id: &str) -> Result<Option<JobRecord>> {
        let row = sqlx::query(sql(self.backend, "job_by_id")?).bind(job_id).fetch_optional(&self.pool).await?;
        row.as_ref().map(job_from_row).transpose()
    }

    /// Most recent jobs first.
    pub async fn list_jobs(&self, limit: u32) -> Result<Vec<JobRecord>> {
        let rows =
            sqlx::query(sql(self.backend, "jobs_newest_first")?).bind(i64::from(limit)).fetch_all(&self.pool).await?;
        rows.iter().map(job_from_row).collect()
    }

    pub async fn progress(&self, job_id: &str) -> Result<Progress> {
        Ok(self.progress_of(&[job_id]).await?.remove(job_id).unwrap_or_default())
    }

    /// The progress of each of `job_ids` (an id with no tasks is absent), in two statements
    /// whatever their number: a listing of jobs asks once, not once per job.
    pub async fn progress_of(&self, job_ids: &[&str]) -> Result<HashMap<String, Progress>> {
        let mut by_job: HashMap<String, Progress> = HashMap::new();
        if job_ids.is_empty() {
            return Ok(by_job);
        }
        let ids = json_text(job_ids)?;
        let rows = sqlx::query(sql(self.backend, "progress_counts")?).bind(&ids).fetch_all(&self.pool).await?;
        for row in rows {
            let p = by_job.entry(row.try_get("job_id")?).or_default();
            let stage = parse("stage", &row.try_get::<String, _>("stage")?)?;
            let state = parse("task state", &row.try_get::<String, _>("state")?)?;
            let n: i64 = row.try_get("n")?;
            let reused: i64 = row.try_get("reused")?;
            p.by_stage.entry(stage).or_default().insert(state, n as u64);
            if reused > 0 {
                *p.reused.entry(stage).or_default() += reused as u64;
            }
        }
        // A package task's outputs row counts the samples it made (migration 0013).
        let rows = sqlx::query(sql(self.backend, "progress_samples")?)
            .bind(&ids)
            .bind(vint_core::Stage::Package.as_str())
            .fetch_all(&self.pool)
            .await?;
        for row in rows {
            let samples: i64 = row.try_get("n")?;
            by_job.entry(row.try_get("job_id")?).or_default().samples = samples as u64;
        }
        Ok(by_job)
    }

    /// Deletes an ended job and every row of it: its tasks, their attempts, outputs, reuse keys
    /// and edges, its submitted files' records. The objects its rows named are left for
    /// `vintctl gc` (another job may name the same content). A running job is refused
    /// (`StoreError::Invalid`): cancel it first. With `dry_run` the same deletions run in a
    /// transaction that is rolled back, so the counts are what a deletion would remove.
    pub async fn delete_job(&self, job_id: &str, dry_run: bool) -> Result<DeletedJob> {
        let mut tx = self.pool.begin().await?;
        let job = sqlx::query(sql(self.backend, "job_by_id")?).bind(job_id).fetch_optional(&mut *tx).await?;
        let job =
            job.as_ref().map(job_from_row).transpose()?.ok_or_else(|| StoreError::NotFound(format!("job {job_id}")))?;
        if job.state == JobState::Running {
            return Err(StoreError::Invalid(format!(
                "job {job_id} is running: cancel it first (vintctl cancel {job_id}), then delete it"
            )));
        }
        let mut removed = [0u64; 4];
        for (statement, slot) in [
            ("delete_job_attempts", Some(1)),
            ("delete_job_outputs", Some(2)),
            ("delete_job_task_keys", None),
            ("delete_job_task_deps", None),
            ("delete_job_tasks", Some(0)),
            ("delete_job_assets", Some(3)),
            ("delete_job_row", None),
        ] {
            let n = sqlx::query(sql(self.backend, statement)?).bind(job_id).execute(&mut *tx).await?.rows_affected();
            if let Some(i) = slot {
                removed[i] = n;
            }
        }
        if dry_run {
            tx.rollback().await?;
        } else {
            tx.commit().await?;
        }
        let [tasks, attempts, outputs, assets] = removed;
        Ok(DeletedJob { tasks, attempts, outputs, assets })
    }

    /// Cancels a running job: no task of it is leased again, and running attempts lose their
    /// lease (their completion is refused). Returns the job as it is afterwards.
    pub async fn cancel_job(&self, job_id: &str, now_ms: i64) -> Result<JobRecord> {
        let mut tx = self.pool.begin().await?;
        let changed = sqlx::query(sql(self.backend, "end_job")?)
            .bind(JobState::Cancelled.as_str())
            .bind(now_ms)
            .bind(job_id)
            .bind(JobState::Running.as_str())
            .execute(&mut *tx)
            .await?
            .rows_affected();
        if changed == 1 {
            // The running attempts end as cancelled (written once, as every attempt).
            sqlx::query(sql(self.backend, "cancel_running_attempts")?)
                .bind(now_ms)
                .bind(AttemptOutcome::Cancelled.as_str())
                .bind(job_id)
                .bind(TaskState::Running.as_str())
                .execute(&mut *tx)
                .await?;
            sqlx::query(sql(self.backend, "cancel_live_tasks")?)
                .bind(TaskState::Cancelled.as_str())
                .bind(now_ms)
                .bind(job_id)
                .bind(TaskState::Waiting.as_str())
                .bind(TaskState::Queued.as_str())
                .bind(TaskState::Running.as_str())
                .execute(&mut *tx)
                .await?;
        }
        tx.commit().await?;
        self.job(job_id).await?.ok_or_else(|| StoreError::NotFound(format!("job {job_id}")))
    }

    /// Marks running jobs whose tasks are all final as succeeded or failed. Returns their ids.
    ///
    /// Called after every completion and periodically: two completions committing at once can
    /// each see the other's task still running, so the periodic call is what guarantees it.
    pub async fn finalize_jobs(&self, now_ms: i64) -> Result<Vec<String>> {
        self.finalize(None, now_ms).await
    }

    /// `finalize_jobs` for the jobs among `job_ids` only: what a batch of completions may finish.
    pub(crate) async fn finalize_jobs_among(&self, job_ids: &BTreeSet<&str>, now_ms: i64) -> Result<Vec<String>> {
        if job_ids.is_empty() {
            return Ok(Vec::new());
        }
        self.finalize(Some(json_text(job_ids)?), now_ms).await
    }

    async fn finalize(&self, among: Option<String>, now_ms: i64) -> Result<Vec<String>> {
        let statement = if among.is_some() { "finished_jobs_among" } else { "finished_jobs" };
        let mut query = sqlx::query(sql(self.backend, statement)?)
            .bind(TaskState::Failed.as_str())
            .bind(JobState::Running.as_str())
            .bind(TaskState::Waiting.as_str())
            .bind(TaskState::Queued.as_str())
            .bind(TaskState::Running.as_str());
        if let Some(among) = among {
            query = query.bind(among);
        }
        let rows = query.fetch_all(&self.pool).await?;
        let mut done = Vec::new();
        for row in rows {
            let id: String = row.try_get("id")?;
            let failed: i64 = row.try_get("failed")?;
            let state = if failed > 0 { JobState::Failed } else { JobState::Succeeded };
            let n = sqlx::query(sql(self.backend, "end_job")?)
                .bind(state.as_str())
                .bind(now_ms)
                .bind(&id)
                .bind(JobState::Running.as_str())
                .execute(&self.pool)
                .await?
                .rows_affected();
            if n == 1 {
                done.push(id);
            }
        }
        Ok(done)
    }

    pub async fn task(&self, task_id: &str) -> Result<Option<TaskRecord>> {
        let row = sqlx::query(sql(self.backend, "task_by_id")?).bind(task_id).fetch_optional(&self.pool).await?;
        row.as_ref().map(task_from_row).transpose()
    }

    /// The tasks among `ids` that exist, in no particular order: one query for a batch.
    pub async fn tasks(&self, ids: &[String]) -> Result<Vec<TaskRecord>> {
        if ids.is_empty() {
            return Ok(Vec::new());
        }
        let rows = sqlx::query(sql(self.backend, "tasks_by_ids")?).bind(json_text(ids)?).fetch_all(&self.pool).await?;
        rows.iter().map(task_from_row).collect()
    }

    pub async fn tasks_of_job(&self, job_id: &str) -> Result<Vec<TaskRecord>> {
        let rows = sqlx::query(sql(self.backend, "tasks_of_job")?).bind(job_id).fetch_all(&self.pool).await?;
        rows.iter().map(task_from_row).collect()
    }

    /// Inserts planned tasks with their dependency edges, `INSERT_BATCH` tasks at a time (each
    /// batch three statements, its rows one bounded JSON parameter). A task whose dependencies have
    /// all succeeded starts queued; otherwise it waits, counting those that have not (a dependency
    /// inserted with it has not). Keys already present are skipped, so re-planning is harmless.
    pub(crate) async fn insert_tasks(
        &self,
        tx: &mut Transaction<'static, Any>,
        job_id: &str,
        tasks: &[NewTask],
        now_ms: i64,
    ) -> Result<()> {
        for batch in tasks.chunks(INSERT_BATCH) {
            self.insert_task_batch(tx, job_id, batch, now_ms).await?;
        }
        Ok(())
    }

    async fn insert_task_batch(
        &self,
        tx: &mut Transaction<'static, Any>,
        job_id: &str,
        tasks: &[NewTask],
        now_ms: i64,
    ) -> Result<()> {
        if tasks.is_empty() {
            return Ok(());
        }
        let deps: BTreeSet<String> = tasks.iter().flat_map(|t| t.deps.iter().map(|d| task_id(job_id, d))).collect();
        let mut succeeded = BTreeSet::new();
        if !deps.is_empty() {
            let rows = sqlx::query(sql(self.backend, "tasks_in_state_among")?)
                .bind(TaskState::Succeeded.as_str())
                .bind(json_text(&deps)?)
                .fetch_all(&mut **tx)
                .await?;
            for row in rows {
                succeeded.insert(row.try_get::<String, _>("id")?);
            }
        }
        let rows: Vec<Value> = tasks
            .iter()
            .map(|t| {
                let pending = t.deps.iter().filter(|d| !succeeded.contains(&task_id(job_id, d))).count();
                let state = if pending == 0 { TaskState::Queued } else { TaskState::Waiting };
                json!({
                    "id": task_id(job_id, &t.key), "key": t.key, "stage": t.stage.as_str(),
                    "priority": t.stage.lease_priority(), "params": t.params.to_string(),
                    "state": state.as_str(), "pending": pending,
                })
            })
            .collect();
        let inserted: BTreeSet<String> = sqlx::query(sql(self.backend, "insert_tasks")?)
            .bind(job_id)
            .bind(i64::from(self.retry.max_attempts))
            .bind(now_ms)
            .bind(json_text(&rows)?)
            .fetch_all(&mut **tx)
            .await?
            .iter()
            .map(|row| row.try_get::<String, _>("id"))
            .collect::<Result<_, _>>()?;
        let edges: Vec<Value> = tasks
            .iter()
            .map(|t| (task_id(job_id, &t.key), t))
            .filter(|(id, _)| inserted.contains(id))
            .flat_map(|(id, t)| t.deps.iter().map(move |d| json!({"task": id, "dep": task_id(job_id, d)})))
            .collect();
        if !edges.is_empty() {
            sqlx::query(sql(self.backend, "insert_task_deps")?).bind(json_text(&edges)?).execute(&mut **tx).await?;
        }
        Ok(())
    }
}

/// Tasks one statement inserts: a job's initial tasks (one grasp task a chunk; 16,276 for the
/// recipe) go in several statements, each parameter a few MB at most, in one transaction.
const INSERT_BATCH: usize = 5_000;

/// A value as JSON text, to bind as one parameter.
pub(crate) fn json_text<T: serde::Serialize + ?Sized>(value: &T) -> Result<String> {
    serde_json::to_string(value).map_err(|e| StoreError::Corrupt(format!("unencodable batch: {e}")))
}

/// A `job_assets` row (path, sha256, size, media_type, object_key).
fn asset_from_row(row: &AnyRow) -> Result<JobAsset> {
    Ok(JobAsset {
        path: row.try_get("path")?,
        sha256: row.try_get("sha256")?,
        size: row.try_get::<i64, _>("size")? as u64,
        media_type: row.try_get("media_type")?,
        object_key: row.try_get("object_key")?,
    })
}

/// What deleting a job removed (or, in a dry run, would remove): rows of tasks, attempts, packed
/// outputs (one per task that made files) and submitted files.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DeletedJob {
    pub tasks: u64,
    pub attempts: u64,
    pub outputs: u64,
    pub assets: u64,
}
