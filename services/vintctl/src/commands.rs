//! The commands that take a spec or talk to a coordinator (all but `run`, `study`, `hands` and
//! `objects`): each wires `spec_file`, `client`, `export` and `report` together and decides its
//! exit code.

use std::path::Path;

use anyhow::anyhow;
use serde_json::json;
use vint_artifacts::ArtifactStore;
use vint_connect::Remote;
use vint_core::JobState;
use vint_core::limits::Limits;
use vint_proto::v1 as pb;
use vint_proto::v1::get_lineage_request::Subject;

use crate::client::Coordinator;
use crate::estimate::Estimate;
use crate::formats::Target;
use crate::report::{self, JsonProgress, ProgressView};
use crate::spec_file::load_spec;
use crate::{CliResult, Failure, bad_input, export};

/// Refuses (exit 2) a spec over any of `limits`, naming each with its count, the limit and the
/// flag that raises it; `--json` prints them as `over_limits`.
pub fn check_limits(path: &Path, spec: &vint_core::DatasetSpec, limits: &Limits) -> CliResult {
    let cost = vint_core::cost::of(spec).map_err(|e| bad_input(anyhow!("{}: {e}", path.display())))?;
    let over = vint_core::limits::check(limits, spec, &cost);
    if over.is_empty() {
        return Ok(());
    }
    let lines: Vec<String> = over.iter().map(|o| format!("  {o}")).collect();
    let report = json!({
        "valid": false,
        "over_limits": over.iter().map(|o| json!({"what": o.what, "count": o.count, "limit": o.limit, "flag": o.flag})).collect::<Vec<_>>(),
    });
    Err(bad_input(anyhow!("{}: over a coordinator's limits:\n{}", path.display(), lines.join("\n")))
        .with_report(report))
}

pub fn validate(path: &Path, limits: &Limits, json: bool) -> CliResult {
    let loaded = match load_spec(path) {
        Ok(loaded) => loaded,
        Err(f) => {
            let report =
                f.spec_errors().map(|errors| json!({"valid": false, "errors": report::spec_errors_json(errors)}));
            return Err(match report {
                Some(report) => f.with_report(report),
                None => f,
            });
        }
    };
    let spec = &loaded.spec;
    check_limits(path, spec, limits)?;
    let estimate = Estimate::of(spec).map_err(|e| bad_input(anyhow!("{}: {e}", path.display())))?;
    if json {
        report::print_json(&json!({
            "valid": true, "spec": spec, "max_samples": spec.max_samples(), "estimate": estimate,
        }));
    } else {
        report::valid_spec(path, spec, &estimate);
    }
    Ok(())
}

/// `vintctl plan`: the spec's cost before anything runs. An invalid spec fails as `validate`'s
/// does (exit 2, every problem named).
pub fn plan(path: &Path, limits: &Limits, json: bool) -> CliResult {
    let loaded = load_spec(path)?;
    check_limits(path, &loaded.spec, limits)?;
    let plan = crate::plan::Plan::of(&loaded.spec).map_err(|e| bad_input(anyhow!("{}: {e}", path.display())))?;
    if json {
        report::print_json(&json!(plan));
    } else {
        print!("{}", crate::plan::text(&plan));
    }
    Ok(())
}

pub async fn submit(remote: &Remote, path: &Path, key: Option<String>, timing_only: bool, json: bool) -> CliResult {
    let loaded = load_spec(path)?;
    let mut coordinator = Coordinator::connect(remote).await?;
    let request = pb::SubmitJobRequest {
        spec_toml: loaded.text,
        idempotency_key: key.unwrap_or_default(),
        assets: loaded.assets,
        timing_only,
    };
    let resp = coordinator.submit(request).await?;
    let job = resp.job.ok_or_else(|| anyhow!("coordinator returned no job"))?;
    if json {
        report::print_json(&json!({"job_id": job.job_id, "created": resp.created, "state": job.state}));
    } else {
        if !resp.created {
            eprintln!("this spec was already submitted (same idempotency key): returning that job");
        }
        println!("{}", job.job_id);
    }
    Ok(())
}

pub async fn status(remote: &Remote, job: &str, json: bool) -> CliResult {
    let job = Coordinator::connect(remote).await?.job(job).await?;
    report::job(&job, json);
    Ok(())
}

pub async fn jobs(remote: &Remote, limit: u32, json: bool) -> CliResult {
    let jobs = Coordinator::connect(remote).await?.jobs(limit).await?;
    report::jobs(&jobs, json);
    Ok(())
}

/// One dashboard view (docs/dashboard.md), of one job or of all.
pub async fn dashboard(remote: &Remote, view: &str, job: Option<&str>, limit: u32, json: bool) -> CliResult {
    let table = Coordinator::connect(remote).await?.dashboard(view, job, limit).await?;
    report::dashboard(&table, json);
    Ok(())
}

pub async fn cancel(remote: &Remote, job: &str, json: bool) -> CliResult {
    let job = Coordinator::connect(remote).await?.cancel(job).await?;
    report::job(&job, json);
    Ok(())
}

/// Follows a job until it ends; exits 1 unless it succeeded, naming the tasks that failed.
pub async fn watch(remote: &Remote, job: &str, json: bool) -> CliResult {
    let mut coordinator = Coordinator::connect(remote).await?;
    let last = coordinator.follow(job, &ProgressView::new(json.then_some(JsonProgress::Stdout))).await?;
    job_outcome(&last)
}

/// Exit status of a finished job: a failed or cancelled one is a failure that says which tasks
/// failed and why.
pub fn job_outcome(p: &pb::JobProgress) -> CliResult {
    if p.state == JobState::Succeeded.as_str() {
        return Ok(());
    }
    let mut message = format!(
        "job {} {}: {} task(s) failed permanently, {} sample(s) packaged",
        p.job_id, p.state, p.tasks_failed, p.samples_packaged
    );
    for (i, line) in report::failed_task_lines(p).into_iter().enumerate() {
        message.push_str(if i == 0 { ":\n  " } else { "\n  " });
        message.push_str(&line);
    }
    Err(Failure { code: 1, error: anyhow!(message) })
}

pub async fn lineage(remote: &Remote, subject: &str, job: Option<String>, artifact: bool, json: bool) -> CliResult {
    let subject = if artifact { Subject::ArtifactSha256(subject.into()) } else { Subject::SampleId(subject.into()) };
    let request = pb::GetLineageRequest { job_id: job.unwrap_or_default(), subject: Some(subject) };
    let lineage = Coordinator::connect(remote).await?.lineage(request).await?;
    report::lineage(&lineage, json);
    Ok(())
}

/// Writes a finished job's packaged samples to `out`. A running job is refused (its dataset is
/// not there yet); a failed or cancelled one exports what it packaged and says what is missing.
pub async fn export(
    remote: &Remote,
    job_id: &str,
    out: &Path,
    target: Target,
    store: Option<String>,
    json: bool,
) -> CliResult {
    let ExportedJob { job, state, planned, summary } = export_job(remote, job_id, out, target, store).await?;
    let p = job.progress.clone().unwrap_or_default();
    if json {
        let mut doc = report::export_json(&summary);
        doc["job_state"] = json!(job.state);
        doc["max_samples"] = json!(planned);
        doc["failed_tasks"] = report::failed_tasks_json(&p.failed_tasks);
        report::print_json(&doc);
        return Ok(());
    }
    report::export_text(&summary);
    if state != JobState::Succeeded {
        let of = planned.map(|n| format!(" of at most {n} (if every trial were accepted)")).unwrap_or_default();
        eprintln!(
            "note: job {job_id} {}: this is the {} sample(s) it packaged{of}; {} task(s) failed permanently \
             (`vintctl status {job_id}` says why)",
            job.state, summary.samples, p.tasks_failed
        );
    }
    Ok(())
}

/// `vintctl convert`: a native dataset directory to another layout.
pub fn convert(dataset: &Path, out: &Path, target: Target, json: bool) -> CliResult {
    if target.format == crate::formats::Format::Native {
        return Err(bad_input(anyhow!(
            "--format native: the dataset is native already; choose bop, webdataset or bop-webdataset"
        )));
    }
    let summary = export::convert_dir(dataset, out, target)?;
    if json {
        report::print_json(&report::export_json(&summary));
    } else {
        report::export_text(&summary);
    }
    Ok(())
}

/// A job's dataset as `export_job` wrote it.
pub struct ExportedJob {
    pub job: pb::Job,
    pub state: JobState,
    /// The spec's upper bound on samples (every trial accepted): what a failed job could have had.
    pub planned: Option<u64>,
    pub summary: export::ExportSummary,
}

/// Exports a finished job's dataset to `out` in `target`'s layout: what `export` reports on, and
/// what `stats` computes on. A running job is refused (its dataset is not there yet).
pub async fn export_job(
    remote: &Remote,
    job_id: &str,
    out: &Path,
    target: Target,
    store: Option<String>,
) -> Result<ExportedJob, Failure> {
    let mut coordinator = Coordinator::connect(remote).await?;
    let job = coordinator.job(job_id).await?;
    let p = job.progress.clone().unwrap_or_default();
    let state: JobState = job.state.parse().map_err(|e| anyhow!("coordinator answered job {job_id}: {e}"))?;
    if state == JobState::Running {
        let done = p.tasks_succeeded + p.tasks_failed + p.tasks_cancelled;
        return Err(bad_input(anyhow!(
            "job {job_id} is still running ({done} of {} tasks so far done, {} samples packaged): export writes \
             a finished job's dataset; wait for it with `vintctl watch {job_id}`, then export",
            p.tasks_total,
            p.samples_packaged
        )));
    }
    if job.timing_only {
        return Err(bad_input(anyhow!(
            "job {job_id} was submitted with --timing-only: timing-only workers served it with stand-in files of \
             the right sizes, which are not data; export refuses it (submit the spec without --timing-only for a \
             dataset)"
        )));
    }
    let spec = vint_core::DatasetSpec::parse(&job.spec_toml).map_err(|e| {
        anyhow!("job {job_id}: its spec no longer parses ({e}); export it with the vintctl that ran it")
    })?;
    let store = artifact_store(&mut coordinator, store).await?;
    let listed = coordinator.samples(job_id).await?;
    let info = export::DatasetInfo { name: &spec.dataset.name, seed: spec.dataset.seed, split: &spec.split };
    let summary = export::export(&store, job_id, &info, &listed, out, target).await?;
    Ok(ExportedJob { job, state, planned: Some(spec.max_samples()), summary })
}

/// The artifact store to export from: `--store` when given, else the one the coordinator was
/// started with; refused, saying so, when neither names one this machine can read.
async fn artifact_store(coordinator: &mut Coordinator, flag: Option<String>) -> Result<ArtifactStore, Failure> {
    let url = match flag {
        Some(url) => url,
        None => {
            let info = coordinator.server_info().await?;
            if info.store_url.is_empty() {
                return Err(bad_input(anyhow!(
                    "export reads samples from the artifact store the workers wrote to, and the coordinator at {} \
                     was started without --store: pass --store URL (or set VINT_STORE), e.g. s3://bucket/prefix",
                    coordinator.url
                )));
            }
            if let Some(dir) = info.store_url.strip_prefix("file://")
                && !Path::new(dir).is_dir()
            {
                return Err(anyhow!(
                    "the coordinator's artifact store {} is not a directory on this machine (the coordinator runs \
                     elsewhere?): pass --store with a URL this machine can read",
                    info.store_url
                )
                .into());
            }
            info.store_url
        }
    };
    ArtifactStore::open(&url).map_err(|e| bad_input(anyhow!("--store {:?}: {e}", vint_telemetry::redact_url(&url))))
}
