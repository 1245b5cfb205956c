//! Task reuse by content, as a researcher tuning a dataset meets it: change one knob of a finished
//! job's spec and only what depends on it runs again (`vintctl run` over one state directory).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use vint_core::Stage;
use vint_tests::*;

/// What happened to each stage's tasks in a job: (ran, reused), where "ran" means at least one
/// attempt row and "reused" means completed from another task's result with none.
type Work = BTreeMap<Stage, (u32, u32)>;

/// The jobs of a state directory, newest last, with what each did per stage.
async fn jobs_work(state: &Path) -> Vec<(String, Work)> {
    let url = format!("sqlite://{}", state.join("vint.db").display());
    let store = vint_store::Store::open(&url, vint_store::RetryPolicy::default()).await.unwrap();
    let mut jobs = store.list_jobs(100).await.unwrap();
    jobs.sort_by_key(|j| j.created_ms);
    let mut out = Vec::new();
    for job in jobs {
        let mut work = Work::new();
        for task in store.tasks_of_job(&job.id).await.unwrap() {
            assert_eq!(task.state, vint_core::TaskState::Succeeded, "{}", task.id);
            let attempts = store.attempt_count(&task.id).await.unwrap();
            let entry = work.entry(task.stage).or_default();
            match &task.reused_from {
                Some(from) => {
                    assert_eq!(attempts, 0, "{}: reused from {from}, yet it has attempts", task.id);
                    assert_ne!(from, &task.id);
                    entry.1 += 1;
                }
                None => {
                    assert!(attempts >= 1, "{}: neither ran nor reused", task.id);
                    entry.0 += 1;
                }
            }
        }
        out.push((job.id, work));
    }
    store.close().await;
    out
}

fn write_spec(dir: &Path, name: &str, edit: impl Fn(String) -> String) -> PathBuf {
    let text = edit(std::fs::read_to_string(tiny_spec()).unwrap());
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

fn run(spec: &Path, out: &Path, state: &Path, env: &[(String, String)]) -> serde_json::Value {
    let args = ["--json", "run", s(spec), "--out", s(out), "--state", s(state), "--workers", "2"];
    let o = vintctl_with_env(&args, env);
    assert!(o.status.success(), "vintctl run {}:\n{}\n{}", spec.display(), stdout(&o), stderr(&o));
    serde_json::from_str(&stdout(&o)).expect("--json summary")
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn ran(work: &Work, stage: Stage) -> u32 {
    work.get(&stage).map_or(0, |w| w.0)
}

fn reused(work: &Work, stage: Stage) -> u32 {
    work.get(&stage).map_or(0, |w| w.1)
}

/// The engines package, its lock and the catalog, copied as the repository lays them out.
fn copy_engines(dest: &Path) -> PathBuf {
    let engines = dest.join("workers").join("engines");
    copy_tree(&repo_root().join("workers/engines/vint_engines"), &engines.join("vint_engines"));
    std::fs::copy(repo_root().join("workers/engines/requirements.lock"), engines.join("requirements.lock")).unwrap();
    copy_tree(&repo_root().join("catalog"), &dest.join("catalog"));
    engines
}

fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let name = entry.file_name();
        if name == "__pycache__" {
            continue;
        }
        if entry.file_type().unwrap().is_dir() {
            copy_tree(&entry.path(), &to.join(&name));
        } else {
            std::fs::copy(entry.path(), to.join(&name)).unwrap();
        }
    }
}

#[tokio::test(flavor = "multi_thread")]
async fn one_changed_knob_reruns_only_what_depends_on_it() {
    let tmp = tempfile::tempdir().unwrap();
    let state = tmp.path().join("state");
    let base = tiny_spec();
    run(&base, &tmp.path().join("out0"), &state, &[]);
    let jobs = jobs_work(&state).await;
    let (first, work) = &jobs[0];
    assert!(work.values().all(|(_, reused)| *reused == 0), "nothing to reuse in a fresh state: {work:?}");

    // One noise parameter changed: the forecast says what will run and why, ...
    let noisier = write_spec(tmp.path(), "noisier.toml", |t| t.replace("sigma_scale = 1.0", "sigma_scale = 1.5"));
    let o = vintctl(&["--json", "plan", s(&noisier), "--against", first, "--state", s(&state)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let forecast: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let stage = |name: &str| forecast["stages"][name].clone();
    assert_eq!(stage("grasp")["reused"], stage("grasp")["planned"], "{forecast}");
    assert_eq!(stage("grasp")["run"], 0, "{forecast}");
    assert_eq!(stage("render")["run"], 0, "{forecast}");
    assert_eq!(stage("render")["reused"].as_u64(), Some(u64::from(ran(work, Stage::Render))), "{forecast}");
    assert_eq!(stage("noise")["reused"], 0, "{forecast}");
    assert_eq!(
        stage("noise")["reasons"]["parameter noise.sigma_scale changed"].as_u64(),
        Some(u64::from(ran(work, Stage::Noise))),
        "{forecast}"
    );
    assert_eq!(stage("package")["reasons"]["its noise task runs"], stage("package")["run"], "{forecast}");
    let text = vintctl(&["plan", s(&noisier), "--against", first, "--state", s(&state)]);
    assert!(stdout(&text).contains("parameter noise.sigma_scale changed"), "{}", stdout(&text));

    // ... and the run does exactly that: no grasp or render task runs, noise and package do.
    let summary = run(&noisier, &tmp.path().join("out1"), &state, &[]);
    let jobs = jobs_work(&state).await;
    let (_, work1) = &jobs[1];
    assert_eq!(ran(work1, Stage::Grasp) + ran(work1, Stage::Render), 0, "{work1:?}");
    assert_eq!(reused(work1, Stage::Grasp), ran(work, Stage::Grasp), "{work1:?}");
    assert_eq!(reused(work1, Stage::Render), ran(work, Stage::Render), "{work1:?}");
    assert_eq!((ran(work1, Stage::Noise), reused(work1, Stage::Noise)), (ran(work, Stage::Noise), 0), "{work1:?}");
    assert_eq!(ran(work1, Stage::Package), ran(work, Stage::Package), "{work1:?}");
    assert_eq!(summary["stages"]["render"]["reused"].as_u64(), Some(u64::from(ran(work, Stage::Render))));
    // The dataset is the one a fresh run of the changed spec makes (on this machine, byte for byte).
    let fresh = tmp.path().join("fresh");
    run(&noisier, &fresh.join("out"), &fresh.join("state"), &[]);
    assert_eq!(manifest_sha256(&tmp.path().join("out1")), manifest_sha256(&fresh.join("out")));
    assert_ne!(manifest_sha256(&tmp.path().join("out0")), manifest_sha256(&tmp.path().join("out1")));

    // One object added: only its tasks run.
    let more = write_spec(tmp.path(), "more.toml", |t| {
        t.replace("sigma_scale = 1.0", "sigma_scale = 1.5").replace(
            r#"objects = ["tomato_soup_can", "mustard_bottle", "mug"]"#,
            r#"objects = ["tomato_soup_can", "mustard_bottle", "mug", "banana"]"#,
        )
    });
    run(&more, &tmp.path().join("out2"), &state, &[]);
    let jobs = jobs_work(&state).await;
    let (job2, work2) = &jobs[2];
    let url = format!("sqlite://{}", state.join("vint.db").display());
    let store = vint_store::Store::open(&url, vint_store::RetryPolicy::default()).await.unwrap();
    for task in store.tasks_of_job(job2).await.unwrap() {
        let new = task.key.contains("/banana/");
        assert_eq!(task.reused_from.is_none(), new, "{}: only the new object's tasks run", task.key);
    }
    store.close().await;
    assert!(ran(work2, Stage::Grasp) >= 2 && reused(work2, Stage::Grasp) == ran(work, Stage::Grasp), "{work2:?}");

    // A changed engine identity re-runs its stage: a comment added to the noise model's code
    // changes the noise engine's identity. Its outputs come out byte-identical, so (early cutoff)
    // the package tasks after it are reused all the same.
    let engines = copy_engines(&tmp.path().join("edited"));
    let model = engines.join("vint_engines/noise/model.py");
    let code = std::fs::read_to_string(&model).unwrap();
    std::fs::write(&model, format!("{code}\n# an edit that changes no output\n")).unwrap();
    let again = write_spec(tmp.path(), "again.toml", |t| {
        t.replace("sigma_scale = 1.0", "sigma_scale = 1.5")
            .replace(r#"objects = ["tomato_soup_can", "mustard_bottle", "mug"]"#, r#"objects = ["tomato_soup_can", "mustard_bottle", "mug", "banana"]"#)
            // The same spec once more, as a new job (its text, so its idempotency key, differs).
            + "\n# submitted again\n"
    });
    let env = [("VINT_ENGINES_DIR".to_string(), s(&engines).to_string())];
    run(&again, &tmp.path().join("out3"), &state, &env);
    let jobs = jobs_work(&state).await;
    let (_, work3) = &jobs[3];
    let noise_tasks = ran(work2, Stage::Noise) + reused(work2, Stage::Noise);
    assert_eq!((ran(work3, Stage::Noise), reused(work3, Stage::Noise)), (noise_tasks, 0), "{work3:?}");
    assert_eq!(ran(work3, Stage::Grasp) + ran(work3, Stage::Render) + ran(work3, Stage::Package), 0, "{work3:?}");
    assert_eq!(manifest_sha256(&tmp.path().join("out3")), manifest_sha256(&tmp.path().join("out2")));
}

#[tokio::test(flavor = "multi_thread")]
async fn gc_deletes_only_what_no_job_references() {
    let tmp = tempfile::tempdir().unwrap();
    let state = tmp.path().join("state");
    let spec = repo_root().join("benches/smoke.toml");
    run(&spec, &tmp.path().join("out"), &state, &[]);
    let objects = vint_artifacts::ArtifactStore::open(&format!("file://{}", state.join("objects").display())).unwrap();
    let before = objects.count_objects().await.unwrap();
    // An upload whose completion never landed: in the store, in no job.
    let orphan = objects.put_bytes(bytes::Bytes::from_static(b"outputs of a lost lease")).await.unwrap();

    let gc = |extra: &[&str]| {
        let mut args = vec!["--json", "gc", "--state", s(&state)];
        args.extend_from_slice(extra);
        let o = vintctl(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        serde_json::from_str::<serde_json::Value>(&stdout(&o)).unwrap()
    };
    // A fresh object may be a completion in flight: kept by default.
    let young = gc(&[]);
    assert_eq!((young["collected"].as_u64(), young["kept_young"].as_u64()), (Some(0), Some(1)), "{young}");
    let dry = gc(&["--min-age-s", "0", "--dry-run"]);
    assert_eq!(dry["collected"], 1, "{dry}");
    assert_eq!(objects.count_objects().await.unwrap(), before + 1, "a dry run deletes nothing");
    let done = gc(&["--min-age-s", "0"]);
    assert_eq!((done["collected"].as_u64(), done["referenced"].as_u64()), (Some(1), Some(before as u64)), "{done}");
    assert!(objects.get(&orphan.sha256).await.is_err(), "the orphan is gone");
    assert_eq!(objects.count_objects().await.unwrap(), before);
    // Everything a job references is still there: the finished job exports again, file by file.
    run(&spec, &tmp.path().join("again"), &state, &[]);
    verify_dataset(&tmp.path().join("again"));

    // Deleting the job (the state's only one) leaves its objects referenced by nothing: gc takes all.
    let jobs = jobs_work(&state).await;
    assert_eq!(jobs.len(), 1);
    let job = jobs[0].0.clone();
    let delete = |extra: &[&str]| {
        let mut args = vec!["--json", "delete", job.as_str(), "--state", s(&state)];
        args.extend_from_slice(extra);
        vintctl(&args)
    };
    let dry = delete(&["--dry-run"]);
    assert!(dry.status.success(), "{}", stderr(&dry));
    let counted: serde_json::Value = serde_json::from_str(&stdout(&dry)).unwrap();
    assert!(counted["tasks"].as_u64().is_some_and(|n| n > 0) && counted["dry_run"] == true, "{counted}");
    assert_eq!(jobs_work(&state).await.len(), 1, "a dry run deletes nothing");
    let done = delete(&[]);
    assert!(done.status.success(), "{}", stderr(&done));
    let deleted: serde_json::Value = serde_json::from_str(&stdout(&done)).unwrap();
    assert_eq!(
        (deleted["tasks"].clone(), deleted["attempts"].clone()),
        (counted["tasks"].clone(), counted["attempts"].clone())
    );
    assert!(jobs_work(&state).await.is_empty());
    let again = delete(&[]);
    assert_eq!(again.status.code(), Some(2), "an unknown job is bad input: {}", stderr(&again));
    assert!(stderr(&again).contains(&format!("job {job:?}")), "{}", stderr(&again));
    let collected = gc(&["--min-age-s", "0"]);
    assert_eq!(collected["collected"].as_u64(), Some(before as u64), "{collected}");
    assert_eq!(objects.count_objects().await.unwrap(), 0);
}
