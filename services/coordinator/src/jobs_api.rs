//! The client API (`JobService`): submit, inspect, watch and cancel jobs; lineage and samples; the
//! dashboard's views.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use prost::Message;
use sha2::{Digest, Sha256};
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status};
use vint_core::asset::{self, Asset, MAX_ASSET_BYTES, MAX_ASSETS_TOTAL_BYTES};
use vint_core::plan;
use vint_core::{DatasetSpec, SampleId};
use vint_proto::v1 as pb;
use vint_proto::v1::get_lineage_request::Subject;
use vint_proto::v1::job_service_server::JobService;
use vint_store::{DashboardView, JobAsset, JobRecord, LineageEntry, NewJob, Store, UnknownView};

use crate::convert::{self, status};
use crate::shared_progress::SharedProgress;
use crate::{CoordinatorConfig, now_ms};

/// Failed tasks a job's progress lists (of `tasks_failed`, which counts them all): enough to see
/// every distinct cause in practice, few enough that a 2-million-sample job's message stays small.
const FAILED_TASKS_SHOWN: u32 = 20;

/// Tasks a lineage of a submitted file lists of those that name it (a mesh every grasp and render
/// task of an object reads): its first ones by key, with `more_tasks` when there are others.
const LINEAGE_TASKS_NAMING_A_FILE: u32 = 100;

/// Producers of an artifact's content read to find its origin: the content of a shared file
/// (a camera's intrinsics) is in every sample, and one producer is the origin.
const PRODUCERS_READ: u32 = 8;

#[derive(Clone)]
pub struct JobApi {
    store: Store,
    config: CoordinatorConfig,
    /// What `WatchJob` streams count, shared between the watchers of a job.
    watched: Arc<SharedProgress>,
}

impl JobApi {
    pub fn new(store: Store, config: CoordinatorConfig) -> JobApi {
        let watched = Arc::new(SharedProgress::new(config.watch_interval));
        JobApi { store, config, watched }
    }

    async fn job_record(&self, job_id: &str) -> Result<JobRecord, Status> {
        self.store
            .job(job_id)
            .await
            .map_err(status)?
            .ok_or_else(|| Status::not_found(format!("job {job_id} not found")))
    }

    /// Writes a submission's user files into the artifact store (idempotent: content-addressed).
    async fn store_assets(&self, files: Vec<pb::AssetFile>) -> Result<Vec<JobAsset>, Status> {
        if files.is_empty() {
            return Ok(Vec::new());
        }
        let store = self.config.artifacts.as_ref().ok_or_else(|| {
            Status::failed_precondition("this coordinator has no artifact store (--store) for the spec's user files")
        })?;
        let mut out = Vec::with_capacity(files.len());
        for f in files {
            let stored = store
                .put_bytes(bytes::Bytes::from(f.content))
                .await
                .map_err(|e| Status::unavailable(format!("storing asset {:?}: {e}", f.path)))?;
            let media_type = asset::media_type(&f.path).to_string();
            out.push(JobAsset {
                path: f.path,
                sha256: stored.sha256,
                size: stored.size,
                media_type,
                object_key: stored.key,
            });
        }
        out.sort_by(|a, b| a.path.cmp(&b.path));
        Ok(out)
    }

    /// A job with its progress and, when tasks failed permanently, why (`FAILED_TASKS_SHOWN`).
    async fn job_message(&self, job: &JobRecord) -> Result<pb::Job, Status> {
        let p = self.store.progress(&job.id).await.map_err(status)?;
        let mut message = convert::job(job, &p);
        if let Some(progress) = message.progress.as_mut() {
            progress.failed_tasks = self.failed_tasks(&job.id, progress.tasks_failed).await?;
        }
        Ok(message)
    }

    /// Refuses a new job of the token named `name` when it has `max_jobs_per_token` running; a
    /// resubmission (an existing `key`) is always answered.
    async fn check_jobs_in_flight(&self, name: &str, key: &str) -> Result<(), Status> {
        let cap = self.config.max_jobs_per_token;
        let running = self.store.running_jobs_submitted_by(name).await.map_err(status)?;
        if running < cap || self.store.job_by_idempotency_key(key).await.map_err(status)?.is_some() {
            return Ok(());
        }
        Err(Status::resource_exhausted(format!(
            "token {name} has {running} jobs running, the most one token may (--max-jobs-per-token {cap}); wait for \
             one to finish or cancel one"
        )))
    }

    /// The failed tasks a progress message shows; none asked of the store when none failed.
    async fn failed_tasks(&self, job_id: &str, tasks_failed: u64) -> Result<Vec<pb::FailedTask>, Status> {
        if tasks_failed == 0 {
            return Ok(Vec::new());
        }
        let failed = self.store.failed_tasks(job_id, FAILED_TASKS_SHOWN).await.map_err(status)?;
        Ok(failed.iter().map(convert::failed_task).collect())
    }

    /// The job that packaged `sample_id`: the given one, or the most recent that has it.
    async fn job_of_sample(&self, job_id: &str, sample_id: &str) -> Result<(String, String), Status> {
        let job = (!job_id.is_empty()).then_some(job_id);
        self.store.sample_package_task(job, sample_id).await.map_err(status)?.ok_or_else(|| {
            Status::not_found(format!("sample {sample_id} is not packaged in {}", job.unwrap_or("any job")))
        })
    }

    /// A sample's chain: its files in the package task, then its own noise, render and grasp tasks.
    async fn sample_lineage(&self, job_id: &str, sample_id: &str) -> Result<pb::Lineage, Status> {
        let id: SampleId =
            sample_id.parse().map_err(|e: vint_core::sample::BadSampleId| Status::invalid_argument(e.to_string()))?;
        let (job_id, package_task) = self.job_of_sample(job_id, sample_id).await?;
        let job = self.job_record(&job_id).await?;
        let job_plan = crate::planner::job_plan(&self.store, &job).await?;
        let own: BTreeSet<String> = plan::grasp_keys(&id.object, &id.hand, id.grasp_index)
            .into_iter()
            .map(|(_, key)| key)
            .chain([job_plan.chunk_of(&id.object, &id.hand, id.grasp_index).key()])
            .collect();
        let mut chain = self.store.lineage(&package_task).await.map_err(status)?;
        // Show the sample's chain in pipeline order, from its package back to its grasp.
        chain.sort_by_key(|e| std::cmp::Reverse(e.task.stage));
        let prefix = format!("{sample_id}/");
        let sample_view = format!("v{:02}_", id.view_index);
        let mut tasks = Vec::new();
        for mut entry in chain.drain(..) {
            let is_package = entry.task.id == package_task;
            if !is_package && !own.contains(&entry.task.key) {
                continue;
            }
            if is_package {
                entry.outputs.retain(|a| a.name.starts_with(&prefix));
                entry.inputs.retain(|a| {
                    own.contains(&a.task_key) && (!a.name.starts_with('v') || a.name.starts_with(&sample_view))
                });
                entry.depends_on.retain(|d| own.iter().any(|k| d.ends_with(&format!("/{k}"))));
            }
            tasks.push(self.lineage_task(entry).await?);
        }
        Ok(pb::Lineage { job_id, subject: sample_id.to_string(), tasks, user_files: Vec::new(), more_tasks: false })
    }

    /// Lineage of content no task produced: a file a user submitted with a job, and the tasks
    /// whose parameters name it.
    async fn user_file_lineage(&self, sha: String, job: Option<&str>) -> Result<pb::Lineage, Status> {
        let files = self.store.user_files_with(&sha, job).await.map_err(status)?;
        let job_id = files
            .first()
            .map(|(j, _)| j.clone())
            .ok_or_else(|| Status::not_found(format!("no artifact and no submitted file with sha256 {sha}")))?;
        let mut naming =
            self.store.tasks_naming(&job_id, &sha, LINEAGE_TASKS_NAMING_A_FILE + 1).await.map_err(status)?;
        let more_tasks = naming.len() > LINEAGE_TASKS_NAMING_A_FILE as usize;
        naming.truncate(LINEAGE_TASKS_NAMING_A_FILE as usize);
        let mut tasks = Vec::new();
        for id in naming {
            if let Some(entry) = self.store.lineage(&id).await.map_err(status)?.into_iter().next() {
                tasks.push(self.lineage_task(entry).await?);
            }
        }
        let user_files = files
            .into_iter()
            .filter(|(j, _)| *j == job_id)
            .map(|(_, a)| pb::UserFile { path: a.path, sha256: a.sha256, size: a.size, media_type: a.media_type })
            .collect();
        Ok(pb::Lineage { job_id, subject: sha, tasks, user_files, more_tasks })
    }

    async fn lineage_task(&self, e: LineageEntry) -> Result<pb::LineageTask, Status> {
        let attempts = self.store.attempt_count(&e.task.id).await.map_err(status)?;
        Ok(pb::LineageTask {
            task_id: e.task.id,
            key: e.task.key,
            stage: e.task.stage.as_str().to_string(),
            state: e.task.state.as_str().to_string(),
            params_json: e.task.params_json,
            engine_json: e.task.engine_json.unwrap_or_default(),
            attempts,
            inputs: e.inputs.iter().map(convert::artifact).collect(),
            outputs: e.outputs.iter().map(convert::artifact).collect(),
            depends_on: e.depends_on,
            reused_from: e.task.reused_from.unwrap_or_default(),
        })
    }
}

/// Default idempotency key: the spec's content and its user files' hashes, so resubmitting the
/// same files is a no-op and changing a mesh on disk makes a new job.
fn default_idempotency_key(spec_toml: &str, assets: &[JobAsset], timing_only: bool) -> String {
    let mut h = Sha256::new();
    h.update(spec_toml.as_bytes());
    if timing_only {
        // The same spec for timing-only workers is another job.
        h.update(b"\0timing-only");
    }
    for a in assets {
        h.update(format!("\0{}\0{}", a.path, a.sha256).as_bytes());
    }
    format!("spec-sha256:{}", hex::encode(h.finalize()))
}

/// The submitted user files, checked against the spec: each a file the spec names, once, within
/// the size limits. (Files the spec names but the submission lacks are the planner's error.)
fn checked_assets(spec: &DatasetSpec, files: Vec<pb::AssetFile>) -> Result<Vec<pb::AssetFile>, Status> {
    let named = spec.asset_paths();
    let mut seen = BTreeSet::new();
    let mut total = 0u64;
    for f in &files {
        let size = f.content.len() as u64;
        total += size;
        if !named.contains(&f.path) {
            return Err(Status::invalid_argument(format!("asset {:?}: the spec names no such file", f.path)));
        }
        if !seen.insert(f.path.as_str()) {
            return Err(Status::invalid_argument(format!("asset {:?}: submitted twice", f.path)));
        }
        if size > MAX_ASSET_BYTES {
            return Err(Status::invalid_argument(format!(
                "asset {:?}: {size} bytes, larger than the limit of {MAX_ASSET_BYTES}",
                f.path
            )));
        }
    }
    if total > MAX_ASSETS_TOTAL_BYTES {
        return Err(Status::invalid_argument(format!(
            "assets: {total} bytes in all, larger than the limit of {MAX_ASSETS_TOTAL_BYTES}"
        )));
    }
    Ok(files)
}

#[tonic::async_trait]
impl JobService for JobApi {
    async fn submit_job(
        &self,
        request: Request<pb::SubmitJobRequest>,
    ) -> Result<Response<pb::SubmitJobResponse>, Status> {
        let submitter = request.extensions().get::<crate::auth::Caller>().map(|c| c.name.to_string());
        let req = request.into_inner();
        let spec =
            DatasetSpec::parse(&req.spec_toml).map_err(|e| Status::invalid_argument(format!("invalid spec:\n{e}")))?;
        // Limits first: nothing is planned, stored or allocated for a spec over one.
        let cost = vint_core::cost::of(&spec).map_err(|e| Status::invalid_argument(e.to_string()))?;
        let over = vint_core::limits::check(&self.config.limits, &spec, &cost);
        if !over.is_empty() {
            let lines: Vec<String> = over.iter().map(ToString::to_string).collect();
            return Err(Status::invalid_argument(format!(
                "spec over this coordinator's limits:\n{}",
                lines.join("\n")
            )));
        }
        let files = checked_assets(&spec, req.assets)?;
        let assets = self.store_assets(files).await?;
        let key = if req.idempotency_key.is_empty() {
            default_idempotency_key(&req.spec_toml, &assets, req.timing_only)
        } else {
            req.idempotency_key
        };
        if let Some(name) = &submitter {
            self.check_jobs_in_flight(name, &key).await?;
        }
        let planned: Vec<Asset> =
            assets.iter().map(|a| Asset { path: a.path.clone(), sha256: a.sha256.clone(), size: a.size }).collect();
        let tasks = plan::initial_tasks(&spec, &planned).map_err(|e| Status::invalid_argument(e.to_string()))?;
        let job_plan = plan::JobPlan::new(&spec, &planned).map_err(|e| Status::invalid_argument(e.to_string()))?;
        let plan_json = serde_json::to_string(&job_plan).map_err(|e| Status::internal(e.to_string()))?;
        let uuid = uuid::Uuid::new_v4().simple().to_string();
        let new_job = NewJob {
            id: format!("j{}", &uuid[..12]),
            name: spec.dataset.name.clone(),
            seed: spec.dataset.seed,
            spec_toml: req.spec_toml,
            plan_json,
            idempotency_key: key,
            assets,
            timing_only: req.timing_only,
            submitted_by: submitter,
        };
        let (job, created) = self.store.submit_job(&new_job, &tasks, now_ms()).await.map_err(status)?;
        if job.timing_only != req.timing_only {
            return Err(Status::invalid_argument(format!(
                "idempotency_key {:?} names job {} submitted with timing_only = {}, not {}",
                new_job.idempotency_key, job.id, job.timing_only, req.timing_only
            )));
        }
        if created {
            self.config.metrics.job_submitted();
        }
        tracing::info!(job = %job.id, created, tasks = tasks.len(), "job submitted");
        Ok(Response::new(pb::SubmitJobResponse { job: Some(self.job_message(&job).await?), created }))
    }

    async fn get_job(&self, request: Request<pb::GetJobRequest>) -> Result<Response<pb::Job>, Status> {
        let job = self.job_record(&request.into_inner().job_id).await?;
        Ok(Response::new(self.job_message(&job).await?))
    }

    async fn list_jobs(&self, request: Request<pb::ListJobsRequest>) -> Result<Response<pb::ListJobsResponse>, Status> {
        let limit = match request.into_inner().limit {
            0 => 50,
            n => n.min(1_000),
        };
        let listed = self.store.list_jobs(limit).await.map_err(status)?;
        let ids: Vec<&str> = listed.iter().map(|j| j.id.as_str()).collect();
        let mut progress = self.store.progress_of(&ids).await.map_err(status)?;
        // A listing counts failed tasks but does not explain them (GetJob does).
        let jobs = listed.iter().map(|job| convert::job(job, &progress.remove(&job.id).unwrap_or_default())).collect();
        Ok(Response::new(pb::ListJobsResponse { jobs }))
    }

    type WatchJobStream = ReceiverStream<Result<pb::JobProgress, Status>>;

    async fn watch_job(&self, request: Request<pb::WatchJobRequest>) -> Result<Response<Self::WatchJobStream>, Status> {
        let job_id = request.into_inner().job_id;
        self.job_record(&job_id).await?;
        let (tx, rx) = tokio::sync::mpsc::channel(16);
        let api = self.clone();
        let open = self.config.metrics.watch_opened();
        tokio::spawn(async move {
            let _open = open;
            let mut last: Option<pb::JobProgress> = None;
            loop {
                let update = async {
                    let job = api.job_record(&job_id).await?;
                    // A running job's count is shared with its other watchers; an ended job's is
                    // final, so it is taken fresh for this watcher's last message.
                    let p = if job.state.is_terminal() {
                        api.store.progress(&job_id).await
                    } else {
                        api.watched.get(&job_id, || api.store.progress(&job_id)).await
                    }
                    .map_err(status)?;
                    let mut progress = convert::progress(&job, &p);
                    // Failed tasks stay failed: ask again only when more have failed.
                    progress.failed_tasks = match &last {
                        Some(l) if l.tasks_failed == progress.tasks_failed => l.failed_tasks.clone(),
                        _ => api.failed_tasks(&job_id, progress.tasks_failed).await?,
                    };
                    Ok::<_, Status>((job.state.is_terminal(), progress))
                }
                .await;
                match update {
                    Ok((done, progress)) => {
                        if last.as_ref() != Some(&progress) {
                            last = Some(progress.clone());
                            if tx.send(Ok(progress)).await.is_err() {
                                return; // the client went away
                            }
                        }
                        if done {
                            return;
                        }
                    }
                    Err(e) => {
                        let _ = tx.send(Err(e)).await;
                        return;
                    }
                }
                // A client that leaves a job that never changes would otherwise be noticed only
                // at the next send, which may never come: the poller ends with its client.
                tokio::select! {
                    () = tokio::time::sleep(api.config.watch_interval) => {}
                    () = tx.closed() => return,
                }
            }
        });
        Ok(Response::new(ReceiverStream::new(rx)))
    }

    async fn cancel_job(&self, request: Request<pb::CancelJobRequest>) -> Result<Response<pb::Job>, Status> {
        let job_id = request.into_inner().job_id;
        self.job_record(&job_id).await?;
        let job = self.store.cancel_job(&job_id, now_ms()).await.map_err(status)?;
        tracing::info!(job = %job_id, state = %job.state, "job cancel requested");
        Ok(Response::new(self.job_message(&job).await?))
    }

    async fn get_lineage(&self, request: Request<pb::GetLineageRequest>) -> Result<Response<pb::Lineage>, Status> {
        let req = request.into_inner();
        match req.subject {
            Some(Subject::SampleId(sample)) => Ok(Response::new(self.sample_lineage(&req.job_id, &sample).await?)),
            Some(Subject::ArtifactSha256(sha)) => {
                let job = (!req.job_id.is_empty()).then_some(req.job_id.as_str());
                let producers = self.store.producers_of(&sha, job, PRODUCERS_READ).await.map_err(status)?;
                // Packaging copies content; the task that first made it is its origin.
                let Some(first) = producers.iter().find(|a| !a.task_key.starts_with("package/")).or(producers.first())
                else {
                    return Ok(Response::new(self.user_file_lineage(sha, job).await?));
                };
                let chain = self.store.lineage(&first.task_id).await.map_err(status)?;
                let job_id = chain.first().map(|e| e.task.job_id.clone()).unwrap_or_default();
                let mut tasks = Vec::new();
                for e in chain {
                    tasks.push(self.lineage_task(e).await?);
                }
                Ok(Response::new(pb::Lineage {
                    job_id,
                    subject: sha,
                    tasks,
                    user_files: Vec::new(),
                    more_tasks: false,
                }))
            }
            None => Err(Status::invalid_argument("lineage needs a sample_id or an artifact_sha256")),
        }
    }

    async fn get_server_info(
        &self,
        _request: Request<pb::GetServerInfoRequest>,
    ) -> Result<Response<pb::ServerInfo>, Status> {
        Ok(Response::new(pb::ServerInfo {
            version: env!("CARGO_PKG_VERSION").to_string(),
            store_url: self.config.artifacts.as_ref().map(|a| a.url().to_string()).unwrap_or_default(),
        }))
    }

    async fn query_dashboard(
        &self,
        request: Request<pb::QueryDashboardRequest>,
    ) -> Result<Response<pb::DashboardTable>, Status> {
        let req = request.into_inner();
        let view: DashboardView = req.view.parse().map_err(|e: UnknownView| Status::invalid_argument(e.to_string()))?;
        let job = Some(req.job_id.as_str()).filter(|j| !j.is_empty());
        if let Some(job_id) = job {
            if !view.per_job() {
                return Err(Status::invalid_argument(format!(
                    "job_id: view {view} is not per job, so it takes no job (got {job_id:?})"
                )));
            }
            self.job_record(job_id).await?;
        }
        let table = self.store.dashboard(view, job, req.limit).await.map_err(status)?;
        Ok(Response::new(convert::dashboard(table)))
    }

    async fn list_samples(
        &self,
        request: Request<pb::ListSamplesRequest>,
    ) -> Result<Response<pb::ListSamplesResponse>, Status> {
        let req = request.into_inner();
        let job_id = req.job_id;
        self.job_record(&job_id).await?;
        let limit = if req.page_size == 0 { SAMPLES_PAGE_TASKS } else { req.page_size.min(SAMPLES_PAGE_TASKS) };
        let rows = self.store.package_outputs_after(&job_id, &req.page_token, limit).await.map_err(status)?;
        let mut page = pb::ListSamplesResponse::default();
        if req.page_token.is_empty() {
            page.models = self.object_models(&job_id).await?;
            page.pairs = self.pair_trials(&job_id).await?;
        }
        // Whole package tasks, in key order, until the page holds about SAMPLES_PAGE_BYTES.
        let mut tasks: Vec<(String, Vec<vint_store::ArtifactRecord>)> = Vec::new();
        for row in rows {
            match tasks.last_mut() {
                Some((key, files)) if *key == row.task_key => files.push(row),
                _ => tasks.push((row.task_key.clone(), vec![row])),
            }
        }
        let fetched = tasks.len();
        let mut taken = 0;
        let mut last_key = String::new();
        for (key, files) in tasks {
            for (sample_id, files) in vint_store::samples_of(files.clone()) {
                page.samples.push(pb::Sample { sample_id, files: files.iter().map(convert::artifact).collect() });
            }
            for (grasp_id, file) in vint_store::grasp_records_of(files) {
                page.grasps.push(pb::GraspRecord { grasp_id, file: Some(convert::artifact(&file)) });
            }
            taken += 1;
            last_key = key;
            if page.encoded_len() >= SAMPLES_PAGE_BYTES {
                break;
            }
        }
        let more = taken < fetched || u32::try_from(fetched).is_ok_and(|n| n == limit);
        page.next_page_token = if more { last_key } else { String::new() };
        Ok(Response::new(page))
    }
}

/// Most package tasks on one page of `ListSamples`, and the size past which a page ends (well
/// under the clients' 4 MiB default message limit).
const SAMPLES_PAGE_TASKS: u32 = 256;
const SAMPLES_PAGE_BYTES: usize = 2 << 20;

impl JobApi {
    /// One model mesh per object: the first grasp task's `object.ply` (every grasp task of an
    /// object builds the same mesh from the same entry).
    async fn object_models(&self, job_id: &str) -> Result<Vec<pb::ObjectModel>, Status> {
        let made = self
            .store
            .stage_artifacts(job_id, vint_core::Stage::Grasp, vint_core::contract::grasp::MODEL_FILE)
            .await
            .map_err(status)?;
        let mut models: BTreeMap<String, pb::ObjectModel> = BTreeMap::new();
        for artifact in &made {
            if let Some(chunk) = plan::GraspChunk::from_key(&artifact.task_key) {
                models.entry(chunk.object.clone()).or_insert_with(|| pb::ObjectModel {
                    object: chunk.object,
                    file: Some(convert::artifact(artifact)),
                });
            }
        }
        Ok(models.into_values().collect())
    }

    /// Trials per (object, hand), summed over the pair's finished grasp tasks' results.
    async fn pair_trials(&self, job_id: &str) -> Result<Vec<pb::PairTrials>, Status> {
        let mut pairs: BTreeMap<(String, String), pb::PairTrials> = BTreeMap::new();
        for task in self.store.tasks_of_job(job_id).await.map_err(status)? {
            let (Some(chunk), Some(result)) = (plan::GraspChunk::from_key(&task.key), task.result_json.as_deref())
            else {
                continue;
            };
            let result: vint_core::contract::grasp::GraspResult = serde_json::from_str(result)
                .map_err(|e| Status::internal(format!("task {}: unreadable grasp result: {e}", task.key)))?;
            let pair = pairs.entry((chunk.object.clone(), chunk.hand.clone())).or_insert_with(|| pb::PairTrials {
                object: chunk.object,
                hand: chunk.hand,
                ..Default::default()
            });
            // Completions are checked against their chunks (`planner::check_grasp_counts`); the
            // sums saturate all the same rather than wrap.
            let accepted = u32::try_from(result.accepted.len()).unwrap_or(u32::MAX);
            pair.accepted = pair.accepted.saturating_add(accepted);
            pair.trials = pair.trials.saturating_add(accepted);
            for (reason, n) in result.rejected {
                pair.trials = pair.trials.saturating_add(n);
                let count = pair.rejected.entry(reason).or_default();
                *count = count.saturating_add(n);
            }
        }
        Ok(pairs.into_values().collect())
    }
}
