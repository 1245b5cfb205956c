//! `vintctl plan` as people and scripts run it: the built binary, no server. The paper's recipe's
//! counts are checked against an independent computation from the spec's numbers (not the
//! planner's code), and a bad spec fails as `validate` fails.

use std::path::PathBuf;
use std::process::{Command, Output};

use serde_json::Value;

fn repo_file(path: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..").join(path)
}

fn vintctl(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_vintctl")).args(args).output().expect("vintctl runs")
}

fn plan_json(spec: &str) -> Value {
    let o = vintctl(&["--json", "plan", repo_file(spec).to_str().unwrap()]);
    assert!(o.status.success(), "{}\n{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).expect("plan --json prints JSON")
}

fn stage(plan: &Value, name: &str) -> (u64, bool) {
    let s = plan["stages"].as_array().unwrap().iter().find(|s| s["stage"] == name).unwrap();
    (s["tasks"].as_u64().unwrap(), s["tasks_exact"].as_bool().unwrap())
}

fn rows(plan: &Value, table: &str) -> u64 {
    let t = plan["database"]["tables"].as_array().unwrap().iter().find(|t| t["table"] == table).unwrap();
    t["rows"].as_u64().unwrap()
}

#[test]
fn the_paper_recipe_plans_the_tasks_and_rows_its_numbers_say() {
    let p = plan_json("examples/vint-sim.toml");
    // 26 objects × 2 hands; 2,500 accepted grasps per pair in chunks of 8 (the default chunk_size);
    // 4 environments × 3 views; every modality: a render writes camera.json, rgb, depth, mask,
    // mask_full and segmentation per view, noise one file per view, a sample holds meta.json and
    // 6 files, and each grasp has one record.
    let (pairs, grasps_per_pair, views) = (26 * 2, 2_500u64, 4 * 3);
    let chunks_per_pair = grasps_per_pair.div_ceil(8);
    let (chunks, grasps) = (pairs * chunks_per_pair, pairs * grasps_per_pair);
    let samples = grasps * views;
    assert_eq!(p["exact"], true);
    assert_eq!(p["counts"]["samples"], 1_560_000);
    assert_eq!(samples, 1_560_000);
    assert_eq!(stage(&p, "grasp"), (chunks, true));
    assert_eq!(stage(&p, "render"), (grasps, true));
    assert_eq!(stage(&p, "noise"), (grasps, true));
    assert_eq!(stage(&p, "package"), (chunks, true));
    assert_eq!(p["totals"]["tasks"], chunks * 2 + grasps * 2);

    let (grasp_files, render_files, noise_files) = (3, views * 6, views);
    assert_eq!(rows(&p, "jobs"), 1);
    assert_eq!(rows(&p, "job_assets"), 0);
    assert_eq!(rows(&p, "tasks"), chunks * 2 + grasps * 2);
    assert_eq!(rows(&p, "attempts"), chunks * 2 + grasps * 2);
    // render ← grasp, noise ← render, package ← its grasp task, renders and noises.
    assert_eq!(rows(&p, "task_deps"), grasps + grasps + chunks + 2 * grasps);
    // Each task's files packed in one `outputs` row.
    assert_eq!(rows(&p, "outputs"), chunks * 2 + grasps * 2);
    assert_eq!(
        rows(&p, "outputs.files"),
        chunks * grasp_files + grasps * render_files + grasps * noise_files + samples * 7 + grasps
    );
    let bytes = p["database"]["bytes"].as_f64().unwrap();
    assert!((p["database"]["bytes_per_sample"].as_f64().unwrap() - bytes / samples as f64).abs() < 1e-6);
    assert!(p["stages"].as_array().unwrap().iter().all(|s| s["cpu_hours"].as_f64().unwrap() > 0.0));
    assert!(p["stages"].as_array().unwrap().iter().all(|s| s["gpu_hours"].is_null()), "no GPU figure is measured");
}

#[test]
fn without_a_quota_the_plan_is_an_upper_bound_with_exact_grasp_tasks() {
    let p = plan_json("examples/tiny.toml");
    assert_eq!(p["exact"], false);
    assert_eq!(stage(&p, "grasp"), (6, true), "2 hands × 3 objects × 2 trials in chunks of 2");
    assert_eq!(stage(&p, "render"), (12, false));
    assert_eq!(p["counts"]["samples"], 72);
}

#[test]
fn the_text_plan_is_a_table_per_stage_and_per_table() {
    let o = vintctl(&["plan", repo_file("examples/vint-sim.toml").to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("1,560,000 samples"), "{text}");
    for line in ["grasp", "render", "noise", "package", "outputs", "total"] {
        assert!(text.lines().any(|l| l.starts_with(line)), "no {line} line:\n{text}");
    }
}

#[test]
fn a_bad_spec_exits_2_naming_the_field_as_validate_does() {
    let dir = tempfile::tempdir().unwrap();
    let spec = dir.path().join("bad.toml");
    std::fs::write(&spec, "objects = [\"mug\"]\n[dataset]\nname = \"b\"\nseed = 1\n[render]\nresolution = [0, 480]\n")
        .unwrap();
    let spec = spec.to_str().unwrap();
    let plan = vintctl(&["--json", "plan", spec]);
    let validate = vintctl(&["--json", "validate", spec]);
    assert_eq!((plan.status.code(), validate.status.code()), (Some(2), Some(2)));
    let (p, v): (Value, Value) =
        (serde_json::from_slice(&plan.stdout).unwrap(), serde_json::from_slice(&validate.stdout).unwrap());
    assert_eq!(p["error"]["errors"], v["error"]["errors"]);
    assert!(p["error"]["errors"][0]["path"].as_str().unwrap().starts_with("render.resolution"), "{p}");
    assert_eq!(vintctl(&["plan", "no/such/spec.toml"]).status.code(), Some(2));
}
