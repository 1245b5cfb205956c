//! How vintctl shows things: text for people, `--json` for scripts, a progress bar for waiting.
//! Everything here takes data and prints it; nothing talks to a coordinator or writes datasets.

use std::collections::BTreeSet;
use std::sync::Mutex;

use chrono::{Local, TimeZone};
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::{Value, json};
use vint_core::{SpecError, SpecErrors, Stage};
use vint_proto::v1 as pb;

use crate::Failure;
use crate::estimate::{self, Estimate};
use crate::export::ExportSummary;

pub fn print_json(v: &Value) {
    println!("{}", serde_json::to_string_pretty(v).unwrap_or_else(|_| v.to_string()));
}

/// A failed command: the error on stderr, and with `--json` also as JSON on stdout — the
/// command's own report with an `error` member when it had one, `{"error": …}` otherwise — on
/// one line, so that it also ends `watch --json`'s JSON lines.
pub fn failure(f: &Failure, json: bool) {
    eprintln!("error: {:#}", f.error);
    if json {
        let mut doc = f.report().cloned().unwrap_or_else(|| json!({}));
        if let Value::Object(map) = &mut doc {
            map.insert("error".into(), error_json(f));
        }
        println!("{doc}");
    }
}

/// `{"message", "code"}`, and `errors` (field by field, as `validate --json`) for an invalid spec.
fn error_json(f: &Failure) -> Value {
    let mut error = json!({"message": format!("{:#}", f.error), "code": f.code});
    if let Some(errors) = f.spec_errors() {
        error["errors"] = spec_errors_json(errors);
    }
    error
}

pub fn spec_errors_json(errors: &SpecErrors) -> Value {
    let one = |e: &SpecError| json!({"path": e.path, "value": e.value, "rule": e.rule, "message": e.to_string()});
    Value::Array(errors.0.iter().map(one).collect())
}

/// `validate` of a valid spec: its size, what it would cost, and a warning when that is a lot.
pub fn valid_spec(path: &std::path::Path, spec: &vint_core::DatasetSpec, e: &Estimate) {
    let grasps = match spec.grasp.accepted_per_pair {
        Some(n) => format!("{n} accepted grasps (at most {} trials)", spec.grasp.trials_per_pair),
        None => format!("{} trials", spec.grasp.trials_per_pair),
    };
    println!(
        "{}: valid — {} hand(s) × {} object(s) × {grasps} × {} views: at most {} samples",
        path.display(),
        spec.hands.len(),
        spec.objects.len(),
        spec.render.views_per_grasp(),
        spec.max_samples()
    );
    let tasks: Vec<String> = e.stages.iter().map(|s| format!("{} {}", s.tasks, s.stage)).collect();
    let bound = if e.stages.iter().all(|s| s.tasks_exact) { "" } else { " (at most: every trial accepted)" };
    println!("  tasks: {}{bound}", tasks.join(", "));
    let cpu: Vec<String> =
        e.stages.iter().map(|s| format!("{} {}", s.stage, estimate::cpu_time(s.cpu_seconds))).collect();
    println!(
        "  rough cost if every trial is accepted: {} ({}), {} written",
        estimate::cpu_time(e.cpu_seconds),
        cpu.join(", "),
        estimate::size(e.output_bytes)
    );
    println!("  ({})", estimate::BASIS);
    for w in &e.warnings {
        eprintln!("warning: {w}");
    }
}

pub fn progress_json(p: &pb::JobProgress) -> Value {
    let stages: serde_json::Map<String, Value> = p
        .stages
        .iter()
        .map(|(k, s)| {
            (k.clone(), json!({"total": s.total, "succeeded": s.succeeded, "failed": s.failed, "reused": s.reused}))
        })
        .collect();
    json!({
        "job_id": p.job_id, "state": p.state, "tasks_total": p.tasks_total, "tasks_succeeded": p.tasks_succeeded,
        "tasks_failed": p.tasks_failed, "tasks_running": p.tasks_running, "tasks_queued": p.tasks_queued,
        "tasks_waiting": p.tasks_waiting, "tasks_cancelled": p.tasks_cancelled,
        "samples_packaged": p.samples_packaged, "stages": stages,
        "failed_tasks": failed_tasks_json(&p.failed_tasks),
    })
}

pub fn failed_tasks_json(tasks: &[pb::FailedTask]) -> Value {
    let one = |t: &pb::FailedTask| {
        json!({"key": t.key, "stage": t.stage, "attempts": t.attempts, "last_error": t.last_error,
               "failed_upstream": t.failed_upstream})
    };
    Value::Array(tasks.iter().map(one).collect())
}

fn progress_line(p: &pb::JobProgress) -> String {
    let stages: Vec<String> = Stage::ALL
        .iter()
        .map(|s| s.as_str())
        .filter_map(|s| {
            p.stages.get(s).map(|st| match st.reused {
                0 => format!("{s} {}/{}", st.succeeded, st.total),
                r => format!("{s} {}/{} ({r} reused)", st.succeeded, st.total),
            })
        })
        .collect();
    format!(
        "{} samples · {} · running {} · failed {}",
        p.samples_packaged,
        stages.join(" · "),
        p.tasks_running,
        p.tasks_failed
    )
}

/// Why tasks failed, a line each (root causes first, as the coordinator orders them), and how
/// many more there are; empty when none failed.
pub fn failed_task_lines(p: &pb::JobProgress) -> Vec<String> {
    let mut lines = Vec::new();
    for t in &p.failed_tasks {
        lines.push(format!("{} ({}, {}): {}", t.key, t.stage, attempts(t), t.last_error));
    }
    let more = p.tasks_failed.saturating_sub(p.failed_tasks.len() as u64);
    if more > 0 {
        lines.push(format!("… and {more} more (vintctl status --json lists the first {})", p.failed_tasks.len()));
    }
    lines
}

fn attempts(t: &pb::FailedTask) -> String {
    match t.attempts {
        _ if t.failed_upstream => "never ran".to_string(),
        1 => "1 attempt".to_string(),
        n => format!("{n} attempts"),
    }
}

/// A job's state and progress (`status`, `cancel`), with why its tasks failed.
pub fn job(job: &pb::Job, json: bool) {
    let p = job.progress.clone().unwrap_or_default();
    if json {
        print_json(&json!({
            "job_id": job.job_id, "name": job.name, "state": job.state, "seed": job.seed,
            "created_ms": job.created_ms, "finished_ms": job.finished_ms, "progress": progress_json(&p),
        }));
        return;
    }
    println!("job {} ({}): {}", job.job_id, job.name, job.state);
    println!("  created {}, {}", local_time(job.created_ms), took(job));
    println!("  {}", progress_line(&p));
    if p.tasks_failed > 0 {
        println!("  {} task(s) failed permanently:", p.tasks_failed);
        for line in failed_task_lines(&p) {
            println!("    {line}");
        }
    }
}

/// `jobs`: most recent first, with a header and times people read.
pub fn jobs(jobs: &[pb::Job], json: bool) {
    if json {
        let list: Vec<Value> = jobs
            .iter()
            .map(|j| {
                let p = j.progress.clone().unwrap_or_default();
                json!({"job_id": j.job_id, "name": j.name, "state": j.state, "created_ms": j.created_ms,
                       "finished_ms": j.finished_ms, "samples_packaged": p.samples_packaged,
                       "tasks_failed": p.tasks_failed})
            })
            .collect();
        print_json(&Value::Array(list));
        return;
    }
    if jobs.is_empty() {
        println!("no jobs yet (vintctl submit SPEC starts one)");
        return;
    }
    println!("{:<14} {:<10} {:<20} {:>8}  {:<19}  TOOK", "JOB", "STATE", "NAME", "SAMPLES", "CREATED");
    for j in jobs {
        let samples = j.progress.as_ref().map(|p| p.samples_packaged).unwrap_or(0);
        println!(
            "{:<14} {:<10} {:<20} {:>8}  {:<19}  {}",
            j.job_id,
            j.state,
            j.name,
            samples,
            local_time(j.created_ms),
            took(j)
        );
    }
}

/// Unix milliseconds as local wall-clock time, to the second.
fn local_time(ms: i64) -> String {
    match Local.timestamp_millis_opt(ms).single() {
        Some(t) => t.format("%Y-%m-%d %H:%M:%S").to_string(),
        None => format!("{ms} ms"),
    }
}

/// How long a finished job took, or how long a running one has been running.
fn took(j: &pb::Job) -> String {
    if j.finished_ms > 0 {
        format!("took {}", duration(j.finished_ms - j.created_ms))
    } else {
        format!("running for {}", duration(chrono::Utc::now().timestamp_millis() - j.created_ms))
    }
}

/// A duration as people say it: `850ms`, `42s`, `3m 05s`, `2h 10m`, `3d 4h`.
pub fn duration(ms: i64) -> String {
    let ms = ms.max(0);
    let s = ms / 1000;
    match s {
        0 => format!("{ms}ms"),
        1..=59 => format!("{s}s"),
        60..=3599 => format!("{}m {:02}s", s / 60, s % 60),
        3600..=86_399 => format!("{}h {:02}m", s / 3600, s % 3600 / 60),
        _ => format!("{}d {}h", s / 86_400, s % 86_400 / 3600),
    }
}

/// Where `--json` progress lines go: stdout when they are the command's output (`watch`),
/// stderr when a final result follows on stdout (`run`).
#[derive(Clone, Copy, PartialEq, Eq)]
pub enum JsonProgress {
    Stdout,
    Stderr,
}

/// How a job's progress is shown while it runs: a progress bar, or JSON lines with `--json`.
/// Text mode also prints each task that fails permanently as it happens (the ones that failed
/// themselves; the job's end lists the rest).
pub struct ProgressView {
    bar: ProgressBar,
    json: Option<JsonProgress>,
    reported: Mutex<BTreeSet<String>>,
}

impl ProgressView {
    pub fn new(json: Option<JsonProgress>) -> ProgressView {
        let bar = if json.is_some() { ProgressBar::hidden() } else { ProgressBar::new(0) };
        bar.set_style(
            ProgressStyle::with_template("{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} tasks  {msg}")
                .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        ProgressView { bar, json, reported: Mutex::default() }
    }

    pub fn show(&self, p: &pb::JobProgress) {
        match self.json {
            Some(JsonProgress::Stdout) => println!("{}", progress_json(p)),
            Some(JsonProgress::Stderr) => eprintln!("{}", progress_json(p)),
            None => self.report_new_failures(p),
        }
        self.bar.set_length(p.tasks_total);
        self.bar.set_position(p.tasks_succeeded + p.tasks_failed + p.tasks_cancelled);
        self.bar.set_message(progress_line(p));
    }

    fn report_new_failures(&self, p: &pb::JobProgress) {
        let Ok(mut reported) = self.reported.lock() else { return };
        for t in p.failed_tasks.iter().filter(|t| !t.failed_upstream) {
            if reported.insert(t.key.clone()) {
                // Above the bar, and in a log too (where the bar is hidden and `println` is not).
                self.bar.suspend(|| eprintln!("task {} failed ({}): {}", t.key, attempts(t), t.last_error));
            }
        }
    }

    /// The job ended: clear the bar and say how (text only; JSON lines already said it).
    pub fn finish(&self, last: &pb::JobProgress) {
        self.bar.finish_and_clear();
        if self.json.is_none() {
            eprintln!("job {} {}: {}", last.job_id, last.state, progress_line(last));
        }
    }
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
                    "reused_from": (!t.reused_from.is_empty()).then_some(&t.reused_from),
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
        print_json(&json!({
            "job_id": l.job_id, "subject": l.subject, "user_files": files, "tasks": tasks, "more_tasks": l.more_tasks,
        }));
        return;
    }
    println!("lineage of {} (job {})", l.subject, l.job_id);
    for f in &l.user_files {
        println!("  submitted with the job as {} ({} B, {}); read by the tasks below", f.path, f.size, f.media_type);
    }
    if l.more_tasks {
        println!("  (more tasks read it: the first {} by key are shown)", l.tasks.len());
    }
    for t in &l.tasks {
        let engine: Value = serde_json::from_str(&t.engine_json).unwrap_or(Value::Null);
        let libs = engine.get("libs").map(|v| v.to_string()).unwrap_or_default();
        match t.reused_from.as_str() {
            "" => println!("\n● {} [{}] {} — {} attempt(s)", t.key, t.stage, t.state, t.attempts),
            from => println!("\n● {} [{}] {} — reused from {from}, not run", t.key, t.stage, t.state),
        }
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

pub fn export_json(s: &ExportSummary) -> Value {
    serde_json::to_value(s).unwrap_or(Value::Null)
}

/// What an export wrote (text); `--json` callers print `export_json` inside their own report.
/// What ran and what was reused, per stage: `grasp 4 (4 reused) · render 12 (12 reused) · …`.
pub fn work_line(p: &pb::JobProgress) -> String {
    let stages: Vec<String> = Stage::ALL
        .iter()
        .map(|s| s.as_str())
        .filter_map(|s| {
            p.stages.get(s).map(|st| match st.reused {
                0 => format!("{s} {} ran", st.succeeded),
                r if r == st.succeeded => format!("{s} {r} reused"),
                r => format!("{s} {} ran, {r} reused", st.succeeded - r),
            })
        })
        .collect();
    format!("tasks: {}", stages.join(" · "))
}

pub fn export_text(s: &ExportSummary) {
    println!(
        "wrote {} samples ({} layout: {} files, {} bytes) to {}\nmanifest.jsonl sha256 {}",
        s.samples,
        s.format,
        s.files,
        s.bytes,
        s.out.display(),
        s.manifest_sha256
    );
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

/// `vintctl objects`: the built-in object catalog. `--json` prints the full entries (texture,
/// colours, `symmetries_continuous`, `symmetries_discrete` in BOP's form) with the BOP `obj_id`
/// an export gives each and the ycbv object it stands in for; the text lists them in short.
pub fn objects(json: bool) {
    use vint_core::catalog;
    let objects = catalog::objects();
    if json {
        let entries: Vec<Value> = objects
            .iter()
            .map(|o| {
                let mut entry = serde_json::to_value(o).unwrap_or(Value::Null);
                entry["obj_id"] = json!(catalog::obj_id(&o.name));
                entry["model_source"] = json!("procedural");
                entry["stand_in_for"] = json!(catalog::stand_in_for(o));
                entry
            })
            .collect();
        print_json(&Value::Array(entries));
        return;
    }
    println!(
        "{:<19} {:>6} {:>4} {:>4} {:>7} {:<9} {:<18} {:<18} {:<9}  description",
        "object", "obj_id", "ycb", "ycbv", "mass kg", "material", "texture", "symmetries", "shape"
    );
    for o in objects {
        let ycbv = catalog::stand_in_for(o).map(|s| s.obj_id.to_string()).unwrap_or_default();
        println!(
            "{:<19} {:>6} {:>4} {:>4} {:>7.3} {:<9} {:<18} {:<18} {:<9}  {}",
            o.name,
            catalog::obj_id(&o.name).map(|id| id.to_string()).unwrap_or_default(),
            o.ycb_id,
            ycbv,
            o.mass_kg,
            o.material,
            texture_summary(&o.texture),
            symmetry_summary(o),
            o.shape.kind(),
            o.description
        );
    }
}

/// `label+print`, `wood_grain z`, `panels`, …
fn texture_summary(t: &vint_core::contract::object::Texture) -> String {
    use vint_core::contract::object::{Texture, name_of};
    match t {
        Texture::Label { print: true, .. } | Texture::Panels { print: true } => format!("{}+print", t.kind()),
        Texture::WoodGrain { axis } => format!("{} {}", t.kind(), name_of(axis)),
        _ => t.kind().to_string(),
    }
}

/// `turns about z + 1`, `7 discrete`, `none`: the continuous axes, then how many discrete ones.
fn symmetry_summary(o: &vint_core::catalog::ObjectEntry) -> String {
    let axes: Vec<String> = o
        .symmetries_continuous
        .iter()
        .map(|c| match c.axis {
            [x, y, _] if x == 0.0 && y == 0.0 => "z".to_string(),
            [_, y, z] if y == 0.0 && z == 0.0 => "x".to_string(),
            [x, _, z] if x == 0.0 && z == 0.0 => "y".to_string(),
            a => format!("{a:?}"),
        })
        .collect();
    let discrete = o.symmetries_discrete.len();
    match (axes.is_empty(), discrete) {
        (true, 0) => "none".into(),
        (true, n) => format!("{n} discrete"),
        (false, 0) => format!("turns about {}", axes.join(",")),
        (false, n) => format!("turns about {} + {n}", axes.join(",")),
    }
}

/// A dashboard view's rows: with `json`, an array of objects keyed by column (raw values, times in
/// Unix ms); else an aligned table, times as local time and NULL as `-`.
pub fn dashboard(table: &pb::DashboardTable, json: bool) {
    if json {
        let rows: Vec<Value> = table
            .rows
            .iter()
            .map(|row| {
                let cells = table.columns.iter().zip(&row.values).map(|(c, v)| (c.clone(), dashboard_json(v)));
                Value::Object(cells.collect())
            })
            .collect();
        print_json(&Value::Array(rows));
        return;
    }
    if table.rows.is_empty() {
        println!("{}: no rows", table.view);
        return;
    }
    let cells: Vec<Vec<String>> = table
        .rows
        .iter()
        .map(|row| table.columns.iter().zip(&row.values).map(|(c, v)| dashboard_text(c, v)).collect())
        .collect();
    let header: Vec<String> = table.columns.iter().map(|c| c.to_uppercase()).collect();
    let widths: Vec<usize> = (0..header.len())
        .map(|i| cells.iter().map(|r| r[i].chars().count()).chain([header[i].len()]).max().unwrap_or(0))
        .collect();
    let line = |cells: &[String]| {
        let padded: Vec<String> = cells.iter().zip(&widths).map(|(c, w)| format!("{c:<w$}")).collect();
        println!("{}", padded.join("  ").trim_end());
    };
    line(&header);
    for row in &cells {
        line(row);
    }
}

fn dashboard_json(v: &pb::DashboardValue) -> Value {
    use pb::dashboard_value::Value as V;
    match &v.value {
        Some(V::Text(s)) => json!(s),
        Some(V::Integer(n)) => json!(n),
        Some(V::Real(x)) => json!(x),
        None => Value::Null,
    }
}

fn dashboard_text(column: &str, v: &pb::DashboardValue) -> String {
    use pb::dashboard_value::Value as V;
    match &v.value {
        Some(V::Text(s)) => s.clone(),
        Some(V::Integer(ms)) if column.ends_with("_ms") => local_time(*ms),
        Some(V::Integer(n)) => n.to_string(),
        Some(V::Real(x)) => format!("{x:.3}"),
        None => "-".to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn durations_read_as_people_say_them() {
        assert_eq!(duration(850), "850ms");
        assert_eq!(duration(42_400), "42s");
        assert_eq!(duration(185_000), "3m 05s");
        assert_eq!(duration(7_800_000), "2h 10m");
        assert_eq!(duration(100 * 3_600_000), "4d 4h");
        assert_eq!(duration(-5), "0ms");
    }

    #[test]
    fn failed_tasks_read_root_cause_first_and_count_the_rest() {
        let task = |key: &str, attempts, error: &str| pb::FailedTask {
            key: key.into(),
            stage: key.split('/').next().unwrap_or_default().into(),
            attempts,
            last_error: error.into(),
            failed_upstream: attempts == 0,
        };
        let p = pb::JobProgress {
            tasks_failed: 5,
            failed_tasks: vec![
                task("grasp/cup/gripper/c00000", 1, "engine: object.cup: not a closed surface"),
                task("render/cup/gripper/g000001", 3, "engine: out of memory"),
                task("package/cup/gripper/c00000", 0, "upstream task j1/render/cup/gripper/g000001 failed"),
            ],
            ..Default::default()
        };
        assert_eq!(
            failed_task_lines(&p),
            [
                "grasp/cup/gripper/c00000 (grasp, 1 attempt): engine: object.cup: not a closed surface",
                "render/cup/gripper/g000001 (render, 3 attempts): engine: out of memory",
                "package/cup/gripper/c00000 (package, never ran): upstream task j1/render/cup/gripper/g000001 failed",
                "… and 2 more (vintctl status --json lists the first 3)",
            ]
        );
    }
}
