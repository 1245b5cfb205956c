//! `vintctl diff A B` on a real dataset: tiny.toml run once, copied, and the copy perturbed as
//! another machine or a bug would perturb it. Byte-identity is a promise per machine build; diff is
//! how two datasets are compared across machines (docs/reproducibility.md).

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use sha2::{Digest, Sha256};
use vint_tests::*;

/// tiny.toml packaged once for every test here (they only read it).
fn reference() -> &'static Path {
    static DATASET: OnceLock<PathBuf> = OnceLock::new();
    DATASET.get_or_init(|| {
        // One fixed place under target/: a later run replaces it rather than piling up copies.
        let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("diff-tiny");
        let _ = std::fs::remove_dir_all(&dir);
        let o = run_tiny(&dir, 2);
        assert!(o.status.success(), "tiny run failed:\n{}\n{}", stdout(&o), stderr(&o));
        dir.join("out")
    })
}

/// A copy of the reference dataset to perturb.
struct Copy {
    _tmp: tempfile::TempDir,
    dir: PathBuf,
}

impl Copy {
    fn new() -> Copy {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("b");
        copy_dir(reference(), &dir);
        Copy { _tmp: tmp, dir }
    }

    fn samples(&self) -> Vec<String> {
        manifest(&self.dir).iter().filter_map(|l| l["sample_id"].as_str().map(str::to_string)).collect()
    }

    /// Runs `code` (Python, with numpy as np, cv2 and `path`) on one file, then records the file's
    /// new hash in the manifest, as a dataset made elsewhere would list it.
    fn edit(&self, sample: &str, file: &str, code: &str) {
        let path = self.dir.join(sample).join(file);
        let script = format!("import sys, numpy as np, cv2\npath = sys.argv[1]\n{code}\n");
        let o = std::process::Command::new(python()).args(["-c", &script]).arg(&path).output().unwrap();
        assert!(o.status.success(), "editing {file}: {}", stderr(&o));
        self.rehash(sample, file);
    }

    fn edit_json(&self, sample: &str, file: &str, edit: impl FnOnce(&mut serde_json::Value)) {
        let path = self.dir.join(sample).join(file);
        let mut doc: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
        edit(&mut doc);
        std::fs::write(&path, serde_json::to_vec_pretty(&doc).unwrap()).unwrap();
        self.rehash(sample, file);
    }

    fn rehash(&self, sample: &str, file: &str) {
        let sha = hex::encode(Sha256::digest(std::fs::read(self.dir.join(sample).join(file)).unwrap()));
        self.rewrite_manifest(|line| {
            if line["sample_id"] == sample {
                line["files"][file]["sha256"] = sha.clone().into();
            }
            true
        });
    }

    /// Rewrites the manifest line by line; lines for which `keep` is false are dropped.
    fn rewrite_manifest(&self, mut keep: impl FnMut(&mut serde_json::Value) -> bool) {
        let mut text = String::new();
        for mut line in manifest(&self.dir) {
            if keep(&mut line) {
                text.push_str(&format!("{line}\n"));
            }
        }
        std::fs::write(self.dir.join("manifest.jsonl"), text).unwrap();
    }

    /// `vintctl --json diff REFERENCE COPY ARGS…`: exit code and report — one JSON document on
    /// stdout, which names the error when the datasets differ.
    fn diff(&self, args: &[&str]) -> (Option<i32>, serde_json::Value) {
        let (a, b) = (reference().to_str().unwrap(), self.dir.to_str().unwrap());
        let o = vintctl(&[&["--json", "diff", a, b], args].concat());
        let report: serde_json::Value = serde_json::from_str(&stdout(&o))
            .unwrap_or_else(|e| panic!("--json report: {e}\n{}\n{}", stdout(&o), stderr(&o)));
        assert_eq!(report.get("error").is_some(), o.status.code() != Some(0), "{report}");
        (o.status.code(), report)
    }
}

fn manifest(dir: &Path) -> Vec<serde_json::Value> {
    let text = std::fs::read_to_string(dir.join("manifest.jsonl")).unwrap();
    text.lines().filter(|l| !l.trim().is_empty()).map(|l| serde_json::from_str(l).unwrap()).collect()
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.file_type().unwrap().is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), target).unwrap();
        }
    }
}

/// The differences the report lists, as (sample, file).
fn differing_files(report: &serde_json::Value) -> Vec<(String, String)> {
    let list = report["differences"].as_array().unwrap();
    list.iter().map(|d| (d["sample"].as_str().unwrap().to_string(), d["file"].as_str().unwrap().to_string())).collect()
}

#[test]
fn a_copy_is_within_tolerance_without_a_byte_read() {
    let copy = Copy::new();
    let (code, report) = copy.diff(&[]);
    assert_eq!(code, Some(0), "{report:#}");
    assert_eq!(report["within_tolerance"], true);
    assert_eq!(report["samples"]["compared"], report["samples"]["in_a"]);
    for modality in report["modalities"].as_array().unwrap() {
        assert_eq!(modality["identical"], modality["compared"], "{modality}");
        assert!(modality["compared"].as_u64().unwrap() > 0);
    }
    let names: Vec<&str> =
        report["modalities"].as_array().unwrap().iter().map(|m| m["modality"].as_str().unwrap()).collect();
    assert!(
        ["rgb.png", "depth.png", "depth_noisy.png", "mask.png", "segmentation.png"].iter().all(|n| names.contains(n)),
        "{names:?}"
    );
}

#[test]
fn an_rgb_pixel_one_level_off_is_within_tolerance_and_forty_levels_off_is_not() {
    let copy = Copy::new();
    let sample = &copy.samples()[0];
    copy.edit(
        sample,
        "rgb.png",
        "i = cv2.imread(path); i[5, 7, 1] = i[5, 7, 1] + 1 if i[5, 7, 1] < 255 else 254; cv2.imwrite(path, i)",
    );
    let (code, report) = copy.diff(&[]);
    assert_eq!(code, Some(0), "{report:#}");
    let rgb = report["modalities"].as_array().unwrap().iter().find(|m| m["modality"] == "rgb.png").unwrap().clone();
    assert_eq!(rgb["identical"].as_u64().unwrap() + 1, rgb["compared"].as_u64().unwrap(), "one rgb.png read");
    assert_eq!(rgb["worst"]["value"], 1.0);
    assert_eq!(rgb["worst"]["at"], "pixel (u=7, v=5)");

    let copy = Copy::new(); // afresh: 40 levels from the reference
    copy.edit(sample, "rgb.png", "i = cv2.imread(path); i[5, 7, 1] = i[5, 7, 1] + 40 if i[5, 7, 1] < 200 else i[5, 7, 1] - 40; cv2.imwrite(path, i)");
    let (code, report) = copy.diff(&[]);
    assert_eq!(code, Some(1), "{report:#}");
    assert_eq!(differing_files(&report), [(sample.clone(), "rgb.png".to_string())]);
    assert_eq!(report["samples"]["differing"], serde_json::json!([sample]));
    assert_eq!(report["differences"][0]["measures"][0]["value"], 40.0);
}

#[test]
fn depth_and_a_camera_pose_a_millimetre_off_are_named_by_sample_file_and_place() {
    let copy = Copy::new();
    let samples = copy.samples();
    let (depth_sample, pose_sample) = (&samples[1], &samples[2]);
    // One pixel with a return, 1 mm further: ten 0.1 mm steps of the 16-bit PNG.
    copy.edit(
        depth_sample,
        "depth.png",
        "d = cv2.imread(path, cv2.IMREAD_UNCHANGED); d[tuple(np.argwhere(d > 0)[0])] += 10; cv2.imwrite(path, d)",
    );
    copy.edit_json(pose_sample, "meta.json", |meta| {
        let x = meta["camera"]["t_w2c"][0].as_f64().unwrap();
        meta["camera"]["t_w2c"][0] = (x + 1e-3).into();
    });
    let (code, report) = copy.diff(&[]);
    assert_eq!(code, Some(1), "{report:#}");
    let mut found = differing_files(&report);
    found.sort();
    let mut expected =
        vec![(depth_sample.clone(), "depth.png".to_string()), (pose_sample.clone(), "meta.json".to_string())];
    expected.sort();
    assert_eq!(found, expected);
    for difference in report["differences"].as_array().unwrap() {
        let worst = &difference["measures"][0];
        if difference["file"] == "meta.json" {
            let length =
                difference["measures"].as_array().unwrap().iter().find(|m| m["name"] == "length_abs_m").unwrap();
            assert_eq!(length["at"], "camera.t_w2c[0]");
            assert!((length["value"].as_f64().unwrap() - 1e-3).abs() < 1e-6, "{length}");
        } else {
            assert_eq!(worst["name"], "max_abs_m");
            assert!((worst["value"].as_f64().unwrap() - 1e-3).abs() < 1e-5, "{worst}");
        }
    }
    let (code, report) = copy.diff(&["--depth-m", "0.002", "--position-m", "0.002"]);
    assert_eq!(code, Some(0), "looser tolerances accept both: {report:#}");
}

#[test]
fn samples_and_files_missing_on_one_side_exit_1_and_are_named() {
    let copy = Copy::new();
    let samples = copy.samples();
    let (dropped, trimmed) = (samples[0].clone(), samples[1].clone());
    copy.rewrite_manifest(|line| {
        if line["sample_id"] == trimmed.as_str() {
            line["files"].as_object_mut().unwrap().remove("mask.png");
        }
        line["sample_id"] != dropped.as_str()
    });
    let (code, report) = copy.diff(&[]);
    assert_eq!(code, Some(1), "{report:#}");
    assert_eq!(report["samples"]["only_in_a"], serde_json::json!([dropped]));
    assert_eq!(report["samples"]["only_in_b"], serde_json::json!([]));
    assert_eq!(
        report["missing_files"],
        serde_json::json!([{"sample": trimmed, "file": "mask.png", "missing_in": "b"}])
    );
}

#[test]
fn a_directory_without_a_manifest_or_a_bad_tolerance_is_bad_input() {
    let tmp = tempfile::tempdir().unwrap();
    let here = reference().to_str().unwrap();
    let o = vintctl(&["diff", here, tmp.path().to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("not a dataset: cannot read manifest.jsonl"), "{}", stderr(&o));
    let o = vintctl(&["diff", here, here, "--rgb-share", "2"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("--rgb-share") && stderr(&o).contains("between 0 and 1"), "{}", stderr(&o));
}
