//! WebDataset shards (`--format webdataset`): per split, tar files `<split>/<split>-NNNNNN.tar` of
//! at most `--shard-samples` samples each, for loaders that stream samples from shards (the
//! `webdataset` package, `examples/webdataset_loader.py`). Layout and member names:
//! `docs/formats.md`, "WebDataset".
//!
//! A loader groups a shard's consecutive members by key: a member's path up to the first dot of its
//! file name. Sample ids hold dots (`mug.allegro.g000001.v00`), so a sample's key is its id with
//! the dots turned into slashes (`mug/allegro/g000001/v00`): names are `[a-z0-9_]`, so the key maps
//! back to exactly one id, and the path splits into ustar's prefix and name fields however long the
//! object and hand names are (64 characters at most each). Every sample carries its own copy of its
//! grasp's record, so any sample — and any shard — stands alone; a grasp's views may therefore span
//! two shards. Samples are in id order (a grasp's views next to each other): shuffling is the
//! loader's business.
//!
//! The shards are plain ustar with fixed metadata (mtime 0, uid/gid 0, mode 0644, no user names)
//! and members in name order, so equal native datasets give equal shards. They are streamed member
//! by member from the native files; no shard is held in memory. This module reads only the native
//! directory and writes only `out`.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter};
use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow, bail};
use serde::{Deserialize, Serialize};
use serde_json::Value;
use vint_core::SampleId;
use vint_core::contract::package::GRASP_RECORD_FILE;

use super::Converted;
use super::ustar;

/// `dataset.json`'s `format` in a WebDataset export.
pub const FORMAT: &str = "vint-webdataset";
/// The shards of each split, with their sample counts, at the output's root.
pub const INDEX_FILE: &str = "shards.json";
/// The member naming the sample (its real id, grasp, view and split).
pub const SAMPLE_RECORD: &str = "sample.json";
/// The splits a dataset's grasps are assigned to (`dataset.json`'s `split.grasps`).
const SPLITS: [&str; 3] = vint_core::split::Split::NAMES;

/// The shard key of a sample: its id with dots turned into slashes.
pub fn sample_key(id: &SampleId) -> String {
    id.to_string().replace('.', "/")
}

/// A shard's path relative to the output's root: `train/train-000000.tar`.
pub fn shard_path(split: &str, index: usize) -> String {
    format!("{split}/{split}-{index:06}.tar")
}

/// Writes the native dataset at `native` as shards of at most `shard_samples` samples into the empty
/// directory `out`, with `dataset.json` (the native record, `format` changed), the models and the
/// shard index.
pub fn write(native: &Path, out: &Path, shard_samples: usize) -> anyhow::Result<Converted> {
    if shard_samples == 0 {
        bail!("a shard must hold at least one sample");
    }
    let mut dataset = read_json(&native.join("dataset.json"))?;
    let splits = grasp_splits(&dataset)?;
    let samples = native_samples(native)?;
    let mut by_split: BTreeMap<&str, Vec<&NativeSample>> = SPLITS.iter().map(|s| (*s, Vec::new())).collect();
    for sample in &samples {
        let grasp = sample.id.grasp().to_string();
        let split = splits.get(&grasp).ok_or_else(|| anyhow!("{}: grasp {grasp} is in no split", sample.id))?;
        by_split.entry(split.as_str()).or_default().push(sample);
    }

    let mut written = Written::default();
    let mut index = ShardIndex { format: FORMAT, shard_samples, samples: samples.len(), splits: BTreeMap::new() };
    for (split, members) in &by_split {
        let mut listed = SplitShards { samples: members.len(), shards: Vec::new() };
        for (n, chunk) in members.chunks(shard_samples).enumerate() {
            let path = shard_path(split, n);
            let bytes = write_shard(native, split, chunk, &out.join(&path))?;
            written.add(bytes);
            listed.shards.push(ShardEntry {
                path,
                samples: chunk.len(),
                bytes,
                first: chunk.first().map(|s| s.id.to_string()).unwrap_or_default(),
                last: chunk.last().map(|s| s.id.to_string()).unwrap_or_default(),
            });
        }
        index.splits.insert(split.to_string(), listed);
    }

    written.add_all(copy_models(native, out)?);
    dataset["format"] = Value::from(FORMAT);
    written.add(write_json(&out.join("dataset.json"), &dataset)?);
    written.add(write_json(&out.join(INDEX_FILE), &index)?);
    Ok(Converted { samples: samples.len(), files: written.files, bytes: written.bytes })
}

#[derive(Default)]
struct Written {
    files: usize,
    bytes: u64,
}

impl Written {
    fn add(&mut self, bytes: u64) {
        self.files += 1;
        self.bytes += bytes;
    }

    fn add_all(&mut self, other: Written) {
        self.files += other.files;
        self.bytes += other.bytes;
    }
}

/// `shards.json`: what a loader needs to pick shards and size an epoch without opening one.
#[derive(Serialize)]
struct ShardIndex {
    format: &'static str,
    shard_samples: usize,
    samples: usize,
    splits: BTreeMap<String, SplitShards>,
}

#[derive(Serialize)]
struct SplitShards {
    samples: usize,
    shards: Vec<ShardEntry>,
}

#[derive(Serialize)]
struct ShardEntry {
    path: String,
    samples: usize,
    bytes: u64,
    /// The first and last sample ids in the shard (shards hold samples in id order).
    first: String,
    last: String,
}

/// A sample of the native dataset and the names of its files, as its manifest line lists them.
struct NativeSample {
    id: SampleId,
    files: BTreeMap<String, u64>,
}

#[derive(Deserialize)]
struct ManifestLine {
    sample_id: Option<String>,
    #[serde(default)]
    files: BTreeMap<String, ManifestFile>,
}

#[derive(Deserialize)]
struct ManifestFile {
    size: u64,
}

/// The samples the native `manifest.jsonl` lists, in id order.
fn native_samples(native: &Path) -> anyhow::Result<Vec<NativeSample>> {
    let path = native.join("manifest.jsonl");
    let file = File::open(&path).with_context(|| format!("reading {}", path.display()))?;
    let mut samples = Vec::new();
    for (n, line) in BufReader::new(file).lines().enumerate() {
        let line = line.with_context(|| format!("reading {}", path.display()))?;
        if line.trim().is_empty() {
            continue;
        }
        let entry: ManifestLine = serde_json::from_str(&line)
            .with_context(|| format!("{}:{}: not a manifest line", path.display(), n + 1))?;
        let Some(id) = entry.sample_id else { continue };
        let id: SampleId = id.parse().with_context(|| format!("{}:{}", path.display(), n + 1))?;
        let files = entry.files.into_iter().map(|(name, f)| (name, f.size)).collect();
        samples.push(NativeSample { id, files });
    }
    samples.sort_by(|a, b| a.id.cmp(&b.id));
    Ok(samples)
}

/// `dataset.json`'s `split.grasps`: each grasp id's split.
fn grasp_splits(dataset: &Value) -> anyhow::Result<BTreeMap<String, String>> {
    let grasps = dataset["split"]["grasps"]
        .as_object()
        .ok_or_else(|| anyhow!("dataset.json has no split.grasps (a grasp id → split map)"))?;
    let mut splits = BTreeMap::new();
    for (grasp, split) in grasps {
        let split = split.as_str().filter(|s| SPLITS.contains(s)).ok_or_else(|| {
            anyhow!("dataset.json: grasp {grasp} is in split {split}, not one of {}", SPLITS.join(", "))
        })?;
        splits.insert(grasp.clone(), split.to_string());
    }
    Ok(splits)
}

/// Where a member's bytes come from: a native file (streamed) or a record made here.
enum Body {
    File(PathBuf),
    Bytes(Vec<u8>),
}

/// Writes one shard of `samples` to `path`; returns its size.
fn write_shard(native: &Path, split: &str, samples: &[&NativeSample], path: &Path) -> anyhow::Result<u64> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let file = File::create(path).with_context(|| format!("creating {}", path.display()))?;
    let mut tar = ustar::Writer::new(BufWriter::with_capacity(1 << 20, file));
    for sample in samples {
        for (name, body) in sample_members(native, split, sample)? {
            let member = format!("{}.{name}", sample_key(&sample.id));
            match body {
                Body::Bytes(bytes) => tar.append(&member, bytes.len() as u64, &mut bytes.as_slice()),
                Body::File(file_path) => {
                    let file = File::open(&file_path).with_context(|| format!("reading {}", file_path.display()))?;
                    let size = file.metadata().with_context(|| format!("reading {}", file_path.display()))?.len();
                    if let Some(&listed) = sample.files.get(&name)
                        && listed != size
                    {
                        bail!("{}: {size} bytes, the manifest says {listed}", file_path.display());
                    }
                    tar.append(&member, size, &mut BufReader::new(file))
                }
            }
            .with_context(|| format!("{}: writing {member}", path.display()))?;
        }
    }
    let bytes = tar.finish().with_context(|| format!("writing {}", path.display()))?;
    Ok(bytes)
}

/// A sample's members, by name after the key, in name order: its native files, its grasp's record
/// and the sample record.
fn sample_members(native: &Path, split: &str, sample: &NativeSample) -> anyhow::Result<BTreeMap<String, Body>> {
    let id = sample.id.to_string();
    let grasp = sample.id.grasp().to_string();
    let mut members = BTreeMap::new();
    for name in sample.files.keys() {
        if name.contains('/') || name.starts_with('.') || name == GRASP_RECORD_FILE || name == SAMPLE_RECORD {
            bail!("{id}: refusing native file name {name:?}");
        }
        members.insert(name.clone(), Body::File(native.join(&id).join(name)));
    }
    members.insert(GRASP_RECORD_FILE.to_string(), Body::File(native.join(&grasp).join(GRASP_RECORD_FILE)));
    let record = serde_json::json!({
        "sample_id": id,
        "grasp_id": grasp,
        "view": sample.id.view_index,
        "split": split,
        "key": sample_key(&sample.id),
    });
    members.insert(SAMPLE_RECORD.to_string(), Body::Bytes(serde_json::to_vec(&record)?));
    Ok(members)
}

/// Copies `native/models/*` as they are, so that `dataset.json`'s model paths hold here too.
fn copy_models(native: &Path, out: &Path) -> anyhow::Result<Written> {
    let mut written = Written::default();
    let models = native.join("models");
    if !models.is_dir() {
        return Ok(written);
    }
    let mut names = Vec::new();
    for entry in std::fs::read_dir(&models).with_context(|| format!("listing {}", models.display()))? {
        let entry = entry?;
        if entry.file_type()?.is_file() {
            names.push(entry.file_name());
        }
    }
    names.sort();
    std::fs::create_dir_all(out.join("models")).context("creating models/")?;
    for name in names {
        let bytes = std::fs::copy(models.join(&name), out.join("models").join(&name))
            .with_context(|| format!("copying models/{}", name.to_string_lossy()))?;
        written.add(bytes);
    }
    Ok(written)
}

fn read_json(path: &Path) -> anyhow::Result<Value> {
    let text = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_slice(&text).with_context(|| format!("parsing {}", path.display()))
}

fn write_json(path: &Path, value: &impl Serialize) -> anyhow::Result<u64> {
    let mut bytes = serde_json::to_vec_pretty(value)?;
    bytes.push(b'\n');
    std::fs::write(path, &bytes).with_context(|| format!("writing {}", path.display()))?;
    Ok(bytes.len() as u64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::formats::ustar::testing::{field, read_archive};

    #[test]
    fn long_paths_split_at_a_slash_into_prefix_and_name() {
        let object = "o".repeat(64);
        let hand = "h".repeat(64);
        let id: SampleId = format!("{object}.{hand}.g000001.v00").parse().unwrap();
        let path = format!("{}.segmentation.png", sample_key(&id));
        assert!(path.len() > 100);
        let mut out = Vec::new();
        let mut w = ustar::Writer::new(&mut out);
        w.append(&path, 3, &mut b"abc".as_slice()).unwrap();
        w.finish().unwrap();
        let members = read_archive(&out);
        assert_eq!(members[0].0, path);
        assert_eq!(field(&out, 345..500), object, "the shortest prefix that leaves a name of at most 100 bytes");
        assert!(ustar::header(&"x".repeat(101), 0).is_err(), "no slash to split at");
        assert!(ustar::header(&format!("{}/{}", "p".repeat(156), "n"), 0).is_err(), "prefix too long");
    }
    #[test]
    fn sample_keys_turn_dots_into_slashes_and_back() {
        let id: SampleId = "tomato_soup_can.trx3.g000003.v01".parse().unwrap();
        let key = sample_key(&id);
        assert_eq!(key, "tomato_soup_can/trx3/g000003/v01");
        assert!(!key.contains('.'), "a loader cuts the key at the first dot of the file name");
        assert_eq!(key.replace('/', ".").parse::<SampleId>().unwrap(), id);
        assert_eq!(shard_path("val", 12), "val/val-000012.tar");
    }

    /// A native dataset of `grasps` grasps with `views` views each, split by grasp index.
    fn native_fixture(dir: &Path, grasps: u32, views: u32) -> Vec<SampleId> {
        let mut manifest = String::new();
        let mut split = serde_json::Map::new();
        let mut ids = Vec::new();
        for g in 0..grasps {
            let grasp = vint_core::GraspId { object: "mug".into(), hand: "allegro".into(), grasp_index: g };
            let name = ["train", "val", "test"][(g % 3) as usize];
            split.insert(grasp.to_string(), Value::from(name));
            std::fs::create_dir_all(dir.join(grasp.to_string())).unwrap();
            std::fs::write(dir.join(grasp.to_string()).join("grasp.json"), format!("{{\"grasp\": {g}}}")).unwrap();
            manifest += &format!("{{\"grasp_id\":\"{grasp}\",\"files\":{{\"grasp.json\":{{\"size\":1}}}}}}\n");
            for v in 0..views {
                let id = grasp.view(v);
                let sdir = dir.join(id.to_string());
                std::fs::create_dir_all(&sdir).unwrap();
                let rgb = vec![g as u8; 700 + v as usize];
                std::fs::write(sdir.join("rgb.png"), &rgb).unwrap();
                std::fs::write(sdir.join("meta.json"), format!("{{\"view\": {v}}}")).unwrap();
                let meta_len = std::fs::metadata(sdir.join("meta.json")).unwrap().len();
                manifest += &format!(
                    "{{\"sample_id\":\"{id}\",\"files\":{{\"meta.json\":{{\"size\":{meta_len}}},\"rgb.png\":{{\"size\":{}}}}}}}\n",
                    rgb.len()
                );
                ids.push(id);
            }
        }
        std::fs::create_dir_all(dir.join("models")).unwrap();
        std::fs::write(dir.join("models/mug.ply"), b"ply\n").unwrap();
        let dataset = serde_json::json!({"format": "vint-native", "version": 1, "split": {"grasps": split}});
        std::fs::write(dir.join("dataset.json"), serde_json::to_vec(&dataset).unwrap()).unwrap();
        std::fs::write(dir.join("manifest.jsonl"), manifest).unwrap();
        ids
    }

    #[test]
    fn shards_hold_every_sample_once_in_its_split_with_its_grasp_record() {
        let tmp = tempfile::tempdir().unwrap();
        let (native, out) = (tmp.path().join("native"), tmp.path().join("out"));
        let ids = native_fixture(&native, 7, 3);
        let converted = write(&native, &out, 2).unwrap();
        assert_eq!(converted.samples, 21);

        let index = read_json(&out.join(INDEX_FILE)).unwrap();
        let dataset = read_json(&out.join("dataset.json")).unwrap();
        assert_eq!(dataset["format"], FORMAT);
        assert_eq!(std::fs::read(out.join("models/mug.ply")).unwrap(), b"ply\n");
        let mut seen = Vec::new();
        let mut files = 3; // dataset.json, shards.json, models/mug.ply
        for split in SPLITS {
            let listed = &index["splits"][split];
            let shards = listed["shards"].as_array().unwrap();
            let mut in_split = 0;
            for (n, shard) in shards.iter().enumerate() {
                assert_eq!(shard["path"], shard_path(split, n));
                let bytes = std::fs::read(out.join(shard["path"].as_str().unwrap())).unwrap();
                assert_eq!(shard["bytes"], bytes.len() as u64);
                let members = read_archive(&bytes);
                let mut keys: Vec<&str> = members.iter().map(|m| m.0.split_once('.').unwrap().0).collect();
                keys.dedup();
                assert!(keys.len() <= 2, "at most --shard-samples samples per shard");
                assert_eq!(shard["samples"], keys.len());
                in_split += keys.len();
                files += 1;
                for key in keys {
                    let id: SampleId = key.replace('/', ".").parse().unwrap();
                    let get = |ext: &str| {
                        members.iter().find(|m| m.0 == format!("{key}.{ext}")).map(|m| m.5.clone()).unwrap()
                    };
                    let names: Vec<&str> =
                        members.iter().filter_map(|m| m.0.strip_prefix(&format!("{key}."))).collect();
                    assert_eq!(names, ["grasp.json", "meta.json", "rgb.png", "sample.json"], "sorted members");
                    assert_eq!(get("rgb.png"), vec![id.grasp_index as u8; 700 + id.view_index as usize]);
                    assert_eq!(get("grasp.json"), format!("{{\"grasp\": {}}}", id.grasp_index).into_bytes());
                    let record: Value = serde_json::from_slice(&get("sample.json")).unwrap();
                    assert_eq!(record["sample_id"], id.to_string());
                    assert_eq!(record["split"], split);
                    assert_eq!(dataset["split"]["grasps"][id.grasp().to_string()], split);
                    seen.push(id);
                }
            }
            assert_eq!(listed["samples"], in_split);
        }
        seen.sort();
        assert_eq!(seen, ids, "every sample exactly once");
        assert_eq!(converted.files, files);
    }

    #[test]
    fn equal_native_datasets_give_equal_shards() {
        let tmp = tempfile::tempdir().unwrap();
        let native = tmp.path().join("native");
        native_fixture(&native, 4, 2);
        let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
        write(&native, &a, 3).unwrap();
        // A later mtime on the inputs must not show in the shards.
        std::fs::write(native.join("mug.allegro.g000000.v00/meta.json"), "{\"view\": 0}").unwrap();
        write(&native, &b, 3).unwrap();
        for path in ["train/train-000000.tar", "val/val-000000.tar", "test/test-000000.tar", INDEX_FILE] {
            assert_eq!(std::fs::read(a.join(path)).unwrap(), std::fs::read(b.join(path)).unwrap(), "{path}");
        }
    }

    #[test]
    fn a_file_whose_size_differs_from_the_manifest_is_refused() {
        let tmp = tempfile::tempdir().unwrap();
        let native = tmp.path().join("native");
        native_fixture(&native, 1, 1);
        std::fs::write(native.join("mug.allegro.g000000.v00/rgb.png"), b"short").unwrap();
        let err = write(&native, &tmp.path().join("out"), 10).unwrap_err();
        assert!(format!("{err:#}").contains("the manifest says 700"), "{err:#}");
    }

    #[test]
    fn a_sample_whose_grasp_has_no_split_is_refused() {
        let tmp = tempfile::tempdir().unwrap();
        let native = tmp.path().join("native");
        native_fixture(&native, 2, 1);
        let dataset = serde_json::json!({"split": {"grasps": {"mug.allegro.g000000": "train"}}});
        std::fs::write(native.join("dataset.json"), serde_json::to_vec(&dataset).unwrap()).unwrap();
        let err = write(&native, &tmp.path().join("out"), 10).unwrap_err();
        assert!(err.to_string().contains("grasp mug.allegro.g000001 is in no split"), "{err}");
    }
}
