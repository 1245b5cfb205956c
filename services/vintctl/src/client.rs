//! Commands that talk to a coordinator over gRPC (and `validate`, which talks to nobody).

use std::path::Path;

use anyhow::{Context, anyhow};
use tonic::Code;
use tonic::transport::Channel;
use vint_core::asset::{MAX_ASSET_BYTES, MAX_ASSETS_TOTAL_BYTES};
use vint_core::{DatasetSpec, SpecError, SpecErrors};
use vint_proto::v1 as pb;
use vint_proto::v1::get_lineage_request::Subject;
use vint_proto::v1::job_service_client::JobServiceClient;

use crate::report;
use crate::{CliResult, Failure, bad_input};

/// A spec as a submission carries it: its text, its parsed form and the user files it names.
pub struct LoadedSpec {
    pub text: String,
    pub spec: DatasetSpec,
    pub assets: Vec<pb::AssetFile>,
}

/// Reads and validates a spec and reads the files it names; every problem is reported and the
/// exit code is 2.
pub fn load_spec(path: &Path) -> Result<LoadedSpec, Failure> {
    let text = read_spec(path)?;
    let spec = DatasetSpec::parse(&text).map_err(|errors| invalid_spec(path, &errors))?;
    let assets = read_assets(path, &spec).map_err(|errors| invalid_spec(path, &errors))?;
    Ok(LoadedSpec { text, spec, assets })
}

/// The files the spec's own hands, objects and HDRIs name, read relative to the spec file's directory;
/// a missing, unreadable or oversized file is a spec error naming the field and the path.
fn read_assets(spec_path: &Path, spec: &DatasetSpec) -> Result<Vec<pb::AssetFile>, SpecErrors> {
    let base = spec_path.parent().unwrap_or(Path::new("."));
    let mut errors = Vec::new();
    let mut files: Vec<pb::AssetFile> = Vec::new();
    let mut total = 0u64;
    for used in spec.asset_uses() {
        if files.iter().any(|f| f.path == used.path) {
            continue;
        }
        let error = |rule: String, value: String| SpecError { path: used.field.clone(), value, rule };
        let file = base.join(&used.path);
        let size = match std::fs::metadata(&file) {
            Ok(m) if m.is_file() => m.len(),
            Ok(_) => {
                errors.push(error(
                    format!("must name a file ({} is not one)", file.display()),
                    format!("{:?}", used.path),
                ));
                continue;
            }
            Err(e) => {
                errors.push(error(
                    format!("must name a readable file ({}: {e})", file.display()),
                    format!("{:?}", used.path),
                ));
                continue;
            }
        };
        if size > MAX_ASSET_BYTES {
            errors.push(error(
                format!("must be a file of at most {MAX_ASSET_BYTES} bytes"),
                format!("{:?} ({size} bytes)", used.path),
            ));
            continue;
        }
        match std::fs::read(&file) {
            Ok(content) => {
                total += content.len() as u64;
                files.push(pb::AssetFile { path: used.path, content });
            }
            Err(e) => errors.push(error(
                format!("must name a readable file ({}: {e})", file.display()),
                format!("{:?}", used.path),
            )),
        }
    }
    if total > MAX_ASSETS_TOTAL_BYTES {
        errors.push(SpecError {
            path: String::new(),
            value: format!("{total} bytes"),
            rule: format!("the spec's files add up to {total} bytes, more than the limit of {MAX_ASSETS_TOTAL_BYTES}"),
        });
    }
    if errors.is_empty() { Ok(files) } else { Err(SpecErrors(errors)) }
}

fn read_spec(path: &Path) -> Result<String, Failure> {
    std::fs::read_to_string(path).with_context(|| format!("reading spec {}", path.display())).map_err(bad_input)
}

/// Every problem of an invalid spec, as one bad-input failure (exit code 2).
fn invalid_spec(path: &Path, errors: &SpecErrors) -> Failure {
    let n = errors.0.len();
    bad_input(anyhow!(
        "{} is not a valid spec ({n} problem{}):\n{errors}",
        path.display(),
        if n == 1 { "" } else { "s" }
    ))
}

pub fn validate(path: &Path, json: bool) -> CliResult {
    let text = read_spec(path)?;
    match DatasetSpec::parse(&text).and_then(|spec| read_assets(path, &spec).map(|_| spec)) {
        Ok(spec) => {
            if json {
                report::print_json(
                    &serde_json::json!({"valid": true, "spec": spec, "max_samples": spec.max_samples()}),
                );
            } else {
                println!(
                    "{}: valid — {} hand(s) × {} object(s) × {} trials × {} views: at most {} samples",
                    path.display(),
                    spec.hands.len(),
                    spec.objects.len(),
                    spec.grasp.trials_per_pair,
                    spec.render.views_per_grasp(),
                    spec.max_samples()
                );
            }
            Ok(())
        }
        Err(errors) => {
            if json {
                let list: Vec<_> = errors
                    .0
                    .iter()
                    .map(|e| serde_json::json!({"path": e.path, "value": e.value, "rule": e.rule, "message": e.to_string()}))
                    .collect();
                report::print_json(&serde_json::json!({"valid": false, "errors": list}));
            }
            Err(invalid_spec(path, &errors))
        }
    }
}

pub async fn connect(url: &str) -> Result<JobServiceClient<Channel>, Failure> {
    let endpoint = Channel::from_shared(url.to_string())
        .map_err(|e| bad_input(anyhow!("invalid coordinator URL {url:?}: {e}")))?
        .connect_timeout(std::time::Duration::from_secs(5));
    let channel = endpoint.connect().await.with_context(|| format!("connecting to coordinator {url}"))?;
    Ok(JobServiceClient::new(channel).max_decoding_message_size(64 << 20))
}

/// Maps "not found" and "invalid argument" answers to exit code 2.
pub fn rpc_failure(what: &str, s: tonic::Status) -> Failure {
    let error = anyhow!("{what}: {}", s.message());
    match s.code() {
        Code::NotFound | Code::InvalidArgument => bad_input(error),
        _ => Failure { code: 1, error },
    }
}

pub async fn submit(url: &str, path: &Path, key: Option<String>, json: bool) -> CliResult {
    let loaded = load_spec(path)?;
    let mut client = connect(url).await?;
    let request = pb::SubmitJobRequest {
        spec_toml: loaded.text,
        idempotency_key: key.unwrap_or_default(),
        assets: loaded.assets,
    };
    let resp = client.submit_job(request).await.map_err(|s| rpc_failure("submit", s))?.into_inner();
    let job = resp.job.ok_or_else(|| anyhow!("coordinator returned no job"))?;
    if json {
        report::print_json(&serde_json::json!({"job_id": job.job_id, "created": resp.created, "state": job.state}));
    } else {
        if !resp.created {
            eprintln!("this spec was already submitted (same idempotency key): returning that job");
        }
        println!("{}", job.job_id);
    }
    Ok(())
}

pub async fn status(url: &str, job: &str, json: bool) -> CliResult {
    let mut client = connect(url).await?;
    let job = client
        .get_job(pb::GetJobRequest { job_id: job.into() })
        .await
        .map_err(|s| rpc_failure("status", s))?
        .into_inner();
    report::job(&job, json);
    Ok(())
}

pub async fn jobs(url: &str, limit: u32, json: bool) -> CliResult {
    let mut client = connect(url).await?;
    let resp = client.list_jobs(pb::ListJobsRequest { limit }).await.map_err(|s| rpc_failure("jobs", s))?.into_inner();
    report::jobs(&resp.jobs, json);
    Ok(())
}

pub async fn cancel(url: &str, job: &str, json: bool) -> CliResult {
    let mut client = connect(url).await?;
    let job = client
        .cancel_job(pb::CancelJobRequest { job_id: job.into() })
        .await
        .map_err(|s| rpc_failure("cancel", s))?
        .into_inner();
    report::job(&job, json);
    Ok(())
}

/// Follows a job until it ends; exits 1 unless it succeeded.
pub async fn watch(url: &str, job: &str, json: bool) -> CliResult {
    let mut client = connect(url).await?;
    let last = report::follow(&mut client, job, json.then_some(report::JsonProgress::Stdout)).await?;
    job_outcome(&last)
}

/// Exit status of a finished job.
pub fn job_outcome(p: &pb::JobProgress) -> CliResult {
    match p.state.as_str() {
        "succeeded" => Ok(()),
        state => Err(Failure {
            code: 1,
            error: anyhow!(
                "job {} {state}: {} task(s) failed permanently, {} sample(s) packaged",
                p.job_id,
                p.tasks_failed,
                p.samples_packaged
            ),
        }),
    }
}

pub async fn lineage(url: &str, subject: &str, job: Option<String>, artifact: bool, json: bool) -> CliResult {
    let mut client = connect(url).await?;
    let subject = if artifact { Subject::ArtifactSha256(subject.into()) } else { Subject::SampleId(subject.into()) };
    let request = pb::GetLineageRequest { job_id: job.unwrap_or_default(), subject: Some(subject) };
    let lineage = client.get_lineage(request).await.map_err(|s| rpc_failure("lineage", s))?.into_inner();
    report::lineage(&lineage, json);
    Ok(())
}

pub async fn export(url: &str, job: &str, out: &Path, store: &str, json: bool) -> CliResult {
    let mut client = connect(url).await?;
    let store = vint_artifacts::ArtifactStore::open(store).map_err(|e| bad_input(e.into()))?;
    let summary = crate::export::export(&mut client, &store, job, out).await?;
    report::export(&summary, json);
    Ok(())
}
