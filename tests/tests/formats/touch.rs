//! The tiny run's touch against geometry (`tests/python/check_touch_recall.py`, which reads only
//! the dataset's grasp records, the layout they cite and the exported models, and measures each
//! taxel's distance to the model with its own code): the taxels that touch the object fire, and
//! the taxels that fire touch it, in every power grasp the palm feels the object, and no grasp
//! presses it with the back of a link; a grasp record whose object is moved off its pose, whose
//! palm readings are zeroed, or with a contact on a finger's back, fails the check.

use std::path::Path;
use std::process::Output;

use serde_json::Value;

use super::{path_str, tiny};
use vint_tests::{python, repo_root, stdout};

fn check_touch_recall(dir: &Path) -> (Output, Value) {
    let script = repo_root().join("tests/python/check_touch_recall.py");
    let out =
        std::process::Command::new(python()).arg(script).arg(path_str(dir)).output().expect("check_touch_recall.py");
    let report = serde_json::from_str(stdout(&out).trim())
        .unwrap_or_else(|e| panic!("{e}: {}\n{}", stdout(&out), String::from_utf8_lossy(&out.stderr)));
    (out, report)
}

#[test]
fn taxels_touching_the_object_fire_and_active_taxels_touch_it() {
    let (out, report) = check_touch_recall(tiny());
    // Power grasps (the default) keep about half the trials: tiny's 12 give 5 on this machine.
    assert!(report["grasps"].as_u64().unwrap_or(0) >= 4, "the tiny run's grasps: {report}");
    assert!(report["near"].as_u64().unwrap_or(0) >= 30, "taxels against the object: {report}");
    assert_eq!(report["power_grasps"], report["grasps"], "tiny grasps with the spec's default power grasp: {report}");
    assert!(out.status.success(), "recall ≥ 0.90, precision ≥ 0.95, every power grasp's palm feels: {report}");
}

/// The palm check can fail: the same records, stated as power grasps, with every palm taxel's
/// reading zeroed.
#[test]
fn touch_check_fails_when_a_power_grasps_palm_feels_nothing() {
    let numb = edited_copy("out-touch-numb-palm", |record| {
        let layout = repo_root().join("catalog").join(record["hand"]["taxels"]["layout"].as_str().expect("layout"));
        let links: Vec<String> = std::fs::read_to_string(layout)
            .expect("taxel layout")
            .lines()
            .skip(1)
            .map(|line| line.split(',').nth(1).expect("link column").to_string())
            .collect();
        record["physics"]["grasp_type"] = Value::from("power");
        let readings = record["touch"]["readings"].as_array_mut().expect("readings");
        for (reading, link) in readings.iter_mut().zip(&links) {
            if link == "palm" {
                *reading = Value::from(0.0);
            }
        }
    });
    let (out, report) = check_touch_recall(&numb);
    assert_eq!(out.status.code(), Some(1), "{report}");
    let numb_palms = report["power_grasps_with_numb_palm"].as_array().map_or(0, Vec::len);
    assert_eq!(numb_palms as u64, report["grasps"].as_u64().unwrap_or(0), "every grasp's palm is numb: {report}");
}

/// The back check can fail: the same records with one more contact, 1 N on the back of a finger
/// link (behind its capsule's axis by its whole radius, at the capsule's middle), in every sample.
#[test]
fn touch_check_fails_when_a_grasp_presses_with_a_finger_back() {
    let pressed = edited_copy("out-touch-pressed-back", |record| {
        let finger = record["hand"]["links"]
            .as_array()
            .expect("hand.links")
            .iter()
            .find_map(|link| {
                let capsule = link["geoms"].as_array()?.iter().find(|g| g["type"] == "capsule")?;
                let radius = capsule["size"][0].as_f64()?;
                Some((link["name"].clone(), radius, capsule["p"][2].as_f64()?))
            })
            .expect("a finger link with a capsule");
        let (name, radius, middle) = finger;
        let contact = serde_json::json!({
            "link": name, "force_n": 1.0, "p_link": [-radius, 0.0, middle], "n_link": [-1.0, 0.0, 0.0],
        });
        for sample in record["touch"]["contact_samples"].as_array_mut().expect("contact_samples") {
            sample.as_array_mut().expect("a sample's contacts").push(contact.clone());
        }
    });
    let (out, report) = check_touch_recall(&pressed);
    assert_eq!(out.status.code(), Some(1), "{report}");
    let pressing = report["grasps_pressing_with_a_back"].as_array().map_or(0, Vec::len);
    assert_eq!(pressing as u64, report["grasps"].as_u64().unwrap_or(0), "every grasp presses with a back: {report}");
}

/// A copy of the tiny run's grasp records (and models) under `name`, each record changed by `edit`.
fn edited_copy(name: &str, edit: impl Fn(&mut Value)) -> std::path::PathBuf {
    let to = tiny().with_file_name(name);
    copy_models(&to);
    for entry in std::fs::read_dir(tiny()).expect("dataset dir") {
        let grasp = entry.expect("entry").path().join("grasp.json");
        let Ok(bytes) = std::fs::read(&grasp) else { continue };
        let mut record: Value = serde_json::from_slice(&bytes).expect("grasp.json");
        edit(&mut record);
        let dir = to.join(grasp.parent().and_then(Path::file_name).expect("grasp dir"));
        std::fs::create_dir_all(&dir).expect("grasp dir");
        std::fs::write(dir.join("grasp.json"), record.to_string()).expect("write grasp.json");
    }
    to
}

fn copy_models(to: &Path) {
    std::fs::create_dir_all(to.join("models")).expect("models dir");
    for entry in std::fs::read_dir(tiny().join("models")).expect("models") {
        let path = entry.expect("entry").path();
        std::fs::copy(&path, to.join("models").join(path.file_name().expect("name"))).expect("copy model");
    }
}

/// The check can fail: the same records with the object 3 mm off its recorded pose put the active
/// taxels off the surface and other taxels into it.
#[test]
fn touch_check_fails_when_the_object_is_off_its_pose() {
    let moved = edited_copy("out-touch-moved", |record| {
        let x = &mut record["trial"]["object_pose"]["p"][0];
        *x = Value::from(x.as_f64().expect("object_pose.p") + 0.003);
    });
    let (out, report) = check_touch_recall(&moved);
    assert_eq!(out.status.code(), Some(1), "{report}");
    assert!(report["recall"].as_f64().unwrap_or(1.0) < 0.9 || report["precision"].as_f64().unwrap_or(1.0) < 0.95);
}
