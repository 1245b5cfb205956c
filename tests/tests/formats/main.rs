//! The dataset formats end to end: examples/tiny.toml is run once per test process in the native
//! layout, converted to BOP's layout, to WebDataset shards and to BOP-webdataset shards with
//! `vintctl convert`, and each module checks one format or one consumer of them (an independent
//! re-projection of the BOP export, the PyTorch loader example, the `webdataset` and `wids` readers,
//! `vintctl eval`, `vintctl stats`, `vintctl preview`).

mod bop;
mod bop_webdataset;
mod eval;
mod images;
mod preview;
mod stats;
mod touch;
mod webdataset;

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use vint_tests::{stdout, vintctl};

struct Fixture {
    _dir: tempfile::TempDir,
    native: PathBuf,
}

fn fixture() -> &'static Fixture {
    static FIXTURE: OnceLock<Fixture> = OnceLock::new();
    FIXTURE.get_or_init(|| {
        let dir = tempfile::tempdir().expect("tempdir");
        let out = vint_tests::run_tiny(dir.path(), 2);
        assert!(out.status.success(), "tiny run failed:\n{}\n{}", stdout(&out), String::from_utf8_lossy(&out.stderr));
        let native = dir.path().join("out");
        Fixture { _dir: dir, native }
    })
}

/// The tiny dataset in the native layout.
pub fn tiny() -> &'static Path {
    &fixture().native
}

fn converted(format: &str, cell: &'static OnceLock<PathBuf>) -> &'static Path {
    cell.get_or_init(|| {
        let out = tiny().with_file_name(format!("out-{format}"));
        let args = ["convert", path_str(tiny()), "--out", path_str(&out), "--format", format, "--json"];
        let run = vintctl(&args);
        assert!(
            run.status.success(),
            "vintctl convert --format {format} failed:\n{}\n{}",
            stdout(&run),
            String::from_utf8_lossy(&run.stderr)
        );
        out
    })
}

/// The tiny dataset in BOP's layout.
pub fn bop() -> &'static Path {
    static BOP: OnceLock<PathBuf> = OnceLock::new();
    converted("bop", &BOP)
}

/// The tiny dataset as WebDataset shards (the default shard size).
pub fn webdataset() -> &'static Path {
    static WDS: OnceLock<PathBuf> = OnceLock::new();
    converted("webdataset", &WDS)
}

pub fn path_str(p: &Path) -> &str {
    p.to_str().expect("test paths are UTF-8")
}

/// A built-in object is a procedural stand-in: its BOP id is its own (never ycbv's 1–21, where
/// a dataset mixed with ycbv would take it for the scanned model, nor a user object's 1001 up),
/// and dataset.json says which ycbv object it stands in for, as BOP's ycbv numbers them.
#[test]
fn built_in_objects_export_ids_of_their_own_and_name_the_ycbv_object_they_stand_in_for() {
    let record: serde_json::Value =
        serde_json::from_slice(&std::fs::read(tiny().join("dataset.json")).expect("dataset.json")).expect("json");
    // BOP's ycbv models_info.json: 005 tomato soup can = 4, 006 mustard bottle = 5, 025 mug = 14.
    let ycbv = [("tomato_soup_can", "005", 4), ("mustard_bottle", "006", 5), ("mug", "025", 14)];
    let objects = record["objects"].as_array().expect("objects");
    assert_eq!(objects.len(), ycbv.len());
    for (name, ycb, ycbv_id) in ycbv {
        let o = objects.iter().find(|o| o["name"] == name).expect("tiny's object");
        let id = o["obj_id"].as_u64().expect("obj_id");
        assert!(!(1..=21).contains(&id), "{name}: obj_id {id} is a ycbv id");
        assert!((101..1001).contains(&id), "{name}: obj_id {id}");
        assert_eq!(Some(id), vint_core::catalog::obj_id(name).map(u64::from), "{name}");
        assert_eq!(o["model_source"], "procedural", "{name}");
        assert_eq!(o["ycb_id"], ycb, "{name}");
        assert_eq!(
            o["stand_in_for"],
            serde_json::json!({"dataset": "ycbv", "obj_id": ycbv_id, "ycb_id": ycb}),
            "{name}"
        );
    }
}

/// The native export has each object's model once and a dataset record whose split covers every
/// grasp, views of one grasp never apart.
#[test]
fn native_export_has_models_and_a_split_of_every_grasp() {
    let dir = tiny();
    vint_tests::verify_dataset(dir);
    let record: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("dataset.json")).expect("dataset.json")).expect("json");
    let objects = record["objects"].as_array().expect("objects");
    assert_eq!(objects.len(), 3, "tiny has three objects");
    for o in objects {
        let model = dir.join(o["model"].as_str().expect("model path"));
        assert!(model.is_file(), "{}", model.display());
        assert!(o["diameter_mm"].as_f64().is_some_and(|d| d > 50.0 && d < 400.0), "{o}");
    }
    let grasps: Vec<String> = std::fs::read_dir(dir)
        .expect("dataset dir")
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|n| n.parse::<vint_core::GraspId>().is_ok())
        .collect();
    let split = record["split"]["grasps"].as_object().expect("split.grasps");
    assert_eq!(split.len(), grasps.len(), "every grasp has a split");
    let mut tally = std::collections::BTreeMap::new();
    for g in &grasps {
        *tally.entry(split[g].as_str().expect("split name")).or_insert(0) += 1;
    }
    let n = grasps.len();
    assert_eq!(tally.values().sum::<usize>(), n);
    assert!(tally.get("train").copied().unwrap_or(0) >= n * 7 / 10, "{tally:?}");
    let pairs = record["pairs"].as_array().expect("pairs");
    assert_eq!(pairs.len(), 6, "2 hands × 3 objects");
    let accepted: u64 = pairs.iter().map(|p| p["accepted"].as_u64().expect("accepted")).sum();
    assert_eq!(accepted as usize, n, "accepted trials are the grasps packaged");
    for p in pairs {
        let rejected: u64 = p["rejected"].as_object().expect("rejected").values().filter_map(|v| v.as_u64()).sum();
        assert_eq!(p["trials"].as_u64(), Some(p["accepted"].as_u64().unwrap_or(0) + rejected), "{p}");
    }
}

/// Converting a dataset into itself (or into a folder inside it) would replace the input: refused
/// as bad input, and the dataset stays whole.
#[test]
fn converting_into_the_dataset_itself_is_refused_and_loses_nothing() {
    let dir = tiny();
    for out in [dir.to_path_buf(), dir.join("bop")] {
        let run = vintctl(&["convert", path_str(dir), "--out", path_str(&out), "--format", "bop"]);
        assert_eq!(run.status.code(), Some(2), "{}", String::from_utf8_lossy(&run.stderr));
        assert!(String::from_utf8_lossy(&run.stderr).contains("overlaps the dataset being converted"));
    }
    vint_tests::verify_dataset(dir);
    // Only the native layout converts: a BOP export is no input for WebDataset shards.
    let out = dir.with_file_name("out-from-bop");
    let run = vintctl(&["convert", path_str(bop()), "--out", path_str(&out), "--format", "webdataset"]);
    assert_eq!(run.status.code(), Some(2), "{}", String::from_utf8_lossy(&run.stderr));
    assert!(
        String::from_utf8_lossy(&run.stderr).contains("says \"vint-bop\""),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    assert!(!out.exists());
}
