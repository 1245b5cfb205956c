//! `vintctl preview` on the tiny dataset: one valid PNG of a header and, per sample, a caption
//! over a row of five tiles (RGB, depth, noisy depth, segmentation, taxels) 320 px wide and as
//! high as the image's aspect keeps them; the samples it shows spread over (object, hand) pairs.
//! Where the dots land is held to an independent projection in
//! `workers/engines/tests/test_preview.py`.

use std::collections::BTreeSet;

use serde_json::{Value, json};
use vint_tests::{stderr, stdout, vintctl};

use super::stats::assert_valid_png;
use super::{path_str, tiny};

const COLUMNS: u32 = 5;
const TILE_WIDTH: u32 = 320;
const TINY_RESOLUTION: (u32, u32) = (128, 128); // examples/tiny.toml

fn meta(sample: &str) -> Value {
    let path = tiny().join(sample).join("meta.json");
    serde_json::from_slice(&std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display())))
        .expect("meta.json is JSON")
}

#[test]
fn preview_of_tiny_is_a_png_of_samples_by_five_tiles() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let out = tmp.path().join("sheets").join("tiny.png");
    let run = vintctl(&["preview", path_str(tiny()), "--out", path_str(&out), "--samples", "3", "--json"]);
    assert!(run.status.success(), "vintctl preview failed:\n{}\n{}", stdout(&run), stderr(&run));
    let summary: Value = serde_json::from_str(&stdout(&run)).expect("preview --json prints JSON");
    assert_eq!(summary["path"], path_str(&out));

    let tile = TILE_WIDTH * TINY_RESOLUTION.1 / TINY_RESOLUTION.0; // the image's aspect
    assert_eq!(summary["tile"], json!([TILE_WIDTH, tile]));
    let samples: Vec<&str> = summary["samples"].as_array().expect("samples").iter().filter_map(Value::as_str).collect();
    assert_eq!(samples.len(), 3, "{summary}");
    let (header, caption) =
        (summary["header_px"].as_u64().unwrap() as u32, summary["caption_px"].as_u64().unwrap() as u32);
    assert!(header > 0 && caption > 0 && header < tile && caption < tile, "{summary}");
    let (width, height) = assert_valid_png(&out);
    assert_eq!((width, height), (COLUMNS * TILE_WIDTH, header + 3 * (caption + tile)));
    assert_eq!(summary["size"], json!([width, height]));

    // Spread: tiny has both hands on three objects, and the first picks change both.
    let pair_of = |sample: &str| {
        let m = meta(sample);
        (m["object"]["name"].as_str().unwrap().to_string(), m["hand"].as_str().unwrap().to_string())
    };
    let shown: BTreeSet<(String, String)> = samples.iter().map(|s| pair_of(s)).collect();
    let all: BTreeSet<(String, String)> = std::fs::read_dir(tiny())
        .expect("tiny")
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|name| tiny().join(name).join("meta.json").is_file())
        .map(|name| pair_of(&name))
        .collect();
    let count = |pairs: &BTreeSet<(String, String)>| {
        let objects: BTreeSet<&String> = pairs.iter().map(|(o, _)| o).collect();
        let hands: BTreeSet<&String> = pairs.iter().map(|(_, h)| h).collect();
        (pairs.len(), objects.len(), hands.len())
    };
    let (_, objects, hands) = count(&all);
    assert_eq!(count(&shown), (3, objects.min(3), hands.min(2)), "{shown:?} of {all:?}");
}

#[test]
fn preview_of_no_dataset_is_bad_input_naming_the_path() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let out = tmp.path().join("sheet.png");
    let missing = tmp.path().join("no-such-dataset");
    for (subject, says) in [(tmp.path(), "no samples"), (missing.as_path(), "is not a dataset directory")] {
        let run = vintctl(&["preview", path_str(subject), "--out", path_str(&out), "--json"]);
        assert_eq!(run.status.code(), Some(2), "{}", stderr(&run));
        let error: Value = serde_json::from_str(stdout(&run).trim()).expect("error JSON");
        let message = error["error"]["message"].as_str().unwrap_or_default();
        assert!(message.contains(path_str(subject)) && message.contains(says), "{error}");
        assert!(!out.exists());
    }
}
