//! How vintctl shows things: text for people, `--json` for scripts, a progress bar for waiting.

use anyhow::anyhow;
use futures::StreamExt;
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::{Value, json};
use tonic::transport::Channel;
use vint_proto::v1 as pb;
use vint_proto::v1::job_service_client::JobServiceClient;

use crate::Failure;
use crate::client::rpc_failure;
use crate::export::ExportSummary;

pub fn print_json(v: &Value) {
    println!("{}", serde_json::to_string_pretty(v).unwrap_or_else(|_| v.to_string()));
}

pub fn progress_json(p: &pb::JobProgress) -> Value {
    let stages: serde_json::Map<String, Value> = p
        .stages
        .iter()
        .map(|(k, s)| (k.clone(), json!({"total": s.total, "succeeded": s.succeeded, "failed": s.failed})))
        .collect();
    json!({
        "job_id": p.job_id, "state": p.state, "tasks_total": p.tasks_total, "tasks_succeeded": p.tasks_succeeded,
        "tasks_failed": p.tasks_failed, "tasks_running": p.tasks_running, "tasks_queued": p.tasks_queued,
        "tasks_waiting": p.tasks_waiting, "tasks_cancelled": p.tasks_cancelled,
        "samples_packaged": p.samples_packaged, "stages": stages,
    })
}

fn progress_line(p: &pb::JobProgress) -> String {
    let stages: Vec<String> = ["grasp", "render", "noise", "package"]
        .iter()
        .filter_map(|s| p.stages.get(*s).map(|st| format!("{s} {}/{}", st.succeeded, st.total)))
        .collect();
    format!(
        "{} samples · {} · running {} · failed {}",
        p.samples_packaged,
        stages.join(" · "),
        p.tasks_running,
        p.tasks_failed
    )
}

pub fn job(job: &pb::Job, json: bool) {
    let p = job.progress.clone().unwrap_or_default();
    if json {
        print_json(&json!({
            "job_id": job.job_id, "name": job.name, "state": job.state, "seed": job.seed,
            "created_ms": job.created_ms, "finished_ms": job.finished_ms, "progress": progress_json(&p),
        }));
    } else {
        println!("job {} ({}): {}", job.job_id, job.name, job.state);
        println!("  {}", progress_line(&p));
    }
}

pub fn jobs(jobs: &[pb::Job], json: bool) {
    if json {
        let list: Vec<Value> = jobs
            .iter()
            .map(|j| json!({"job_id": j.job_id, "name": j.name, "state": j.state, "created_ms": j.created_ms}))
            .collect();
        print_json(&Value::Array(list));
    } else {
        for j in jobs {
            let samples = j.progress.as_ref().map(|p| p.samples_packaged).unwrap_or(0);
            println!("{}  {:<10} {:<20} {} samples", j.job_id, j.state, j.name, samples);
        }
    }
}

/// Where `--json` progress lines go: stdout when they are the command's output (`watch`),
/// stderr when a final result follows on stdout (`run`).
#[derive(Clone, Copy, PartialEq, Eq)]
pub enum JsonProgress {
    Stdout,
    Stderr,
}

/// Streams a job's progress until it ends, as a progress bar (text) or JSON lines (`--json`).
pub async fn follow(
    client: &mut JobServiceClient<Channel>,
    job_id: &str,
    json: Option<JsonProgress>,
) -> Result<pb::JobProgress, Failure> {
    let mut stream = client
        .watch_job(pb::WatchJobRequest { job_id: job_id.into() })
        .await
        .map_err(|s| rpc_failure("watch", s))?
        .into_inner();
    let bar = if json.is_some() { ProgressBar::hidden() } else { ProgressBar::new(0) };
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} tasks  {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let mut last = None;
    while let Some(update) = stream.next().await {
        let p = update.map_err(|s| rpc_failure("watch", s))?;
        match json {
            Some(JsonProgress::Stdout) => println!("{}", progress_json(&p)),
            Some(JsonProgress::Stderr) => eprintln!("{}", progress_json(&p)),
            None => {}
        }
        bar.set_length(p.tasks_total);
        bar.set_position(p.tasks_succeeded + p.tasks_failed + p.tasks_cancelled);
        bar.set_message(progress_line(&p));
        last = Some(p);
    }
    bar.finish_and_clear();
    let last = last.ok_or_else(|| anyhow!("the coordinator closed the watch without any progress"))?;
    if json.is_none() {
        eprintln!("job {} {}: {}", last.job_id, last.state, progress_line(&last));
    }
    Ok(last)
}

pub fn lineage(l: &pb::Lineage, json: bool) {
    if json {
        let tasks: Vec<Value> = l
            .tasks
            .iter()
            .map(|t| {
                let art = |a: &pb::ArtifactRef| json!({"name": a.name, "sha256": a.sha256, "size": a.size, "task_key": a.task_key});
                json!({
                    "task_id": t.task_id, "key": t.key, "stage": t.stage, "state": t.state, "attempts": t.attempts,
                    "params": serde_json::from_str::<Value>(&t.params_json).unwrap_or(Value::Null),
                    "engine": serde_json::from_str::<Value>(&t.engine_json).unwrap_or(Value::Null),
                    "depends_on": t.depends_on,
                    "inputs": t.inputs.iter().map(art).collect::<Vec<_>>(),
                    "outputs": t.outputs.iter().map(art).collect::<Vec<_>>(),
                })
            })
            .collect();
        let files: Vec<Value> = l
            .user_files
            .iter()
            .map(|f| json!({"path": f.path, "sha256": f.sha256, "size": f.size, "media_type": f.media_type}))
            .collect();
        print_json(&json!({"job_id": l.job_id, "subject": l.subject, "user_files": files, "tasks": tasks}));
        return;
    }
    println!("lineage of {} (job {})", l.subject, l.job_id);
    for f in &l.user_files {
        println!("  submitted with the job as {} ({} B, {}); read by the tasks below", f.path, f.size, f.media_type);
    }
    for t in &l.tasks {
        let engine: Value = serde_json::from_str(&t.engine_json).unwrap_or(Value::Null);
        let libs = engine.get("libs").map(|v| v.to_string()).unwrap_or_default();
        println!("\n● {} [{}] {} — {} attempt(s)", t.key, t.stage, t.state, t.attempts);
        println!(
            "  engine: {} {} {}",
            engine.get("name").and_then(Value::as_str).unwrap_or("?"),
            engine.get("version").and_then(Value::as_str).unwrap_or("?"),
            libs
        );
        let params = match t.params_json.char_indices().nth(300) {
            Some((cut, _)) => format!("{}…", &t.params_json[..cut]),
            None => t.params_json.clone(),
        };
        println!("  params: {params}");
        for a in &t.inputs {
            println!("  in  {:<24} sha256:{} (from {})", a.name, a.sha256, a.task_key);
        }
        for a in &t.outputs {
            println!("  out {:<24} sha256:{} {} B", a.name, a.sha256, a.size);
        }
    }
}

pub fn export(s: &ExportSummary, json: bool) {
    if json {
        print_json(&serde_json::to_value(s).unwrap_or(Value::Null));
    } else {
        println!(
            "wrote {} samples ({} files, {} bytes) to {}\nmanifest.jsonl sha256 {}",
            s.samples,
            s.files,
            s.bytes,
            s.out.display(),
            s.manifest_sha256
        );
    }
}

/// `vintctl hands`: each built-in hand with its DoF and taxels per region.
pub fn hands(json: bool) {
    let hands = vint_core::catalog::hands();
    if json {
        print_json(&serde_json::to_value(hands).unwrap_or(Value::Null));
        return;
    }
    println!(
        "{:<10} {:>7} {:>4} {:>7} {:>5} {:>5} {:>5}  description",
        "hand", "fingers", "dof", "taxels", "tip", "pulp", "palm"
    );
    for h in hands {
        let region = |r: &str| h.taxels_per_region.get(r).copied().unwrap_or(0);
        println!(
            "{:<10} {:>7} {:>4} {:>7} {:>5} {:>5} {:>5}  {}",
            h.entry.name,
            h.entry.fingers,
            h.entry.dof,
            h.taxel_count(),
            region("tip"),
            region("pulp"),
            region("palm"),
            h.entry.description
        );
    }
}

/// `vintctl objects`: the built-in object catalog.
pub fn objects(json: bool) {
    let objects = vint_core::catalog::objects();
    if json {
        print_json(&serde_json::to_value(objects).unwrap_or(Value::Null));
        return;
    }
    println!(
        "{:<22} {:>5} {:>8} {:<10} {:<13} {:<9}  description",
        "object", "ycb", "mass kg", "material", "symmetry", "shape"
    );
    for o in objects {
        let shape = o.shape.kind();
        println!(
            "{:<22} {:>5} {:>8.3} {:<10} {:<13} {:<9}  {}",
            o.name, o.ycb_id, o.mass_kg, o.material, o.symmetry, shape, o.description
        );
    }
}
