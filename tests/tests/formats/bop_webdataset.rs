//! The BOP-webdataset export of tiny, in shards of 5 images so that every split with images has
//! several: read by `tests/python/check_bop_webdataset.py` with the `webdataset` package (in
//! sequence) and with `wids` (by index), every member decoded and compared with the BOP export of
//! the same dataset, the shard order recomputed from the documented rule; checks that the script
//! fails on a wrong order and on a wrong pose; the same bytes from two conversions.

use std::path::{Path, PathBuf};
use std::process::Output;
use std::sync::OnceLock;

use serde_json::Value;
use vint_tests::{python, repo_root, stderr, stdout, vintctl};

use super::bop::{copy_dir, files_of};
use super::{bop, path_str, tiny};

const SHARD_SAMPLES: &str = "5";

fn convert(out: &Path) {
    let args = ["convert", path_str(tiny()), "--out", path_str(out), "--format", "bop-webdataset"];
    let run = vintctl(&[&args[..], &["--shard-samples", SHARD_SAMPLES, "--json"]].concat());
    assert!(run.status.success(), "convert --format bop-webdataset:\n{}\n{}", stdout(&run), stderr(&run));
}

/// The tiny dataset as BOP-webdataset shards of 5 images.
fn exported() -> &'static Path {
    static OUT: OnceLock<PathBuf> = OnceLock::new();
    OUT.get_or_init(|| {
        let out = tiny().with_file_name("out-bop-webdataset-5");
        convert(&out);
        out
    })
}

fn check(wds: &Path, bop: &Path) -> Output {
    std::process::Command::new(python())
        .arg(repo_root().join("tests/python/check_bop_webdataset.py"))
        .args([wds, bop])
        .output()
        .expect("running check_bop_webdataset.py")
}

fn native_samples() -> usize {
    let manifest = std::fs::read_to_string(tiny().join("manifest.jsonl")).expect("native manifest");
    manifest.lines().filter(|l| l.contains("\"sample_id\"")).count()
}

#[test]
fn shards_load_with_webdataset_and_wids_every_member_decodes_and_matches_the_bop_export() {
    let run = check(exported(), bop());
    assert!(run.status.success(), "check_bop_webdataset.py failed:\n{}\n{}", stdout(&run), stderr(&run));
    let summary: Value = serde_json::from_str(&stdout(&run)).expect("the check prints JSON");
    assert_eq!(summary["images"].as_u64(), Some(native_samples() as u64), "every native sample once: {summary}");
    let splits = summary["splits"].as_object().expect("splits");
    let train = &splits["train"];
    assert!(train["shards"].as_u64().is_some_and(|n| n > 1), "several shards to order: {summary}");
    for (split, s) in splits {
        let images = s["images"].as_u64().expect("images");
        assert_eq!(s["shards"].as_u64(), Some(images.div_ceil(5)), "{split}: shards of 5");
        assert!(s["members_compared"].as_u64().is_some_and(|m| m >= images * 8), "{split}: {s}");
    }
    let record: Value =
        serde_json::from_slice(&std::fs::read(exported().join("dataset.json")).expect("dataset.json")).expect("json");
    assert_eq!(record["format"], "vint-bop-webdataset");
    for o in record["objects"].as_array().expect("objects") {
        let model = o["model"].as_str().expect("model");
        assert_eq!(
            std::fs::read(exported().join(model)).expect("model in the export"),
            std::fs::read(bop().join(model)).expect("the BOP export's model"),
            "{model}: BOP's model, in mm with normals"
        );
    }
}

/// The check must be able to fail: an order drawn from another seed, and a pose off by a
/// millimetre in the BOP export it compares with.
#[test]
fn the_check_fails_on_another_seeds_order_and_on_a_different_pose() {
    let dir = tempfile::tempdir().expect("tempdir");
    let wds = dir.path().join("wds");
    copy_dir(exported(), &wds);
    let mut record: Value =
        serde_json::from_slice(&std::fs::read(wds.join("dataset.json")).expect("dataset.json")).expect("json");
    record["seed"] = Value::from(record["seed"].as_u64().expect("seed") + 1);
    std::fs::write(wds.join("dataset.json"), serde_json::to_vec(&record).expect("json")).expect("write");
    let run = check(&wds, bop());
    assert!(!run.status.success(), "another seed's order passed:\n{}", stdout(&run));
    assert!(stderr(&run).contains("shard order is not the seeded shuffle"), "{}", stderr(&run));

    let moved = dir.path().join("bop");
    copy_dir(bop(), &moved);
    let described: Value =
        serde_json::from_slice(&std::fs::read(moved.join("dataset.json")).expect("dataset.json")).expect("json");
    let split = described["bop"]["scenes"][0]["split"].as_str().expect("scene 0's split");
    let scene = moved.join(split).join("000000/scene_gt.json");
    let mut gt: Value = serde_json::from_slice(&std::fs::read(&scene).expect("scene_gt.json")).expect("json");
    let first = gt.as_object_mut().expect("per image").values_mut().next().expect("an image");
    first[0]["cam_t_m2c"][0] = Value::from(first[0]["cam_t_m2c"][0].as_f64().expect("t") + 1.0);
    std::fs::write(&scene, serde_json::to_vec(&gt).expect("json")).expect("write");
    let run = check(exported(), &moved);
    assert!(!run.status.success(), "a moved pose passed:\n{}", stdout(&run));
    assert!(stderr(&run).contains("gt.json ≠ scene_gt.json"), "{}", stderr(&run));
}

#[test]
fn converting_twice_writes_the_same_bytes() {
    let again = tempfile::tempdir().expect("tempdir");
    let out = again.path().join("wds");
    convert(&out);
    let (a, b) = (files_of(exported()), files_of(&out));
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    for (name, bytes) in &a {
        assert!(b[name] == *bytes, "{name} differs between two conversions");
    }
}
