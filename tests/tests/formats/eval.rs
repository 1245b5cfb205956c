//! `vintctl eval` on tiny's BOP export and on a synthetic BOP dataset with symmetric objects
//! (tests/python/synthetic_bop.py): its ADD and ADD-S, instance by instance, and its AUC and
//! success rates, group by group, against an independent implementation
//! (tests/python/independent_add.py: numpy, its own PLY reader, brute-force nearest neighbours) on
//! perturbed ground truth (tests/python/check_eval.py); and its refusal of bad input.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde_json::Value;
use vint_tests::{bin, python, repo_root, stderr, stdout, vintctl};

use super::{bop, path_str};

fn script(name: &str) -> PathBuf {
    repo_root().join("tests/python").join(name)
}

fn eval(dataset: &Path, estimates: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["eval", "--dataset", path_str(dataset), "--estimates", path_str(estimates)];
    args.extend_from_slice(extra);
    vintctl(&args)
}

/// check_eval.py's summary of one seeded perturbation of `dataset`'s ground truth, after it found
/// vintctl and the independent implementation in agreement.
fn check_eval(dataset: &Path, seed: u32) -> Value {
    let work = tempfile::tempdir().expect("tempdir");
    let out = Command::new(python())
        .arg(script("check_eval.py"))
        .args(["--dataset", path_str(dataset), "--vintctl", path_str(&bin("vintctl"))])
        .args(["--out", path_str(work.path()), "--seed", &seed.to_string()])
        .output()
        .expect("run check_eval.py");
    assert!(
        out.status.success(),
        "check_eval.py (seed {seed}) on {}:\n{}\n{}",
        dataset.display(),
        stdout(&out),
        stderr(&out)
    );
    serde_json::from_slice(&out.stdout).expect("check_eval.py prints JSON")
}

/// Every perturbation check exercised what it claims to: estimates missing, duplicated, turned
/// about the symmetry axis, and errors spread across the AUC's range.
fn assert_exercised(summary: &Value) {
    let tally = &summary["tally"];
    for key in ["missing", "duplicates", "about_axis"] {
        assert!(tally[key].as_u64().is_some_and(|n| n > 0), "no {key} case: {summary}");
    }
    let auc = summary["overall"]["add_s_auc"].as_f64().expect("overall ADD(S) AUC");
    assert!(auc > 20.0 && auc < 95.0, "errors of 0–50 mm and 0–30° give a middling AUC, not {auc}");
}

#[test]
fn eval_agrees_with_an_independent_add_on_perturbed_ground_truth() {
    for seed in [1, 2] {
        let summary = check_eval(bop(), seed);
        assert_exercised(&summary);
        assert_eq!(summary["models"], "models_eval", "a BOP export is scored on its uniformly resampled models");
    }
}

#[test]
fn eval_agrees_on_symmetric_objects_and_two_objects_an_image() {
    let dir = tempfile::tempdir().expect("tempdir");
    let dataset = dir.path().join("synthetic");
    let out = Command::new(python()).arg(script("synthetic_bop.py")).arg(&dataset).output().expect("synthetic_bop.py");
    assert!(out.status.success(), "synthetic_bop.py: {}", stderr(&out));
    for seed in [1, 2, 3] {
        let summary = check_eval(&dataset, seed);
        assert_exercised(&summary);
        assert_eq!(summary["models"], "models", "without models_eval/, the models' vertices");
    }
    // A turn about the cylinder's axis is nearly free for ADD-S and not for ADD: the symmetric
    // objects' ADD-S AUC must beat their ADD AUC, and ADD(S) must be ADD-S for them.
    let csv = dir.path().join("axis.csv");
    let rows = estimates_from_ground_truth(&dataset, |obj_id, r, t| {
        if obj_id == 2 { turned_about_model_z(r, t, 7f64.to_radians()) } else { (r.to_vec(), t.to_vec()) }
    });
    std::fs::write(&csv, rows).expect("write csv");
    let report = json_report(&eval(&dataset, &csv, &["--json"]));
    let cylinder = report["objects"].as_array().expect("objects").iter().find(|o| o["obj_id"] == 2).expect("cylinder");
    assert_eq!(cylinder["symmetric"], true);
    assert_eq!(cylinder["adds_auc"].as_f64(), Some(cylinder["add_s_auc"].as_f64().expect("ADD(S) AUC")));
    for p in report["per_estimate"].as_array().expect("per_estimate").iter().filter(|p| p["obj_id"] == 2) {
        let (add, adds) = (p["add_mm"].as_f64().expect("add"), p["adds_mm"].as_f64().expect("adds"));
        // 7° on a 30 mm radius moves rim points 3.7 mm; the rim is sampled every 5°, so the
        // nearest rim point is at most 2·30·sin(1.25°) ≈ 1.3 mm away.
        assert!(add > 1.0 && adds < 1.4 && adds < add / 2.0, "cylinder ADD {add}, ADD-S {adds}");
    }
}

/// A BOP results CSV with one row per ground-truth instance of `dataset`, its pose passed through
/// `pose(obj_id, R, t)`.
fn estimates_from_ground_truth(dataset: &Path, pose: impl Fn(u64, &[f64], &[f64]) -> (Vec<f64>, Vec<f64>)) -> String {
    let mut csv = String::from("scene_id,im_id,obj_id,score,R,t,time\n");
    for split in std::fs::read_dir(dataset).expect("dataset dir").filter_map(Result::ok) {
        for scene in std::fs::read_dir(split.path()).into_iter().flatten().filter_map(Result::ok) {
            let Ok(text) = std::fs::read_to_string(scene.path().join("scene_gt.json")) else { continue };
            let scene_id: u32 = scene.file_name().to_str().and_then(|n| n.parse().ok()).expect("scene id");
            let gt: Value = serde_json::from_str(&text).expect("scene_gt.json");
            for (im_id, instances) in gt.as_object().expect("images") {
                for i in instances.as_array().expect("instances") {
                    let numbers = |k: &str| -> Vec<f64> {
                        i[k].as_array().expect(k).iter().map(|v| v.as_f64().expect("number")).collect()
                    };
                    let obj_id = i["obj_id"].as_u64().expect("obj_id");
                    let (r, t) = pose(obj_id, &numbers("cam_R_m2c"), &numbers("cam_t_m2c"));
                    let join = |v: &[f64]| v.iter().map(|x| format!("{x:?}")).collect::<Vec<_>>().join(" ");
                    csv.push_str(&format!("{scene_id},{im_id},{obj_id},1,{},{},-1\n", join(&r), join(&t)));
                }
            }
        }
    }
    csv
}

/// R·Rz(angle): the model turned about its own z axis before the ground-truth pose.
fn turned_about_model_z(r: &[f64], t: &[f64], angle: f64) -> (Vec<f64>, Vec<f64>) {
    let (s, c) = angle.sin_cos();
    let rz = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]];
    let turned = (0..9).map(|k| (0..3).map(|m| r[(k / 3) * 3 + m] * rz[m][k % 3]).sum()).collect();
    (turned, t.to_vec())
}

fn json_report(out: &Output) -> Value {
    assert!(out.status.success(), "vintctl eval:\n{}\n{}", stdout(out), stderr(out));
    serde_json::from_slice(&out.stdout).expect("eval --json prints JSON")
}

#[test]
fn the_ground_truth_itself_scores_perfectly_and_the_tables_name_the_objects() {
    let dir = tempfile::tempdir().expect("tempdir");
    let csv = dir.path().join("truth.csv");
    std::fs::write(&csv, estimates_from_ground_truth(bop(), |_, r, t| (r.to_vec(), t.to_vec()))).expect("csv");
    let report = json_report(&eval(bop(), &csv, &["--json"]));
    let overall = &report["overall"];
    assert_eq!(overall["missing"], 0, "{overall}");
    for key in ["add_auc", "adds_auc", "add_s_auc", "add_s_0.1d", "add_s_0.05d"] {
        assert_eq!(overall[key].as_f64(), Some(100.0), "{key}: {overall}");
    }
    let per_estimate = report["per_estimate"].as_array().expect("per_estimate");
    assert_eq!(per_estimate.len() as u64, overall["n"].as_u64().expect("n"));
    assert!(per_estimate.iter().all(|p| p["add_mm"].as_f64().is_some_and(|e| e < 1e-9)), "ADD of the truth is 0");
    // Text: the paper's tables, objects named as dataset.json names them.
    let text = stdout(&eval(bop(), &csv, &[]));
    let record: Value =
        serde_json::from_slice(&std::fs::read(bop().join("dataset.json")).expect("dataset.json")).expect("json");
    for o in record["objects"].as_array().expect("objects") {
        let name = o["name"].as_str().expect("name");
        let row = format!("| {name} | {} |", o["obj_id"]);
        assert!(text.contains(&row), "no row {row:?} in:\n{text}");
    }
    assert!(text.contains("| occlusion |") && text.contains("| ADD(S) AUC |"), "{text}");
}

#[test]
fn a_bad_estimates_csv_exits_2_naming_line_field_value_and_rule() {
    let dir = tempfile::tempdir().expect("tempdir");
    let csv = dir.path().join("bad.csv");
    std::fs::write(
        &csv,
        "scene_id,im_id,obj_id,score,R,t,time\n\
         0,0,4,0.9,1 0 0 0 1 0 0 0 1,0 0 500,-1\n\
         0,1,4,0.9,1 0 0 0 1 0 0 0,0 0 500,-1\n\
         0,2,4,high,1 0 0 0 1 0 0 0 1,0 0 500,-1\n",
    )
    .expect("csv");
    let out = eval(bop(), &csv, &[]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    let message = stderr(&out);
    for needle in ["line 3: R = \"1 0 0 0 1 0 0 0\"", "9 finite numbers", "line 4: score = \"high\"", "a finite number"]
    {
        assert!(message.contains(needle), "{needle:?} not in:\n{message}");
    }
    let out = eval(bop(), &csv, &["--json"]);
    assert_eq!(out.status.code(), Some(2));
    let doc: Value = serde_json::from_str(stdout(&out).trim()).expect("a JSON error on stdout");
    assert_eq!(doc["error"]["code"], 2, "{doc}");
    // Not a BOP dataset, and a split it does not have: bad input too.
    let empty = dir.path().join("empty.csv");
    std::fs::write(&empty, "scene_id,im_id,obj_id,score,R,t,time\n").expect("csv");
    assert!(eval(bop(), &empty, &[]).status.success(), "no estimates at all is valid (every instance missing)");
    let not_bop = eval(&repo_root().join("examples"), &empty, &[]);
    assert!(not_bop.status.code() == Some(2) && stderr(&not_bop).contains("models_info.json"), "{}", stderr(&not_bop));
    let split = eval(bop(), &empty, &["--split", "no_such_split"]);
    assert!(split.status.code() == Some(2) && stderr(&split).contains("no_such_split"), "{}", stderr(&split));
}
