//! vintctl as people and scripts meet it: failed jobs that say why, errors that say what to do,
//! JSON for every outcome, and exports that refuse what is not finished.

use std::path::{Path, PathBuf};

use serde_json::Value;
use vint_tests::*;

/// A spec whose object `cup` is a mesh the grasp engine rejects (an open surface, which the spec
/// validation cannot see), next to a built-in object that works: a job that fails for a parameter
/// reason and still packages samples.
fn broken_spec(dir: &Path) -> PathBuf {
    std::fs::create_dir_all(dir.join("assets")).unwrap();
    std::fs::write(dir.join("assets/open.obj"), "v 0 0 0\nv 0.05 0 0\nv 0 0.05 0\nv 0 0 0.05\nf 1 2 3\nf 1 2 4\n")
        .unwrap();
    let spec = dir.join("broken.toml");
    std::fs::write(
        &spec,
        r#"hands = ["trx3"]
objects = ["cup", "tomato_soup_can"]

[object.cup]
mesh = "assets/open.obj"
unit = "m"
mass_kg = 0.15
material = "ceramic"

[dataset]
name = "broken"
seed = 3

[grasp]
trials_per_pair = 2
chunk_size = 1
hold_s = 0.5

[render]
resolution = [32, 32]
samples = 1
views_per_environment = 1

[outputs]
modalities = ["depth", "mask"]
"#,
    )
    .unwrap();
    spec
}

fn json_of(text: &str) -> Value {
    serde_json::from_str(text).unwrap_or_else(|e| panic!("not JSON ({e}):\n{text}"))
}

/// The failed tasks of the broken spec, as a JSON list: both chunks of the mesh object, each with
/// the engine's message.
fn assert_cup_grasps_failed_with_the_engines_message(failed: &Value) {
    let failed = failed.as_array().unwrap_or_else(|| panic!("failed_tasks is not a list: {failed}"));
    let keys: Vec<&str> = failed.iter().map(|t| t["key"].as_str().unwrap()).collect();
    assert_eq!(keys, ["grasp/cup/trx3/c00000", "grasp/cup/trx3/c00001"], "{failed:#?}");
    for t in failed {
        assert_eq!((t["stage"].as_str(), t["attempts"].as_u64()), (Some("grasp"), Some(1)), "{t}");
        assert_eq!(t["failed_upstream"], false);
        let error = t["last_error"].as_str().unwrap();
        assert!(error.starts_with("engine: ") && error.contains("'open.obj'"), "not the engine's message: {error}");
    }
}

#[test]
fn a_failed_job_names_each_failed_task_and_its_error_in_run_status_watch_and_export() {
    let tmp = tempfile::tempdir().unwrap();
    let spec = broken_spec(tmp.path());
    let (state, out) = (tmp.path().join("state"), tmp.path().join("out"));
    let (spec_arg, state_arg) = (spec.to_str().unwrap(), state.to_str().unwrap());

    // run --json: one document with the export, the job's end and why it failed; exit 1.
    let run = vintctl(&["--json", "run", spec_arg, "--out", out.to_str().unwrap(), "--state", state_arg]);
    assert_eq!(run.status.code(), Some(1), "{}\n{}", stdout(&run), stderr(&run));
    let doc = json_of(&stdout(&run));
    assert_eq!(doc["state"], "failed");
    assert_eq!((doc["tasks_failed"].as_u64(), doc["error"]["code"].as_u64()), (Some(2), Some(1)));
    assert_cup_grasps_failed_with_the_engines_message(&doc["failed_tasks"]);
    assert_eq!(doc["samples"].as_u64().unwrap() as usize, verify_dataset(&out).len(), "what was packaged is exported");
    let job = doc["job_id"].as_str().unwrap().to_string();

    // run (text), again on the same state: the same finished job, its failed tasks named.
    let again = vintctl(&["run", spec_arg, "--out", tmp.path().join("out2").to_str().unwrap(), "--state", state_arg]);
    assert_eq!(again.status.code(), Some(1));
    let text = stderr(&again);
    assert!(text.contains(&format!("job {job} failed: 2 task(s) failed permanently")), "{text}");
    assert!(text.contains("\n  grasp/cup/trx3/c00000 (grasp, 1 attempt): engine: "), "{text}");
    assert!(text.contains("'open.obj'"), "{text}");
    assert!(text.contains("task grasp/cup/trx3/c00000 failed (1 attempt): engine: "), "as it happens: {text}");

    // The job's database and artifacts, served by a coordinator (given without http://).
    let port = free_port();
    let database = format!("sqlite://{}", state.join("vint.db").display());
    let objects = format!("file://{}", state.canonicalize().unwrap().join("objects").display());
    let _coordinator = start_coordinator_with_store(&database, port, &tmp.path().join("logs"), "c", Some(&objects));
    let at = format!("127.0.0.1:{port}");
    let status = vintctl(&["--coordinator", &at, "status", &job, "--json"]);
    assert!(status.status.success(), "{}", stderr(&status));
    let status = json_of(&stdout(&status));
    assert_eq!(status["state"], "failed");
    assert_cup_grasps_failed_with_the_engines_message(&status["progress"]["failed_tasks"]);
    let text = stdout(&vintctl(&["--coordinator", &at, "status", &job]));
    assert!(
        text.contains("2 task(s) failed permanently:\n    grasp/cup/trx3/c00000 (grasp, 1 attempt): engine: "),
        "{text}"
    );

    let watch = vintctl(&["--coordinator", &at, "watch", &job]);
    assert_eq!(watch.status.code(), Some(1));
    assert!(stderr(&watch).contains("grasp/cup/trx3/c00001 (grasp, 1 attempt): engine: "), "{}", stderr(&watch));
    // watch --json: JSON lines, progress first, the error last.
    let watch = vintctl(&["--coordinator", &at, "--json", "watch", &job]);
    assert_eq!(watch.status.code(), Some(1));
    let lines: Vec<Value> = stdout(&watch).lines().map(json_of).collect();
    assert_cup_grasps_failed_with_the_engines_message(&lines[0]["failed_tasks"]);
    assert_eq!(lines.last().unwrap()["error"]["code"], 1);

    // jobs: a header and people's times.
    let jobs = stdout(&vintctl(&["--coordinator", &at, "jobs"]));
    let mut rows = jobs.lines();
    let header = rows.next().unwrap();
    assert!(["JOB", "STATE", "NAME", "SAMPLES", "CREATED", "TOOK"].iter().all(|h| header.contains(h)), "{jobs}");
    let row = rows.next().unwrap();
    assert!(row.starts_with(&job) && row.contains("failed") && row.contains("took "), "{jobs}");

    // export learns the store from the coordinator, writes what was packaged, says what is not.
    let exported = tmp.path().join("exported");
    let export = vintctl(&["--coordinator", &at, "export", &job, "--out", exported.to_str().unwrap()]);
    assert!(export.status.success(), "{}", stderr(&export));
    assert_eq!(manifest_sha256(&exported), manifest_sha256(&out));
    let note = stderr(&export);
    assert!(note.contains(&format!("job {job} failed")) && note.contains("of at most 4"), "{note}");
}

#[test]
fn export_refuses_a_running_job_and_says_where_the_store_must_come_from() {
    let tmp = tempfile::tempdir().unwrap();
    let port = free_port();
    let database = format!("sqlite://{}", tmp.path().join("c.db").display());
    let _coordinator = start_coordinator(&database, port, &tmp.path().join("logs"), "c");
    // No scheme, from the environment; no workers, so the job stays running.
    let env = [("VINT_COORDINATOR".to_string(), format!("127.0.0.1:{port}"))];
    let ctl = |args: &[&str]| vintctl_with_env(args, &env);
    let submitted = ctl(&["submit", tiny_spec().to_str().unwrap()]);
    assert!(submitted.status.success(), "{}", stderr(&submitted));
    let job = stdout(&submitted).trim().to_string();
    let out = tmp.path().join("out");

    let refused = ctl(&["export", &job, "--out", out.to_str().unwrap()]);
    assert_eq!(refused.status.code(), Some(2), "{}", stderr(&refused));
    assert!(stderr(&refused).contains(&format!("job {job} is still running")), "{}", stderr(&refused));
    assert!(stderr(&refused).contains(&format!("vintctl watch {job}")), "{}", stderr(&refused));
    assert!(!out.exists(), "nothing may be written for an unfinished job");
    let refused = ctl(&["--json", "export", &job, "--out", out.to_str().unwrap()]);
    assert_eq!(refused.status.code(), Some(2));
    let error = &json_of(&stdout(&refused))["error"];
    assert_eq!(error["code"], 2);
    assert!(error["message"].as_str().unwrap().contains("still running"), "{error}");
    assert!(stdout(&ctl(&["jobs"])).contains("running for "));

    // Cancelled is final: export what there is, from a store the coordinator does not have.
    assert!(ctl(&["cancel", &job]).status.success());
    let no_store = ctl(&["export", &job, "--out", out.to_str().unwrap()]);
    assert_eq!(no_store.status.code(), Some(2));
    assert!(stderr(&no_store).contains("was started without --store: pass --store URL"), "{}", stderr(&no_store));
    let store = format!("file://{}", tmp.path().join("objects").display());
    let exported = ctl(&["export", &job, "--out", out.to_str().unwrap(), "--store", &store]);
    assert!(exported.status.success(), "{}", stderr(&exported));
    assert!(verify_dataset(&out).is_empty());
    assert!(stderr(&exported).contains(&format!("job {job} cancelled")), "{}", stderr(&exported));
}

#[test]
fn an_unreachable_coordinator_says_what_was_tried_and_what_to_do() {
    let url = format!("http://127.0.0.1:{}", free_port());
    let o = vintctl(&["--coordinator", &url, "status", "j1"]);
    assert_eq!(o.status.code(), Some(1));
    let text = stderr(&o);
    for hint in [url.as_str(), "vint-coordinator", "--coordinator", "VINT_COORDINATOR", "vintctl run"] {
        assert!(text.contains(hint), "{hint:?} missing from:\n{text}");
    }
    assert_eq!(text.to_lowercase().matches("refused").count(), 1, "the cause, once:\n{text}");
    let o = vintctl(&["--coordinator", &url, "--json", "jobs"]);
    assert_eq!(o.status.code(), Some(1));
    let doc = json_of(&stdout(&o));
    assert_eq!(doc["error"]["code"], 1);
    assert!(doc["error"]["message"].as_str().unwrap().contains(&url));
}

#[test]
fn a_coordinator_url_with_another_scheme_is_bad_input() {
    for url in ["ftp://127.0.0.1:7700", "grpc://127.0.0.1:7700", "http://"] {
        let o = vintctl(&["--coordinator", url, "jobs"]);
        assert_eq!(o.status.code(), Some(2), "{url}: {}", stderr(&o));
        assert!(stderr(&o).contains(&format!("got {url:?}")), "{}", stderr(&o));
    }
}

#[test]
fn with_json_every_error_is_json_on_stdout_with_the_same_exit_code() {
    let tmp = tempfile::tempdir().unwrap();
    let bad = tmp.path().join("bad.toml");
    let tiny = std::fs::read_to_string(tiny_spec()).unwrap();
    std::fs::write(&bad, tiny.replace("resolution = [128, 128]", "resolution = [0, 128]").replace("hold_s", "hold"))
        .unwrap();
    let out = tmp.path().join("out");
    let run = vintctl(&["--json", "run", bad.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert_eq!(run.status.code(), Some(2));
    let error = &json_of(&stdout(&run))["error"];
    assert_eq!(error["code"], 2);
    let paths: Vec<&str> = error["errors"].as_array().unwrap().iter().map(|e| e["path"].as_str().unwrap()).collect();
    assert_eq!(paths, ["grasp.hold", "render.resolution[0]"]);
    assert!(error["errors"][0]["rule"].as_str().unwrap().contains("did you mean `hold_s`?"), "{error}");

    let validate = vintctl(&["validate", bad.to_str().unwrap(), "--json"]);
    assert_eq!(validate.status.code(), Some(2));
    let doc = json_of(&stdout(&validate));
    assert_eq!(
        (doc["valid"].as_bool(), doc["errors"][1]["path"].as_str()),
        (Some(false), Some("render.resolution[0]"))
    );
    assert_eq!(doc["error"]["code"], 2);

    for args in [&["--json", "status"][..], &["--json", "frobnicate"], &["--json"]] {
        let o = vintctl(args);
        assert_eq!(o.status.code(), Some(2), "{args:?}");
        let doc = json_of(&stdout(&o));
        assert_eq!(doc["error"]["code"], 2, "{args:?}");
    }
}

/// A spec valid field by field whose product is huge (4 objects × 2 hands × 10⁶ trials in chunks
/// of one: 8·10⁶ grasp tasks) is refused by validate, plan and a coordinator before anything is
/// planned or stored, each limit named with its count and the flag that raises it.
#[test]
fn a_spec_over_the_limits_is_refused_before_it_is_planned_naming_the_limit_and_its_flag() {
    let tmp = tempfile::tempdir().unwrap();
    let spec = tmp.path().join("huge.toml");
    std::fs::write(
        &spec,
        "hands = [\"trx3\", \"allegro\"]\nobjects = [\"mug\", \"bowl\", \"banana\", \"sugar_box\"]\n\
         [dataset]\nname = \"huge\"\nseed = 1\n[grasp]\ntrials_per_pair = 1000000\nchunk_size = 1\n",
    )
    .unwrap();
    let spec = spec.to_str().unwrap();
    for command in ["validate", "plan"] {
        let o = vintctl(&[command, spec]);
        assert_eq!(o.status.code(), Some(2), "{command}: {}", stderr(&o));
        let text = stderr(&o);
        assert!(text.contains("tasks per job") && text.contains("--max-tasks-per-job"), "{command}: {text}");
    }
    let o = vintctl(&["--json", "validate", spec]);
    let over = &json_of(&stdout(&o))["over_limits"];
    assert!(over.as_array().is_some_and(|o| o.iter().any(|l| l["flag"] == "--max-tasks-per-job")), "{over}");
    let raised = ["--max-tasks-per-job", "100000000", "--max-samples-per-job", "1000000000"];
    let o = vintctl(&[&["validate", spec][..], &raised[..]].concat());
    assert!(o.status.success(), "raised limits: {}", stderr(&o));

    let port = free_port();
    let database = format!("sqlite://{}", tmp.path().join("c.db").display());
    let _coordinator = start_coordinator(&database, port, &tmp.path().join("logs"), "c");
    let o = vintctl(&["submit", spec, "--coordinator", &format!("http://127.0.0.1:{port}")]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    let text = stderr(&o);
    assert!(text.contains("over this coordinator's limits") && text.contains("--max-tasks-per-job"), "{text}");
    let jobs = vintctl(&["--json", "jobs", "--coordinator", &format!("http://127.0.0.1:{port}")]);
    assert!(!stdout(&jobs).contains("huge"), "a refused spec left a job: {}", stdout(&jobs));
}

/// `--out` holding a file named `manifest.jsonl` that vint did not write (a common name in ML
/// datasets) is refused before anything runs, and nothing in it is touched.
#[test]
fn run_and_convert_refuse_an_out_directory_that_is_not_a_vint_dataset_and_delete_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("captions");
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("manifest.jsonl"), "{\"image\": \"a.jpg\", \"caption\": \"a mug\"}\n").unwrap();
    std::fs::write(out.join("data.txt"), "precious").unwrap();
    let native = dir.path().join("native");
    std::fs::create_dir_all(&native).unwrap();
    for args in [
        vec![
            "run",
            tiny_spec().to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--state",
            dir.path().join("state").to_str().unwrap(),
        ],
        vec!["convert", native.to_str().unwrap(), "--out", out.to_str().unwrap(), "--format", "bop"],
    ] {
        let o = vintctl(&args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
        let text = stderr(&o);
        assert!(text.contains("refusing to replace it") && text.contains("nothing was changed"), "{args:?}: {text}");
        assert_eq!(std::fs::read_to_string(out.join("data.txt")).unwrap(), "precious");
        assert!(out.join("manifest.jsonl").exists());
    }
}

#[test]
fn bare_vintctl_shows_how_to_start() {
    let o = vintctl(&[]);
    assert_eq!(o.status.code(), Some(2));
    let text = stderr(&o);
    for line in
        ["vintctl run examples/tiny.toml --out out/tiny", "vintctl validate", "vintctl submit", "VINT_COORDINATOR"]
    {
        assert!(text.contains(line), "{line:?} missing from:\n{text}");
    }
}

#[test]
fn validate_says_what_a_spec_would_cost_and_warns_when_it_is_a_lot() {
    let ok = vintctl(&["validate", tiny_spec().to_str().unwrap()]);
    assert!(ok.status.success());
    assert!(stdout(&ok).contains("tasks: 6 grasp,") && stdout(&ok).contains("rough"), "{}", stdout(&ok));
    assert!(!stderr(&ok).contains("warning"), "{}", stderr(&ok));
    let doc = json_of(&stdout(&vintctl(&["validate", tiny_spec().to_str().unwrap(), "--json"])));
    assert_eq!(doc["estimate"]["samples_max"], 72);

    let tmp = tempfile::tempdir().unwrap();
    let huge = tmp.path().join("huge.toml");
    let tiny = std::fs::read_to_string(tiny_spec()).unwrap();
    std::fs::write(&huge, tiny.replace("trials_per_pair = 2", "trials_per_pair = 100000")).unwrap();
    let o = vintctl(&["validate", huge.to_str().unwrap()]);
    assert!(o.status.success(), "a large spec is valid: {}", stderr(&o));
    assert!(stderr(&o).contains("CPU-days of compute (more than 1 CPU-day)"), "{}", stderr(&o));
    assert!(stderr(&o).contains("(more than 100 GB)"), "{}", stderr(&o));
}
