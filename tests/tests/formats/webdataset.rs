//! The WebDataset export of tiny: its shards read back by Python's own tar reader and compared
//! with the native manifest (every native file of every sample, byte for byte, under the sample's
//! key; fixed ustar metadata), the split and shard counts against the native `dataset.json`, and
//! the PyTorch loader example (`examples/webdataset_loader.py`) run over it with 0 and 2 DataLoader
//! workers, its poses and camera-frame touch points checked against values computed here from the
//! native `meta.json` and `grasp.json`.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::process::Command;

use serde_json::Value;
use vint_tests::{python, repo_root, stderr, stdout, vintctl};

use super::{path_str, tiny, webdataset};

fn read_json(path: &Path) -> Value {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_slice(&bytes).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The native manifest's lines: sample id → {file name → sha256}, and grasp id → grasp.json's sha256.
fn native_manifest(native: &Path) -> (BTreeMap<String, BTreeMap<String, String>>, BTreeMap<String, String>) {
    let text = std::fs::read_to_string(native.join("manifest.jsonl")).expect("native manifest");
    let (mut samples, mut grasps) = (BTreeMap::new(), BTreeMap::new());
    for line in text.lines() {
        let line: Value = serde_json::from_str(line).expect("manifest line");
        let files = line["files"].as_object().expect("files");
        let hashes = files.iter().map(|(n, f)| (n.clone(), f["sha256"].as_str().expect("sha").to_string()));
        if let Some(id) = line["sample_id"].as_str() {
            samples.insert(id.to_string(), hashes.collect());
        } else if let Some(id) = line["grasp_id"].as_str() {
            grasps.insert(id.to_string(), files["grasp.json"]["sha256"].as_str().expect("sha").to_string());
        }
    }
    (samples, grasps)
}

/// Samples per split, from the native dataset.json's split of grasps and the native sample ids.
fn native_split_counts(native: &Path, samples: &BTreeMap<String, BTreeMap<String, String>>) -> BTreeMap<String, usize> {
    let record = read_json(&native.join("dataset.json"));
    let mut counts = BTreeMap::new();
    for id in samples.keys() {
        let grasp = id.rsplit_once('.').expect("a view suffix").0;
        let split = record["split"]["grasps"][grasp].as_str().unwrap_or_else(|| panic!("{grasp} has no split"));
        *counts.entry(split.to_string()).or_insert(0) += 1;
    }
    counts
}

fn shard_files(out: &Path) -> Vec<String> {
    let index = read_json(&out.join("shards.json"));
    let mut paths = Vec::new();
    for split in index["splits"].as_object().expect("splits").values() {
        for shard in split["shards"].as_array().expect("shards") {
            paths.push(path_str(&out.join(shard["path"].as_str().expect("path"))).to_string());
        }
    }
    paths
}

/// Every member of the export's shards, as Python's tarfile reads them.
fn tar_members(out: &Path) -> Vec<Value> {
    let run = Command::new(python())
        .arg(repo_root().join("tests/python/tar_members.py"))
        .args(shard_files(out))
        .output()
        .expect("run tar_members.py");
    assert!(run.status.success(), "tar_members.py failed:\n{}", stderr(&run));
    stdout(&run).lines().map(|l| serde_json::from_str(l).expect("member line")).collect()
}

#[test]
fn shards_hold_every_native_file_of_every_sample_under_its_key_with_fixed_ustar_metadata() {
    let (native, out) = (tiny(), webdataset());
    let (samples, grasps) = native_manifest(native);
    assert!(samples.len() >= 24, "tiny has {} samples: too few to exercise the shards", samples.len());
    let members = tar_members(out);

    let mut found: BTreeMap<String, BTreeMap<String, String>> = BTreeMap::new();
    for m in &members {
        assert_eq!(m["regular"], true, "{m}");
        assert_eq!((m["mode"].as_u64(), m["uid"].as_u64(), m["gid"].as_u64()), (Some(0o644), Some(0), Some(0)), "{m}");
        assert_eq!(m["mtime"], 0, "{m}");
        assert_eq!((m["uname"].as_str(), m["gname"].as_str()), (Some(""), Some("")), "{m}");
        assert_eq!(m["magic"], "ustar\u{0}00", "POSIX ustar: {m}");
        let name = m["name"].as_str().expect("name");
        // A loader's key: the path up to the first dot of the file name.
        let (key, ext) = name.split_once('.').expect("key.ext");
        let id = key.replace('/', ".");
        let previous = found.entry(id).or_default().insert(ext.to_string(), m["sha256"].as_str().expect("sha").into());
        assert!(previous.is_none(), "{name} twice");
    }
    assert_eq!(found.keys().collect::<Vec<_>>(), samples.keys().collect::<Vec<_>>(), "every sample exactly once");
    for (id, files) in &samples {
        let got = &found[id];
        for (name, sha) in files {
            assert_eq!(got.get(name), Some(sha), "{id}: {name} is the native file's bytes");
        }
        let grasp = id.rsplit_once('.').expect("view suffix").0;
        assert_eq!(got.get("grasp.json"), Some(&grasps[grasp]), "{id}: its grasp's record");
        let extra: BTreeSet<&str> =
            got.keys().map(String::as_str).filter(|n| !files.contains_key(*n) && *n != "grasp.json").collect();
        assert_eq!(extra, BTreeSet::from(["sample.json"]), "{id}");
    }
}

#[test]
fn shard_index_and_dataset_record_agree_with_the_native_split() {
    let (native, out) = (tiny(), webdataset());
    let (samples, _) = native_manifest(native);
    let expected = native_split_counts(native, &samples);

    let record = read_json(&out.join("dataset.json"));
    let mut native_record = read_json(&native.join("dataset.json"));
    assert_eq!(record["format"], "vint-webdataset");
    native_record["format"] = record["format"].clone();
    assert_eq!(record, native_record, "the native record but for its format");
    for object in record["objects"].as_array().expect("objects") {
        let model = object["model"].as_str().expect("model");
        assert_eq!(
            std::fs::read(out.join(model)).expect("model in the export"),
            std::fs::read(native.join(model)).expect("native model"),
            "{model}"
        );
    }

    let index = read_json(&out.join("shards.json"));
    assert_eq!(index["samples"].as_u64(), Some(samples.len() as u64), "the native dataset's samples");
    let members = tar_members(out);
    for (split, listed) in index["splits"].as_object().expect("splits") {
        assert_eq!(listed["samples"].as_u64(), Some(expected.get(split).copied().unwrap_or(0) as u64), "{split}");
        let mut total = 0;
        for shard in listed["shards"].as_array().expect("shards") {
            let path = path_str(&out.join(shard["path"].as_str().expect("path"))).to_string();
            let keys: BTreeSet<&str> = members
                .iter()
                .filter(|m| m["shard"] == path.as_str())
                .filter_map(|m| m["name"].as_str()?.split_once('.').map(|(k, _)| k))
                .collect();
            assert_eq!(shard["samples"].as_u64(), Some(keys.len() as u64), "{path}");
            assert!(keys.len() <= index["shard_samples"].as_u64().expect("shard_samples") as usize);
            assert_eq!(std::fs::metadata(&path).expect("shard").len(), shard["bytes"].as_u64().expect("bytes"));
            total += keys.len();
        }
        assert_eq!(total as u64, listed["samples"].as_u64().expect("samples"), "{split}");
    }
}

/// Runs the loader example over `out` and returns its sample lines (sorted by id) and summary.
fn run_loader(out: &Path, workers: u32) -> (Vec<Value>, Value) {
    let run = Command::new(python())
        .arg(repo_root().join("examples/webdataset_loader.py"))
        .arg(out)
        .args(["--json", "--batch-size", "8", "--workers", &workers.to_string()])
        .output()
        .expect("run the loader example");
    assert!(
        run.status.success(),
        "webdataset_loader.py --workers {workers} failed:\n{}\n{}",
        stdout(&run),
        stderr(&run)
    );
    let mut lines: Vec<Value> = stdout(&run).lines().map(|l| serde_json::from_str(l).expect("json line")).collect();
    let summary = lines.pop().expect("a summary line")["summary"].clone();
    lines.sort_by(|a, b| a["sample_id"].as_str().cmp(&b["sample_id"].as_str()));
    (lines, summary)
}

/// Rotation matrix of a unit quaternion [w, x, y, z].
fn rotation(q: &[f64]) -> [[f64; 3]; 3] {
    let (w, x, y, z) = (q[0], q[1], q[2], q[3]);
    [
        [w * w + x * x - y * y - z * z, 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), w * w - x * x + y * y - z * z, 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), w * w - x * x - y * y + z * z],
    ]
}

fn apply(r: &[[f64; 3]; 3], p: [f64; 3], t: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| r[i][0] * p[0] + r[i][1] * p[1] + r[i][2] * p[2] + t[i])
}

fn vec3(v: &Value) -> [f64; 3] {
    std::array::from_fn(|i| v[i].as_f64().expect("a number"))
}

fn mat3(v: &Value) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| vec3(&v[i]))
}

fn close(a: &Value, b: f64, what: &str) {
    let a = a.as_f64().unwrap_or_else(|| panic!("{what}: not a number"));
    assert!((a - b).abs() < 1e-5, "{what}: {a} vs {b}");
}

#[test]
fn loader_example_yields_every_sample_once_as_tensors_with_0_and_2_workers() {
    let (native, out) = (tiny(), webdataset());
    let (samples, _) = native_manifest(native);
    // Shards of 7 samples as well, so that two workers each get shards of a split.
    let small = out.with_file_name("out-webdataset-7");
    let run = vintctl(&[
        "convert",
        path_str(native),
        "--out",
        path_str(&small),
        "--format",
        "webdataset",
        "--shard-samples",
        "7",
    ]);
    assert!(run.status.success(), "convert --shard-samples 7:\n{}\n{}", stdout(&run), stderr(&run));
    assert!(shard_files(&small).len() > shard_files(out).len());

    let (lines, summary) = run_loader(out, 0);
    let (lines_2, summary_2) = run_loader(&small, 2);
    assert_eq!(lines, lines_2, "0 workers over one shard per split, 2 over shards of 7: the same samples");
    assert_eq!(summary["splits"], summary_2["splits"]);
    assert_eq!(summary["samples"].as_u64(), Some(samples.len() as u64), "the native dataset's samples");
    let ids: Vec<&str> = lines.iter().map(|l| l["sample_id"].as_str().expect("id")).collect();
    assert_eq!(ids, samples.keys().map(String::as_str).collect::<Vec<_>>(), "every sample id once");
    let expected = native_split_counts(native, &samples);
    for (split, n) in summary["splits"].as_object().expect("splits") {
        assert_eq!(n.as_u64(), Some(expected.get(split).copied().unwrap_or(0) as u64), "{split}");
    }

    let mut touch_points = 0;
    for line in &lines {
        let id = line["sample_id"].as_str().expect("id");
        let meta = read_json(&native.join(id).join("meta.json"));
        let grasp = read_json(&native.join(id.rsplit_once('.').expect("view").0).join("grasp.json"));
        let camera = &meta["camera"];
        let (h, w) = (camera["height"].as_u64().expect("height"), camera["width"].as_u64().expect("width"));
        assert_eq!(line["rgb"], serde_json::json!([3, h, w]), "{id}");
        assert_eq!(line["depth"], serde_json::json!([h, w]), "{id}");
        assert_eq!(line["mask_px"], camera["visible_px"], "{id}: mask pixels are the visible pixels");
        for i in 0..3 {
            close(&line["t"][i], camera["t_m2c"][i].as_f64().expect("t"), id);
            for j in 0..3 {
                close(&line["R"][i][j], camera["R_m2c"][i][j].as_f64().expect("R"), id);
            }
        }
        // Active taxels: palm frame → world (the hand's pose) → camera (R_w2c, t_w2c).
        let hand = &meta["poses"]["hand"];
        let q: Vec<f64> = hand["q"].as_array().expect("q").iter().filter_map(Value::as_f64).collect();
        let (r_palm, p_palm) = (rotation(&q), vec3(&hand["p"]));
        let (r_w2c, t_w2c) = (mat3(&camera["R_w2c"]), vec3(&camera["t_w2c"]));
        let active = grasp["touch"]["active"].as_array().expect("active taxels");
        let touch = line["touch"].as_array().expect("touch points");
        assert_eq!(touch.len(), active.len(), "{id}");
        for (got, taxel) in touch.iter().zip(active) {
            let p_cam = apply(&r_w2c, apply(&r_palm, vec3(&taxel["p_palm"]), p_palm), t_w2c);
            for k in 0..3 {
                close(&got[k], p_cam[k], id);
            }
        }
        touch_points += active.len();
    }
    assert_eq!(summary["touch_points"], touch_points);
    assert_eq!(summary["shapes"]["K"], serde_json::json!([3, 3]));
}
