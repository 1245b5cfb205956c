//! The tiny run's pictures at the spec defaults (denoised, then the firefly filter; three objects,
//! both hands): no firefly on the object, the hand or the arm (`tests/python/check_fireflies.py`,
//! which reads only the dataset's PNGs and id maps).

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
