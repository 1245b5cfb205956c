//! `vint-worker --engine-mode timing-only` drives the real coordinator, planner, lineage and
//! object store through a whole job without an engine: what `benches/dispatch.sh` scales to
//! 2 M samples. Its output is marked as such and is not data.

use std::process::{Command, Stdio};

use vint_artifacts::ArtifactStore;
use vint_store::{RetryPolicy, Store};
use vint_tests::*;

/// Two pairs with a quota: 12 accepted grasps each out of at most 24 trials, chunks of 5 trials
/// (so quotas split across chunks), 2 views, every modality.
const SPEC: &str = r#"
hands = ["trx3"]
objects = ["tomato_soup_can", "mug"]
[dataset]
name = "timing_only"
seed = 11
[grasp]
accepted_per_pair = 12
trials_per_pair = 24
chunk_size = 5
[render]
resolution = [64, 48]
views_per_environment = 2
[outputs]
modalities = ["rgb", "depth", "depth_noisy", "mask", "segmentation", "pose"]
"#;

#[tokio::test(flavor = "multi_thread")]
async fn a_timing_only_worker_drains_a_job_with_full_lineage_and_marks_its_outputs() {
    let dir = tempfile::tempdir().unwrap();
    let spec = dir.path().join("spec.toml");
    std::fs::write(&spec, SPEC).unwrap();
    let database = format!("sqlite://{}", dir.path().join("vint.db").display());
    let store_url = format!("file://{}", dir.path().join("objects").display());
    let port = free_port();
    let coordinator = format!("http://127.0.0.1:{port}");
    let logs = dir.path().join("logs");
    let _coordinator = start_coordinator(&database, port, &logs, "coordinator");
    // The same spec submitted for real workers: another job, which no timing-only worker serves.
    let o = vintctl(&["submit", spec.to_str().unwrap(), "--coordinator", &coordinator]);
    assert!(o.status.success(), "submit: {}", stderr(&o));
    let real_job = stdout(&o).trim().to_string();
    let o = vintctl(&["submit", spec.to_str().unwrap(), "--timing-only", "--coordinator", &coordinator]);
    assert!(o.status.success(), "submit: {}", stderr(&o));
    let job = stdout(&o).trim().to_string();
    assert_ne!(job, real_job, "a spec for timing-only workers is another job");

    let worker = Command::new(bin("vint-worker"))
        .args(["--coordinator", &coordinator, "--store", &store_url, "--worker-id", "timing"])
        .args(["--engine-mode", "timing-only", "--batch", "7", "--concurrency", "2"])
        .stdout(Stdio::null())
        .stderr(Stdio::from(std::fs::File::create(dir.path().join("worker.log")).unwrap()))
        .spawn()
        .expect("start worker");
    let _worker = Proc { child: worker, name: "timing".into() };
    let o = vintctl(&["watch", &job, "--coordinator", &coordinator, "--json"]);
    assert!(o.status.success(), "job did not succeed: {}\n{}", stdout(&o), stderr(&o));

    let o = vintctl(&["status", &real_job, "--coordinator", &coordinator, "--json"]);
    let status: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(
        (status["progress"]["tasks_running"].as_u64(), status["progress"]["tasks_succeeded"].as_u64()),
        (Some(0), Some(0)),
        "a timing-only worker served a job not submitted for it: {status:#}"
    );
    // Its output is not data: export refuses it, saying why, and writes nothing.
    let out = dir.path().join("export");
    let o = vintctl(&["export", &job, "--out", out.to_str().unwrap(), "--coordinator", &coordinator]);
    assert_eq!(o.status.code(), Some(2), "export of a timing-only job: {}", stderr(&o));
    assert!(stderr(&o).contains("--timing-only") && stderr(&o).contains("not data"), "{}", stderr(&o));
    assert!(!out.exists());

    let o = vintctl(&["status", &job, "--coordinator", &coordinator, "--json"]);
    let status: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(status["state"], "succeeded");
    assert_eq!(
        status["progress"]["samples_packaged"],
        2 * 12 * 2,
        "each pair's quota of grasps, two views each: {status:#}"
    );

    // A sample's lineage is the whole chain, every task marked timing-only, and every artifact
    // on it is in the object store under its hash.
    let store = Store::open(&database, RetryPolicy::default()).await.unwrap();
    let samples = store.samples(&job).await.unwrap();
    assert_eq!(samples.len(), 2 * 12 * 2);
    // Every sample carries the files of its six modalities and its meta.json.
    for (id, files) in &samples {
        assert_eq!(files.len(), 7, "{id}: {:?}", files.iter().map(|f| &f.name).collect::<Vec<_>>());
    }
    let sample = samples.keys().nth(samples.len() / 2).unwrap().clone();
    let o = vintctl(&["lineage", &sample, "--job", &job, "--coordinator", &coordinator, "--json"]);
    assert!(o.status.success(), "lineage of {sample}: {}", stderr(&o));
    let lineage: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let tasks = lineage["tasks"].as_array().unwrap();
    let stages: Vec<&str> = tasks.iter().map(|t| t["stage"].as_str().unwrap()).collect();
    assert_eq!(stages, ["package", "noise", "render", "grasp"], "{lineage:#}");
    let objects = ArtifactStore::open(&store_url).unwrap();
    for t in tasks {
        assert_eq!(t["engine"]["mode"], "timing-only", "{t:#}");
        for a in t["outputs"].as_array().unwrap() {
            let sha = a["sha256"].as_str().unwrap();
            let bytes = objects.get(sha).await.unwrap_or_else(|e| panic!("{}: {e}", a["name"]));
            assert_eq!(bytes.len() as u64, a["size"].as_u64().unwrap(), "{}", a["name"]);
        }
    }
    // The package references its render's files: the same hashes, not copies.
    let hashes = |t: &serde_json::Value| -> Vec<String> {
        t["outputs"].as_array().unwrap().iter().map(|a| a["sha256"].as_str().unwrap().to_string()).collect()
    };
    let render = hashes(&tasks[2]);
    let packaged_rgb = tasks[0]["outputs"]
        .as_array()
        .unwrap()
        .iter()
        .find(|a| a["name"].as_str().unwrap().ends_with("/rgb.png"))
        .expect("a packaged rgb.png");
    assert!(render.contains(&packaged_rgb["sha256"].as_str().unwrap().to_string()));
    // Sizes follow the resolution: a 64×48 16-bit PNG depth image, as large as the engines' files
    // of that many pixels (the model of measured sizes; > 0.37 B/px, the 128×128 figure).
    let depth = tasks[2]["outputs"].as_array().unwrap().iter().find(|a| a["name"] == "v00_depth.png").unwrap();
    let expected = vint_core::contract::render::ViewFile::Depth(Default::default()).bytes(64 * 48);
    assert_eq!(depth["size"], expected);
    assert!(expected as f64 > 0.368 * 64.0 * 48.0, "{expected}");
}
