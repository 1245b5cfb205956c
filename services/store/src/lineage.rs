//! Lineage: from a sample or an artifact back through every task, parameter set, engine version
//! and input hash that made it; and the packaged samples of a job.

use std::collections::{BTreeMap, BTreeSet};

use sqlx::Row;
use sqlx::any::AnyRow;

use vint_core::sample::SampleId;

use crate::sql::sql;
use crate::{ArtifactRecord, JobAsset, LineageEntry, Result, Store, StoreError, outputs};

/// The files of a row with a task's `task_id`, `key` and packed `files` (`outputs.rs`).
pub(crate) fn outputs_from_row(row: &AnyRow) -> Result<Vec<ArtifactRecord>> {
    let task_id: String = row.try_get("task_id")?;
    let key: String = row.try_get("key")?;
    let files: Vec<u8> = row.try_get("files")?;
    outputs::unpack(&task_id, &key, &files)
}

/// Every file of `rows` (see `outputs_from_row`), in the rows' order and then by name.
fn outputs_from_rows(rows: &[AnyRow]) -> Result<Vec<ArtifactRecord>> {
    let mut files = Vec::new();
    for row in rows {
        files.extend(outputs_from_row(row)?);
    }
    Ok(files)
}

/// The `task_key` lineage gives a job's user files (they come with the submission, not a task).
pub const ASSET_TASK_KEY: &str = "asset";

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
            let depends_on: Vec<String> = sqlx::query(sql(self.backend, "task_dependencies")?)
                .bind(&id)
                .fetch_all(&self.pool)
                .await?
                .iter()
                .map(|r| r.try_get("depends_on"))
                .collect::<Result<_, _>>()?;
            let rows = sqlx::query(sql(self.backend, "task_inputs")?).bind(&id).fetch_all(&self.pool).await?;
            let mut inputs = outputs_from_rows(&rows)?;
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
        outputs_from_rows(&sqlx::query(sql(self.backend, "task_outputs")?).bind(task_id).fetch_all(&self.pool).await?)
    }

    /// The files of a job's tasks of `stage`, in task-key order (only a succeeded task has an
    /// `outputs` row).
    async fn stage_outputs(&self, job_id: &str, stage: vint_core::Stage) -> Result<Vec<ArtifactRecord>> {
        let rows = sqlx::query(sql(self.backend, "stage_outputs")?)
            .bind(job_id)
            .bind(stage.as_str())
            .fetch_all(&self.pool)
            .await?;
        outputs_from_rows(&rows)
    }

    /// Up to `limit` tasks that produced content with this hash (content can be produced by
    /// several tasks, e.g. a rendered image and its packaged copies), optionally within one job;
    /// by stage and task, packaged copies last. Outputs are not indexed by hash (an index entry a
    /// file cost more than the packed file): the database finds the rows holding the hash's bytes
    /// by scanning the job's (or every job's) outputs.
    pub async fn producers_of(&self, sha256: &str, job_id: Option<&str>, limit: u32) -> Result<Vec<ArtifactRecord>> {
        if outputs::digest_bytes(sha256).is_none() {
            return Ok(Vec::new());
        }
        let rows = sqlx::query(sql(self.backend, "outputs_holding")?)
            .bind(sha256)
            .bind(job_id.unwrap_or(""))
            .bind(i64::from(limit))
            .fetch_all(&self.pool)
            .await?;
        Ok(outputs_from_rows(&rows)?.into_iter().filter(|a| a.sha256 == sha256).collect())
    }

    /// The ids of up to `limit` of the job's tasks whose parameters name `text` (a submitted
    /// file's hash), by key.
    pub async fn tasks_naming(&self, job_id: &str, text: &str, limit: u32) -> Result<Vec<String>> {
        let rows = sqlx::query(sql(self.backend, "tasks_naming")?)
            .bind(job_id)
            .bind(text)
            .bind(i64::from(limit))
            .fetch_all(&self.pool)
            .await?;
        rows.iter().map(|row| Ok(row.try_get("id")?)).collect()
    }

    /// Packaged samples of a job and their files (names relative to the sample's directory).
    pub async fn samples(&self, job_id: &str) -> Result<BTreeMap<String, Vec<ArtifactRecord>>> {
        Ok(samples_of(self.stage_outputs(job_id, vint_core::Stage::Package).await?))
    }

    /// The files of up to `limit` of a job's package tasks whose keys sort after `after_key`
    /// ("" for the first), in key order: one page of `samples_of` and `grasp_records_of`.
    pub async fn package_outputs_after(
        &self,
        job_id: &str,
        after_key: &str,
        limit: u32,
    ) -> Result<Vec<ArtifactRecord>> {
        let rows = sqlx::query(sql(self.backend, "stage_outputs_after")?)
            .bind(job_id)
            .bind(vint_core::Stage::Package.as_str())
            .bind(after_key)
            .bind(i64::from(limit))
            .fetch_all(&self.pool)
            .await?;
        outputs_from_rows(&rows)
    }

    /// The grasp records of a job's packaged samples, by grasp id (`<grasp_id>/grasp.json`
    /// artifacts of its package tasks; the artifact's name is given as `grasp.json`).
    pub async fn grasp_records(&self, job_id: &str) -> Result<BTreeMap<String, ArtifactRecord>> {
        Ok(grasp_records_of(self.stage_outputs(job_id, vint_core::Stage::Package).await?))
    }

    /// The artifacts named `name` that a job's `stage` tasks made, in task-key order (e.g. each
    /// grasp task's `object.ply`).
    pub async fn stage_artifacts(
        &self,
        job_id: &str,
        stage: vint_core::Stage,
        name: &str,
    ) -> Result<Vec<ArtifactRecord>> {
        Ok(self.stage_outputs(job_id, stage).await?.into_iter().filter(|a| a.name == name).collect())
    }

    /// The (job, package task) that made `sample_id`: in `job_id` if given, else in the newest job
    /// that packaged it. A job's stored plan names the sample's package task (the chunk of its
    /// grasp); a job stored without one (before migration 0005) has its sample's (object, hand)
    /// pair's package tasks read until one lists it.
    pub async fn sample_package_task(&self, job_id: Option<&str>, sample_id: &str) -> Result<Option<(String, String)>> {
        let Ok(id) = sample_id.parse::<SampleId>() else {
            return Ok(None);
        };
        let jobs =
            sqlx::query(sql(self.backend, "job_plans")?).bind(job_id.unwrap_or("")).fetch_all(&self.pool).await?;
        let dir = format!("{sample_id}/");
        for job in &jobs {
            let job_id: String = job.try_get("id")?;
            let plan_json: Option<String> = job.try_get("plan_json")?;
            let plan = plan_json.as_deref().and_then(|p| serde_json::from_str::<vint_core::plan::JobPlan>(p).ok());
            let rows = match plan {
                Some(plan) => {
                    let key = plan.chunk_of(&id.object, &id.hand, id.grasp_index).package_key();
                    sqlx::query(sql(self.backend, "task_outputs")?)
                        .bind(format!("{job_id}/{key}"))
                        .fetch_all(&self.pool)
                        .await?
                }
                None => {
                    let prefix = format!("{}/{}/{}/", vint_core::Stage::Package.as_str(), id.object, id.hand);
                    let pattern = format!("{}%", prefix.replace('\\', "\\\\").replace('%', "\\%").replace('_', "\\_"));
                    sqlx::query(sql(self.backend, "outputs_with_key_prefix")?)
                        .bind(&job_id)
                        .bind(pattern)
                        .fetch_all(&self.pool)
                        .await?
                }
            };
            for row in &rows {
                if outputs_from_row(row)?.iter().any(|a| a.name.starts_with(&dir)) {
                    return Ok(Some((job_id, row.try_get("task_id")?)));
                }
            }
        }
        Ok(None)
    }

    /// Number of attempts of a task, ended or running (for lineage displays).
    pub async fn attempt_count(&self, task_id: &str) -> Result<u32> {
        self.attempts(task_id).await.map(|a| a.len() as u32)
    }

    /// (artifact rows, distinct contents) of a job: with content addressing, retries and copies
    /// add rows but never new objects for the same content.
    pub async fn artifact_stats(&self, job_id: &str) -> Result<(u64, u64)> {
        let files = outputs_from_rows(
            &sqlx::query(sql(self.backend, "job_outputs")?).bind(job_id).fetch_all(&self.pool).await?,
        )?;
        let distinct: BTreeSet<&str> = files.iter().map(|a| a.sha256.as_str()).collect();
        Ok((files.len() as u64, distinct.len() as u64))
    }
}

/// Package tasks' files as samples and their files (names relative to the sample's directory).
pub fn samples_of(package_outputs: Vec<ArtifactRecord>) -> BTreeMap<String, Vec<ArtifactRecord>> {
    let mut out: BTreeMap<String, Vec<ArtifactRecord>> = BTreeMap::new();
    for mut a in package_outputs {
        let Some((sample, file)) = a.name.split_once('/') else { continue };
        if sample.parse::<SampleId>().is_err() {
            continue;
        }
        let (sample, file) = (sample.to_string(), file.to_string());
        a.name = file;
        out.entry(sample).or_default().push(a);
    }
    out
}

/// Package tasks' grasp records, by grasp id (`<grasp_id>/grasp.json`; the artifact's name is
/// given as `grasp.json`).
pub fn grasp_records_of(package_outputs: Vec<ArtifactRecord>) -> BTreeMap<String, ArtifactRecord> {
    let record = vint_core::contract::package::GRASP_RECORD_FILE;
    let mut out = BTreeMap::new();
    for mut a in package_outputs {
        let Some((grasp, file)) = a.name.split_once('/') else { continue };
        if file != record {
            continue;
        }
        let grasp = grasp.to_string();
        a.name = record.to_string();
        out.insert(grasp, a);
    }
    out
}
