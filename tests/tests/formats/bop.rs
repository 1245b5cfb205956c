//! The BOP export of the tiny run: every file BOP's layout requires, the geometry checked by an
//! independent re-projection (`tests/python/check_bop.py`, which shares no code with the writer),
//! a check that fails on a wrong export, and the same bytes from two conversions.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Output;

use serde_json::Value;

use super::{bop, path_str, tiny};
use vint_tests::{python, repo_root, stdout, vintctl};

fn read_json(path: &Path) -> Value {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_slice(&bytes).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn check_bop(dir: &Path) -> Output {
    let script = repo_root().join("tests/python/check_bop.py");
    std::process::Command::new(python()).arg(script).arg(dir).output().expect("running check_bop.py")
}

/// Native samples by grasp id: sample id → the files it has.
fn native_samples() -> BTreeMap<String, BTreeMap<u32, (String, Vec<String>)>> {
    let mut grasps: BTreeMap<String, BTreeMap<u32, (String, Vec<String>)>> = BTreeMap::new();
    for entry in std::fs::read_dir(tiny()).expect("native dir") {
        let name = entry.expect("entry").file_name().into_string().expect("utf-8 name");
        let Ok(id) = name.parse::<vint_core::SampleId>() else { continue };
        let files = std::fs::read_dir(tiny().join(&name))
            .expect("sample dir")
            .map(|e| e.expect("entry").file_name().into_string().expect("utf-8 name"))
            .collect();
        grasps.entry(id.grasp().to_string()).or_default().insert(id.view_index, (name, files));
    }
    grasps
}

#[test]
fn bop_export_has_every_file_of_the_layout_for_every_sample() {
    let dir = bop();
    let dataset = read_json(&dir.join("dataset.json"));
    assert_eq!(dataset["format"], "vint-bop");
    let info = read_json(&dir.join("models/models_info.json"));
    for o in dataset["objects"].as_array().expect("objects") {
        let id = o["obj_id"].as_u64().expect("obj_id");
        assert!(!(1..=21).contains(&id), "obj_id {id} would be ycbv's model {id}");
        assert!(dir.join(format!("models/obj_{id:06}.ply")).is_file(), "model of obj_id {id}");
        for key in ["diameter", "min_x", "min_y", "min_z", "size_x", "size_y", "size_z"] {
            assert!(info[id.to_string()][key].is_number(), "models_info[{id}].{key}");
        }
    }
    let grasps = native_samples();
    let scenes = dataset["bop"]["scenes"].as_array().expect("bop.scenes");
    assert_eq!(scenes.len(), grasps.len(), "one scene per grasp");
    let split = &dataset["split"]["grasps"];
    for (scene_id, (grasp, views)) in grasps.iter().enumerate() {
        let entry = &scenes[scene_id];
        assert_eq!(
            (entry["scene_id"].as_u64(), entry["grasp_id"].as_str()),
            (Some(scene_id as u64), Some(grasp.as_str()))
        );
        let scene = dir.join(split[grasp].as_str().expect("split")).join(format!("{scene_id:06}"));
        for file in ["scene_camera", "scene_gt", "scene_gt_info", "scene_touch", "scene_hand", "scene_meta"] {
            let records = read_json(&scene.join(format!("{file}.json")));
            let ids: Vec<u32> =
                records.as_object().expect("per-image object").keys().map(|k| k.parse().expect("int key")).collect();
            let mut expected: Vec<u32> = views.keys().copied().collect();
            expected.sort_unstable();
            let mut ids = ids;
            ids.sort_unstable();
            assert_eq!(ids, expected, "{}/{file}.json", scene.display());
        }
        for (view, (sample, files)) in views {
            let has = |f: &str| files.iter().any(|x| x == f);
            let mut required: Vec<PathBuf> = Vec::new();
            for (native, folder) in [
                ("rgb.png", "rgb"),
                ("depth.png", "depth"),
                ("depth_noisy.png", "depth_noisy"),
                ("segmentation.png", "segmentation"),
            ] {
                if has(native) {
                    required.push(scene.join(folder).join(format!("{view:06}.png")));
                }
            }
            assert!(
                has("depth.png") && has("mask.png") && has("mask_full.png"),
                "tiny asks for depth and masks: {sample}"
            );
            required.push(scene.join(format!("mask/{view:06}_000000.png")));
            required.push(scene.join(format!("mask_visib/{view:06}_000000.png")));
            for path in required {
                assert!(path.is_file(), "{sample}: {} is missing", path.display());
            }
        }
    }
}

#[test]
fn bop_export_matches_an_independent_reprojection_of_the_models() {
    let run = check_bop(bop());
    assert!(run.status.success(), "check_bop.py failed:\n{}\n{}", stdout(&run), String::from_utf8_lossy(&run.stderr));
    let summary: Value = serde_json::from_str(&stdout(&run)).expect("check_bop prints JSON");
    let samples: usize = native_samples().values().map(BTreeMap::len).sum();
    assert_eq!(summary["images"].as_u64(), Some(samples as u64), "every sample checked: {summary}");
    assert_eq!(summary["models"].as_u64(), Some(3), "{summary}");
    let depth = &summary["depth_error_mm"];
    assert!(depth["median"].as_f64().is_some_and(|m| m <= 0.1), "0.1 mm steps, exact geometry: {summary}");
    assert!(depth["pixels"].as_u64().is_some_and(|n| n > 1000), "{summary}");
    assert!(summary["mask_iou"]["min"].as_f64().is_some_and(|iou| iou >= 0.98), "{summary}");
    assert!(summary["touch_surface_mm"]["taxels"].as_u64().is_some_and(|n| n > 0), "tiny's grasps touch: {summary}");
    assert!(summary["touch_surface_mm"]["max"].as_f64().is_some_and(|d| d <= 2.0), "{summary}");
    let coco = summary["coco_annotations"].as_u64().expect("coco_annotations");
    assert!(coco > 0 && coco <= samples as u64, "one COCO annotation per image that sees its object: {summary}");
    // camera.json and the test targets, enumerated by the toolkit's rules in the check.
    let targets = &summary["targets"];
    assert_eq!(targets["bop24"], targets["test_images"], "one detection target per test image: {summary}");
    assert!(targets["bop19"].as_u64() <= targets["test_images"].as_u64(), "{summary}");
    assert!(bop().join("camera.json").is_file() && bop().join("test_targets_bop24.json").is_file());
    // models_eval: on the surface, at least the spacing apart, covering it within 1.25 spacings.
    let eval = &summary["models_eval"];
    assert!(eval["on_surface_mm"].as_f64().is_some_and(|d| d <= 1e-3), "{summary}");
    assert!(eval["min_spacing_over_r"].as_f64().is_some_and(|s| s >= 0.99999), "{summary}");
    assert!(eval["max_gap_over_r"].as_f64().is_some_and(|g| g <= 1.25), "{summary}");
    assert_eq!(eval["volume_ratio"].as_array().map(Vec::len), Some(3), "{summary}");
}

#[test]
fn the_reprojection_check_fails_on_a_pose_off_by_millimetres_and_on_a_wrong_box() {
    let copy = tempfile::tempdir().expect("tempdir");
    let broken = copy.path().join("bop");
    copy_dir(bop(), &broken);
    let dataset = read_json(&broken.join("dataset.json"));
    let scene = &dataset["bop"]["scenes"][0];
    let dir = broken
        .join(scene["split"].as_str().expect("split"))
        .join(format!("{:06}", scene["scene_id"].as_u64().expect("id")));
    let im = scene["im_ids"][0].to_string();
    let mut gt = read_json(&dir.join("scene_gt.json"));
    let z = gt[&im][0]["cam_t_m2c"][2].as_f64().expect("t_z");
    gt[&im][0]["cam_t_m2c"][2] = Value::from(z + 3.0);
    std::fs::write(dir.join("scene_gt.json"), serde_json::to_vec(&gt).expect("json")).expect("write");
    let mut info = read_json(&dir.join("scene_gt_info.json"));
    let w = info[&im][0]["bbox_visib"][2].as_i64().expect("w");
    info[&im][0]["bbox_visib"][2] = Value::from(w + 1);
    std::fs::write(dir.join("scene_gt_info.json"), serde_json::to_vec(&info).expect("json")).expect("write");

    let mut camera = read_json(&broken.join("camera.json"));
    camera["fx"] = Value::from(camera["fx"].as_f64().expect("fx") + 1.0);
    std::fs::write(broken.join("camera.json"), serde_json::to_vec(&camera).expect("json")).expect("write");
    let mut targets = read_json(&broken.join("test_targets_bop19.json"));
    targets
        .as_array_mut()
        .expect("targets")
        .push(serde_json::json!({"im_id": 0, "inst_count": 1, "obj_id": 1, "scene_id": 999}));
    std::fs::write(broken.join("test_targets_bop19.json"), serde_json::to_vec(&targets).expect("json")).expect("write");

    let mut coco = read_json(&dir.join("scene_gt_coco.json"));
    let area = coco["annotations"][0]["area"].as_u64().expect("area");
    coco["annotations"][0]["area"] = Value::from(area + 1);
    std::fs::write(dir.join("scene_gt_coco.json"), serde_json::to_vec(&coco).expect("json")).expect("write");
    // The first vertex's normal turned inside out (each float's sign bit: little-endian, byte 3).
    let id = dataset["objects"][0]["obj_id"].as_u64().expect("obj_id");
    let model = broken.join(format!("models/obj_{id:06}.ply"));
    let mut ply = std::fs::read(&model).expect("model");
    let end = ply.windows(11).position(|w| w == b"end_header\n").expect("PLY header") + 11;
    for k in 3..6 {
        ply[end + 4 * k + 3] ^= 0x80;
    }
    std::fs::write(&model, ply).expect("write");
    // models_eval: the first object's first vertex moved out to 1.5 times its distance from the
    // model's centre (off the surface of a model around its centre); the second object's
    // spacing stated as half what it is, so the surface has points farther than 1.25 of it from all.
    let model_eval = broken.join(format!("models_eval/obj_{id:06}.ply"));
    let mut ply = std::fs::read(&model_eval).expect("models_eval model");
    let end = ply.windows(11).position(|w| w == b"end_header\n").expect("PLY header") + 11;
    for k in 0..3 {
        let at = end + 4 * k;
        let v = f32::from_le_bytes(ply[at..at + 4].try_into().expect("4 bytes"));
        ply[at..at + 4].copy_from_slice(&(v * 1.5).to_le_bytes());
    }
    std::fs::write(&model_eval, ply).expect("write");
    let mut described = dataset.clone();
    let spacing = described["bop"]["models_eval"]["objects"][1]["spacing_mm"].as_f64().expect("spacing_mm");
    described["bop"]["models_eval"]["objects"][1]["spacing_mm"] = Value::from(spacing / 2.0);
    std::fs::write(broken.join("dataset.json"), serde_json::to_vec(&described).expect("json")).expect("write");

    let run = check_bop(&broken);
    let errors = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(1), "{errors}");
    assert!(errors.contains("median depth error"), "{errors}");
    assert!(errors.contains("vertex normals differ"), "{errors}");
    assert!(errors.contains(&format!("area {} != {area}", area + 1)), "{errors}");
    assert!(errors.contains("bbox_visib"), "{errors}");
    assert!(errors.contains("camera.json K"), "{errors}");
    assert!(errors.contains("test_targets_bop19.json"), "{errors}");
    assert!(errors.contains("off the model's surface"), "{errors}");
    assert!(errors.contains("from every vertex"), "{errors}");
}

#[test]
fn converting_twice_writes_the_same_bytes() {
    let again = tempfile::tempdir().expect("tempdir");
    let out = again.path().join("bop");
    let run = vintctl(&["convert", path_str(tiny()), "--out", path_str(&out), "--format", "bop", "--json"]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let (a, b) = (files_of(bop()), files_of(&out));
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    for (name, bytes) in &a {
        assert!(b[name] == *bytes, "{name} differs between two conversions");
    }
}

/// Every file under `root` by its path relative to it.
pub(crate) fn files_of(root: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut files = BTreeMap::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).expect("dir") {
            let path = entry.expect("entry").path();
            if path.is_dir() {
                stack.push(path);
            } else {
                let name = path.strip_prefix(root).expect("under root").to_string_lossy().into_owned();
                files.insert(name, std::fs::read(&path).expect("read"));
            }
        }
    }
    files
}

pub(crate) fn copy_dir(from: &Path, to: &Path) {
    for (name, bytes) in files_of(from) {
        let path = to.join(name);
        std::fs::create_dir_all(path.parent().expect("parent")).expect("mkdir");
        std::fs::write(path, bytes).expect("write");
    }
}

#[test]
fn test_targets_are_what_the_toolkit_enumerates_for_the_test_split() {
    // Tiny's split puts no grasp in test: a copy whose every grasp is a test grasp has targets.
    let copy = tempfile::tempdir().expect("tempdir");
    let native = copy.path().join("native");
    copy_dir(tiny(), &native);
    let mut dataset = read_json(&native.join("dataset.json"));
    for split in dataset["split"]["grasps"].as_object_mut().expect("grasps").values_mut() {
        *split = Value::from("test");
    }
    std::fs::write(native.join("dataset.json"), serde_json::to_vec(&dataset).expect("json")).expect("write");
    let out = copy.path().join("bop");
    let run = vintctl(&["convert", path_str(&native), "--out", path_str(&out), "--format", "bop"]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let check = check_bop(&out);
    assert!(
        check.status.success(),
        "check_bop.py failed:\n{}\n{}",
        stdout(&check),
        String::from_utf8_lossy(&check.stderr)
    );
    let summary: Value = serde_json::from_str(&stdout(&check)).expect("check_bop prints JSON");
    let samples: usize = native_samples().values().map(BTreeMap::len).sum();
    let targets = &summary["targets"];
    assert_eq!(targets["test_images"].as_u64(), Some(samples as u64), "{summary}");
    assert_eq!(targets["bop24"], targets["test_images"], "{summary}");
    assert!(targets["bop19"].as_u64().is_some_and(|n| n > 0), "tiny's views see their object: {summary}");
}
