//! Lineage: from a sample or an artifact back through every task, parameter set, engine version
//! and input hash that made it; and the packaged samples of a job.

use std::collections::{BTreeMap, BTreeSet};

use sqlx::Row;
use sqlx::any::AnyRow;

use crate::{ArtifactRecord, JobAsset, LineageEntry, Result, Store, StoreError, trusted};

pub(crate) fn artifact_from_row(row: &AnyRow) -> Result<ArtifactRecord> {
    Ok(ArtifactRecord {
        task_id: row.try_get("task_id")?,
        task_key: row.try_get("key")?,
        name: row.try_get("name")?,
        sha256: row.try_get("sha256")?,
        size: row.try_get::<i64, _>("size")? as u64,
        media_type: row.try_get("media_type")?,
        object_key: row.try_get("object_key")?,
    })
}

/// The `task_key` lineage gives a job's user files (they come with the submission, not a task).
pub const ASSET_TASK_KEY: &str = "asset";

const ARTIFACT_SELECT: &str = "SELECT a.task_id, t.key, a.name, a.sha256, a.size, a.media_type, a.object_key FROM artifacts a JOIN tasks t ON t.id = a.task_id";

impl Store {
    /// The task and, recursively, every task it depends on: producer first, then inputs'
    /// producers breadth-first.
    pub async fn lineage(&self, task_id: &str) -> Result<Vec<LineageEntry>> {
        let mut seen = BTreeSet::new();
        let mut queue = std::collections::VecDeque::from([task_id.to_string()]);
        let mut chain = Vec::new();
        let mut job_assets: BTreeMap<String, Vec<JobAsset>> = BTreeMap::new();
        while let Some(id) = queue.pop_front() {
            if !seen.insert(id.clone()) {
                continue;
            }
            let task = self.task(&id).await?.ok_or_else(|| StoreError::NotFound(format!("task {id}")))?;
            let depends_on: Vec<String> =
                sqlx::query("SELECT depends_on FROM task_deps WHERE task_id = $1 ORDER BY depends_on")
                    .bind(&id)
                    .fetch_all(&self.pool)
                    .await?
                    .iter()
                    .map(|r| r.try_get("depends_on"))
                    .collect::<Result<_, _>>()?;
            let mut inputs = sqlx::query(
                "SELECT a.task_id, t.key, a.name, a.sha256, a.size, a.media_type, a.object_key FROM task_deps d \
                 JOIN artifacts a ON a.task_id = d.depends_on JOIN tasks t ON t.id = a.task_id \
                 WHERE d.task_id = $1 ORDER BY t.key, a.name",
            )
            .bind(&id)
            .fetch_all(&self.pool)
            .await?
            .iter()
            .map(artifact_from_row)
            .collect::<Result<Vec<_>>>()?;
            // A user file the task's parameters name (by hash) is an input too, "from" the job.
            if !job_assets.contains_key(&task.job_id) {
                job_assets.insert(task.job_id.clone(), self.job_assets(&task.job_id).await?);
            }
            let named =
                job_assets.get(&task.job_id).into_iter().flatten().filter(|a| task.params_json.contains(&a.sha256));
            inputs.extend(named.map(|a| ArtifactRecord {
                task_id: String::new(),
                task_key: ASSET_TASK_KEY.to_string(),
                name: a.path.clone(),
                sha256: a.sha256.clone(),
                size: a.size,
                media_type: a.media_type.clone(),
                object_key: a.object_key.clone(),
            }));
            let outputs = self.artifacts_of_task(&id).await?;
            queue.extend(depends_on.iter().cloned());
            chain.push(LineageEntry { task, depends_on, inputs, outputs });
        }
        Ok(chain)
    }

    pub async fn artifacts_of_task(&self, task_id: &str) -> Result<Vec<ArtifactRecord>> {
        let sql = format!("{ARTIFACT_SELECT} WHERE a.task_id = $1 ORDER BY a.name");
        sqlx::query(trusted(sql)).bind(task_id).fetch_all(&self.pool).await?.iter().map(artifact_from_row).collect()
    }

    /// Tasks that produced content with this hash (content can be produced by several tasks,
    /// e.g. a rendered image and its packaged copy), optionally within one job.
    pub async fn producers_of(&self, sha256: &str, job_id: Option<&str>) -> Result<Vec<ArtifactRecord>> {
        let sql = format!(
            "{ARTIFACT_SELECT} WHERE a.sha256 = $1 AND ($2 = '' OR t.job_id = $2) ORDER BY t.stage, a.task_id, a.name"
        );
        sqlx::query(trusted(sql))
            .bind(sha256)
            .bind(job_id.unwrap_or(""))
            .fetch_all(&self.pool)
            .await?
            .iter()
            .map(artifact_from_row)
            .collect()
    }

    /// Packaged samples of a job and their files (names relative to the sample's directory).
    pub async fn samples(&self, job_id: &str) -> Result<BTreeMap<String, Vec<ArtifactRecord>>> {
        let rows = sqlx::query(
            "SELECT s.sample_id, a.task_id, t.key, a.name, a.sha256, a.size, a.media_type, a.object_key \
             FROM samples s JOIN artifacts a ON a.task_id = s.package_task_id JOIN tasks t ON t.id = a.task_id \
             WHERE s.job_id = $1 ORDER BY s.sample_id, a.name",
        )
        .bind(job_id)
        .fetch_all(&self.pool)
        .await?;
        let mut out: BTreeMap<String, Vec<ArtifactRecord>> = BTreeMap::new();
        for row in rows {
            let sample: String = row.try_get("sample_id")?;
            let mut a = artifact_from_row(&row)?;
            let Some(file) = a.name.strip_prefix(&format!("{sample}/")).map(str::to_string) else {
                continue;
            };
            a.name = file;
            out.entry(sample).or_default().push(a);
        }
        Ok(out)
    }

    /// The grasp records of a job's packaged samples, by grasp id (`<grasp_id>/grasp.json`
    /// artifacts of its package tasks; the artifact's name is given as `grasp.json`).
    pub async fn grasp_records(&self, job_id: &str) -> Result<BTreeMap<String, ArtifactRecord>> {
        let rows = sqlx::query(
            "SELECT a.task_id, t.key, a.name, a.sha256, a.size, a.media_type, a.object_key \
             FROM tasks t JOIN artifacts a ON a.task_id = t.id \
             WHERE t.job_id = $1 AND t.stage = $2 AND a.name LIKE $3 ORDER BY a.name",
        )
        .bind(job_id)
        .bind(vint_core::Stage::Package.as_str())
        .bind(format!("%/{}", vint_core::contract::package::GRASP_RECORD_FILE))
        .fetch_all(&self.pool)
        .await?;
        let mut out = BTreeMap::new();
        for row in rows {
            let mut a = artifact_from_row(&row)?;
            let Some((grasp, file)) = a.name.split_once('/').map(|(g, f)| (g.to_string(), f.to_string())) else {
                continue;
            };
            a.name = file;
            out.insert(grasp, a);
        }
        Ok(out)
    }

    /// The artifacts named `name` that a job's `stage` tasks made, in task-key order (e.g. each
    /// grasp task's `object.ply`).
    pub async fn stage_artifacts(
        &self,
        job_id: &str,
        stage: vint_core::Stage,
        name: &str,
    ) -> Result<Vec<ArtifactRecord>> {
        sqlx::query(
            "SELECT a.task_id, t.key, a.name, a.sha256, a.size, a.media_type, a.object_key \
             FROM tasks t JOIN artifacts a ON a.task_id = t.id \
             WHERE t.job_id = $1 AND t.stage = $2 AND a.name = $3 ORDER BY t.key",
        )
        .bind(job_id)
        .bind(stage.as_str())
        .bind(name)
        .fetch_all(&self.pool)
        .await?
        .iter()
        .map(artifact_from_row)
        .collect()
    }

    /// The (job, package task) that made `sample_id`: in `job_id` if given, else in the newest job
    /// that packaged it.
    pub async fn sample_package_task(&self, job_id: Option<&str>, sample_id: &str) -> Result<Option<(String, String)>> {
        let row = sqlx::query(
            "SELECT s.job_id, s.package_task_id FROM samples s JOIN jobs j ON j.id = s.job_id \
             WHERE s.sample_id = $1 AND ($2 = '' OR s.job_id = $2) ORDER BY j.created_ms DESC, j.id LIMIT 1",
        )
        .bind(sample_id)
        .bind(job_id.unwrap_or(""))
        .fetch_optional(&self.pool)
        .await?;
        row.map(|r| Ok((r.try_get("job_id")?, r.try_get("package_task_id")?))).transpose()
    }

    /// Number of attempts of a task, ended or running (for lineage displays).
    pub async fn attempt_count(&self, task_id: &str) -> Result<u32> {
        self.attempts(task_id).await.map(|a| a.len() as u32)
    }

    /// (artifact rows, distinct contents) of a job: with content addressing, retries and copies
    /// add rows but never new objects for the same content.
    pub async fn artifact_stats(&self, job_id: &str) -> Result<(u64, u64)> {
        let row = sqlx::query(
            "SELECT COUNT(*) AS n, COUNT(DISTINCT a.sha256) AS d FROM artifacts a JOIN tasks t ON t.id = a.task_id \
             WHERE t.job_id = $1",
        )
        .bind(job_id)
        .fetch_one(&self.pool)
        .await?;
        Ok((row.try_get::<i64, _>("n")? as u64, row.try_get::<i64, _>("d")? as u64))
    }
}
