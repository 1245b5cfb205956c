//! The tiny run's pictures at the spec defaults (denoised, then the firefly filter; three objects,
//! both hands): no firefly on the object, the hand or the arm (`tests/python/check_fireflies.py`,
//! which reads only the dataset's PNGs and id maps); every view's occlusion within the spec's range
//! (`tests/python/check_occlusion.py`, from the mask files alone).

use super::{path_str, tiny};
use vint_tests::{python, repo_root, stdout};

#[test]
fn the_default_render_has_no_isolated_bright_pixels_on_hand_or_object() {
    let script = repo_root().join("tests/python/check_fireflies.py");
    let out =
        std::process::Command::new(python()).arg(script).arg(path_str(tiny())).output().expect("check_fireflies.py");
    let report: serde_json::Value = serde_json::from_str(stdout(&out).trim())
        .unwrap_or_else(|e| panic!("{e}: {}\n{}", stdout(&out), String::from_utf8_lossy(&out.stderr)));
    assert!(report["images"].as_u64().unwrap_or(0) >= 12, "the tiny run's RGB views: {report}");
    assert!(report["foreground_px"].as_u64().unwrap_or(0) > 1000, "hand and object in view: {report}");
    assert!(out.status.success(), "fireflies on the foreground: {report}");
}

/// Every view of the tiny run — both hands, three objects — has its occlusion, recomputed from its
/// `mask.png` and `mask_full.png` alone (`tests/python/check_occlusion.py`), within the spec's
/// `render.occlusion` (the paper's 10–90 % unless the spec says otherwise).
#[test]
fn every_views_occlusion_from_its_masks_lies_within_the_specs_range() {
    let text = std::fs::read_to_string(repo_root().join("examples/tiny.toml")).expect("examples/tiny.toml");
    let [low, high] = vint_core::DatasetSpec::parse(&text).expect("tiny.toml parses").render.occlusion;
    let script = repo_root().join("tests/python/check_occlusion.py");
    let out = std::process::Command::new(python())
        .arg(script)
        .arg(path_str(tiny()))
        .args([low.to_string(), high.to_string()])
        .output()
        .expect("check_occlusion.py");
    let report: serde_json::Value = serde_json::from_str(stdout(&out).trim())
        .unwrap_or_else(|e| panic!("{e}: {}\n{}", stdout(&out), String::from_utf8_lossy(&out.stderr)));
    assert!(report["views"].as_u64().unwrap_or(0) >= 12, "the tiny run's views: {report}");
    assert!(out.status.success(), "views outside [{low}, {high}]: {report}");
}
