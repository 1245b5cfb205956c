//! `vintctl run` on the embedded default, as a researcher uses it.

use vint_tests::*;

#[test]
fn tiny_spec_produces_verified_samples_identical_for_any_worker_count() {
    let tmp = tempfile::tempdir().unwrap();
    let mut hashes = Vec::new();
    for workers in [1, 3] {
        let dir = tmp.path().join(format!("w{workers}"));
        let o = run_tiny(&dir, workers);
        assert!(o.status.success(), "vintctl run failed:\n{}\n{}", stdout(&o), stderr(&o));
        let lines = verify_dataset(&dir.join("out"));
        assert!(!lines.is_empty(), "no samples");
        for line in &lines {
            let files: Vec<&str> = line["files"].as_object().unwrap().keys().map(String::as_str).collect();
            assert_eq!(files, ["depth.npy", "depth_noisy.npy", "mask.png", "meta.json", "rgb.png"]);
            let sample = line["sample_id"].as_str().unwrap();
            let meta: serde_json::Value =
                serde_json::from_slice(&std::fs::read(dir.join("out").join(sample).join("meta.json")).unwrap())
                    .unwrap();
            assert_eq!(meta["sample_id"], sample);
            assert_eq!(meta["camera"]["K"].as_array().unwrap().len(), 3);
            assert!(
                meta["grasp"]["object_pose"]["p"].as_array().unwrap().iter().all(|x| x.as_f64().unwrap().is_finite())
            );
            assert!(!meta["grasp"]["link_poses"].as_object().unwrap().is_empty());
            assert!(!meta["grasp"]["joints"].as_object().unwrap().is_empty());
        }
        let summary: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("--json summary");
        assert_eq!(summary["manifest_sha256"], manifest_sha256(&dir.join("out")));
        hashes.push(manifest_sha256(&dir.join("out")));
    }
    assert_eq!(hashes[0], hashes[1], "1 and 3 workers must produce the same dataset");
}

#[test]
fn rerunning_a_spec_with_its_state_resumes_the_same_job() {
    let tmp = tempfile::tempdir().unwrap();
    let first = run_tiny(tmp.path(), 2);
    assert!(first.status.success(), "{}", stderr(&first));
    let hash = manifest_sha256(&tmp.path().join("out"));
    let again = run_tiny(tmp.path(), 2);
    assert!(again.status.success(), "{}", stderr(&again));
    assert_eq!(manifest_sha256(&tmp.path().join("out")), hash);
}

#[test]
fn an_invalid_spec_exits_2_and_writes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let spec = tmp.path().join("bad.toml");
    let text =
        std::fs::read_to_string(tiny_spec()).unwrap().replace("resolution = [128, 128]", "resolution = [0, 128]");
    std::fs::write(&spec, text).unwrap();
    let out = tmp.path().join("out");
    let state = tmp.path().join("state");
    let o =
        vintctl(&["run", spec.to_str().unwrap(), "--out", out.to_str().unwrap(), "--state", state.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("render.resolution[0]: must be 16..=8192, got 0"), "{}", stderr(&o));
    assert!(!out.exists() && !state.exists(), "nothing may be written for an invalid spec");

    let v = vintctl(&["validate", spec.to_str().unwrap(), "--json"]);
    assert_eq!(v.status.code(), Some(2));
    let report: serde_json::Value = serde_json::from_str(&stdout(&v)).unwrap();
    assert_eq!(report["valid"], false);
    assert_eq!(report["errors"][0]["path"], "render.resolution[0]");

    let ok = vintctl(&["validate", tiny_spec().to_str().unwrap()]);
    assert!(ok.status.success(), "{}", stderr(&ok));
}

#[test]
fn a_missing_spec_file_is_bad_input() {
    let o = vintctl(&["validate", "/nonexistent/spec.toml"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("/nonexistent/spec.toml"));
}

#[test]
fn an_existing_unrelated_output_directory_is_not_replaced() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("precious");
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("thesis.tex"), "do not delete").unwrap();
    let state = tmp.path().join("state");
    let o = vintctl(&[
        "run",
        tiny_spec().to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--state",
        state.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(out.join("thesis.tex").exists());
}

#[test]
fn hands_lists_dof_and_taxels_per_region() {
    let o = vintctl(&["hands", "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let hands: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let allegro = hands.as_array().unwrap().iter().find(|h| h["name"] == "allegro").expect("allegro listed");
    assert_eq!(allegro["dof"], 16);
    let regions = allegro["taxels_per_region"].as_object().unwrap();
    let total: u64 = regions.values().map(|v| v.as_u64().unwrap()).sum();
    assert_eq!(total, 679);
    assert_eq!(regions.keys().map(String::as_str).collect::<Vec<_>>(), ["palm", "pulp", "tip"]);
}

#[test]
fn grasp_study_writes_csv_plot_and_table() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("study");
    let o = vintctl(&["study", "grasp", "--out", out.to_str().unwrap(), "--quick"]);
    assert!(o.status.success(), "{}\n{}", stdout(&o), stderr(&o));
    for f in ["grasp_study.csv", "grasp_study_summary.csv", "grasp_study.png", "grasp_study.md"] {
        assert!(out.join(f).metadata().map(|m| m.len() > 0).unwrap_or(false), "{f} missing");
    }
    let bad = vintctl(&["study", "paint", "--out", out.to_str().unwrap()]);
    assert_eq!(bad.status.code(), Some(2));
}
