//! BOP-webdataset (`--format bop-webdataset`): the layout of the BOP 2023 training sets
//! (MegaPose-GSO, MegaPose-ShapeNetCore), as the BOP toolkit's `bop_webdataset.py`,
//! `bop_imagewise.py` and `convert_imagewise_to_webdataset.py` define it, for the loaders that
//! read those sets. Per split, a folder of tar shards `shard-NNNNNN.tar` of at most
//! `--shard-samples` images each; one key per image, `{scene_id:06d}_{im_id:06d}` with the ids of
//! the BOP export (`--format bop`); under it BOP's per-image members (`rgb.png`, `depth.png`,
//! `camera.json`, `gt.json`, `gt_info.json`, `mask.json`, `mask_visib.json`) and ours beside them
//! (`touch.json`, `hand.json`, `meta.json`, `depth_noisy.png`, `segmentation.png`). Each split
//! folder also has the toolkit's `key_to_shard.json` and a `wids` shard index
//! (`shardindex.json`) for random access. `docs/formats.md`, "BOP-webdataset", lists every member.
//!
//! The records are the BOP export's own (`bop::image`): a member is the entry its image has in the
//! scene file of the same name (`gt.json` ↔ `scene_gt.json`), as the toolkit's scenewise →
//! imagewise conversion splits them. Masks are the toolkit's `save_masks` JSON: instance id →
//! COCO's uncompressed RLE.
//!
//! Images are shuffled at write time, as the toolkit's converter does with `--shuffle`, so that a
//! loader reading shards in sequence reads a grasp's views apart. The order is seeded, not random:
//! within a split, images go by increasing `vint_core::seed::shard_rank` of the job seed
//! (`dataset.json`'s `seed`) and the image's sample identity, ties by key. Same input, same bytes.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use anyhow::{Context, anyhow, bail};
use serde_json::json;
use vint_core::SampleId;
use vint_core::contract::package::GRASP_RECORD_FILE;

use super::bop::{self, GT_ID, Grasp, Image, Mask, Objects, Scene, Sink};
use super::{Converted, ustar};

/// `dataset.json`'s `format` in a BOP-webdataset export.
pub const FORMAT: &str = "vint-bop-webdataset";
/// The toolkit's map of image key → shard index, in each split folder.
pub const KEY_TO_SHARD: &str = "key_to_shard.json";
/// The `wids` shard index (`wids-shard-index-v1`) of each split folder.
pub const WIDS_INDEX: &str = "shardindex.json";

/// An image's key: `{scene_id:06d}_{im_id:06d}`, as the toolkit's scenewise → imagewise
/// conversion names it.
pub fn image_key(scene_id: u64, im_id: u32) -> String {
    format!("{scene_id:06}_{im_id:06}")
}

/// A shard's file name in its split folder, as the toolkit's `ShardWriter` pattern names it.
pub fn shard_name(index: usize) -> String {
    format!("shard-{index:06}.tar")
}

/// One image in shard order.
struct Entry<'a> {
    key: String,
    rank: u64,
    scene: &'a Scene<'a>,
    sample_id: &'a str,
}

/// Writes the native dataset at `native` as BOP-webdataset shards of at most `shard_samples`
/// images into the empty directory `out`, with BOP's models (`models/`, `models_eval/`) and a
/// `dataset.json`.
pub fn write(native: &Path, out: &Path, shard_samples: usize) -> anyhow::Result<Converted> {
    if shard_samples == 0 {
        bail!("a shard must hold at least one image");
    }
    let dataset = bop::read_json(&native.join("dataset.json"))?;
    let seed =
        dataset["seed"].as_u64().ok_or_else(|| anyhow!("dataset.json has no seed: the shard order derives from it"))?;
    let objects = Objects::of(&dataset)?;
    let grasps = bop::views_by_grasp(native)?;
    let scenes = bop::scenes(&dataset, &grasps)?;
    let name = dataset["name"].as_str().unwrap_or("vint");
    let mut sink = Sink::new(out);
    let models_eval = bop::write_models(native, &objects, &mut sink)?;

    let mut splits = serde_json::Map::new();
    let mut samples = 0;
    for split in vint_core::split::Split::NAMES {
        let order = shard_order(seed, scenes.iter().filter(|s| s.split == split))?;
        if order.is_empty() {
            continue;
        }
        // Shards are independent (each writes only its own file).
        let shards: Vec<(usize, &[Entry<'_>])> = order.chunks(shard_samples).enumerate().collect();
        let sizes = super::on_all_cores(&shards, |(n, entries)| {
            let path = out.join(split).join(shard_name(*n));
            write_shard(native, &objects, entries, &path).with_context(|| format!("{}", path.display()))
        })?;
        let mut key_to_shard = BTreeMap::new();
        let mut shardlist = Vec::new();
        for ((n, entries), bytes) in shards.iter().zip(&sizes) {
            key_to_shard.extend(entries.iter().map(|e| (e.key.as_str(), *n)));
            shardlist.push(json!({"url": shard_name(*n), "nsamples": entries.len(), "filesize": bytes}));
            sink.files += 1;
            sink.bytes += bytes;
        }
        sink.put(&format!("{split}/{KEY_TO_SHARD}"), &serde_json::to_vec(&key_to_shard)?)?;
        let wids = json!({
            "__kind__": "wids-shard-index-v1",
            "wids_version": 1,
            "name": format!("{name}-{split}"),
            "shardlist": shardlist,
        });
        sink.put(&format!("{split}/{WIDS_INDEX}"), &bop::pretty(&wids)?)?;
        splits.insert(split.to_string(), json!({"images": order.len(), "shards": shards.len()}));
        samples += order.len();
    }

    let mut described = bop::described(&dataset, &objects)?;
    described["format"] = json!(FORMAT);
    described["bop_webdataset"] = json!({
        "scenes": scenes.iter().map(Scene::record).collect::<Vec<_>>(),
        "models_eval": models_eval,
        "depth_scale": bop::DEPTH_SCALE_MM,
        "shard_samples": shard_samples,
        "splits": splits,
        "conventions": {
            "key": "{scene_id:06d}_{im_id:06d}, the scene and image ids of the BOP export",
            "scene": bop::SCENE_CONVENTION,
            "order": ORDER_CONVENTION,
            "units": bop::UNITS_CONVENTION,
            "camera": bop::CAMERA_CONVENTION,
        },
    });
    sink.put("dataset.json", &bop::pretty(&described)?)?;
    Ok(Converted { samples, files: sink.files, bytes: sink.bytes })
}

/// What `dataset.json` says of the shard order; `docs/formats.md` spells out the hash.
const ORDER_CONVENTION: &str = concat!(
    "per split, images by increasing shard rank, ties by key, dealt into shards in that order; ",
    "shard rank = vint_core::seed::shard_rank(seed, object, hand, grasp_index, view_index): ",
    "the first 8 bytes, little-endian, of sha256(b\"vint-seed-v1\\0\" + seed as 8 little-endian bytes ",
    "+ b\"shard-order\" + each part as its length in 8 little-endian bytes and its UTF-8 bytes), ",
    "masked to 53 bits",
);

/// The images of `scenes` in shard order: by increasing `shard_rank`, ties by key.
fn shard_order<'a>(seed: u64, scenes: impl Iterator<Item = &'a Scene<'a>>) -> anyhow::Result<Vec<Entry<'a>>> {
    let mut order = Vec::new();
    for scene in scenes {
        for (&im_id, sample_id) in scene.views {
            let id: SampleId = sample_id.parse().map_err(|e| anyhow!("sample {sample_id}: {e}"))?;
            let rank = vint_core::seed::shard_rank(seed, &id.object, &id.hand, id.grasp_index, id.view_index);
            order.push(Entry { key: image_key(scene.scene_id, im_id), rank, scene, sample_id });
        }
    }
    order.sort_by(|a, b| (a.rank, &a.key).cmp(&(b.rank, &b.key)));
    Ok(order)
}

/// Writes one shard of `entries`, in their order, each key's members in name order; returns its
/// size in bytes.
fn write_shard(native: &Path, objects: &Objects, entries: &[Entry<'_>], path: &Path) -> anyhow::Result<u64> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let file = File::create(path).with_context(|| format!("creating {}", path.display()))?;
    let mut tar = ustar::Writer::new(BufWriter::with_capacity(1 << 20, file));
    for entry in entries {
        let grasp_path = native.join(entry.scene.grasp_id).join(GRASP_RECORD_FILE);
        let record = bop::read_json(&grasp_path)?;
        let grasp = Grasp::of(&record, objects).with_context(|| format!("{}", grasp_path.display()))?;
        let image =
            bop::image(native, entry.sample_id, &grasp).with_context(|| format!("sample {}", entry.sample_id))?;
        for (name, bytes) in members(image)? {
            tar.append(&format!("{}.{name}", entry.key), bytes.len() as u64, &mut bytes.as_slice())?;
        }
    }
    tar.finish()
}

/// An image's members by name (after the key): BOP's image folders as `<folder>.png`, its masks
/// as `mask.json` and `mask_visib.json`, and each per-image record as its scene file's name
/// without `scene_` (`scene_gt.json` → `gt.json`).
fn members(image: Image) -> anyhow::Result<BTreeMap<String, Vec<u8>>> {
    let mut members = BTreeMap::new();
    for (folder, bytes) in image.pngs {
        members.insert(format!("{folder}.png"), bytes);
    }
    if let Some((full, visible)) = &image.masks {
        members.insert("mask.json".to_string(), masks_json(full)?);
        members.insert("mask_visib.json".to_string(), masks_json(visible)?);
    }
    for (file, record) in &image.records {
        let name = file.strip_prefix("scene_").ok_or_else(|| anyhow!("{file} is not a scene file"))?;
        members.insert(name.to_string(), serde_json::to_vec(record)?);
    }
    Ok(members)
}

/// The toolkit's `bop_imagewise.save_masks`: the instance id (as a JSON key) → the mask as COCO's
/// uncompressed RLE, `{"counts": [...], "size": [height, width]}`.
fn masks_json(mask: &Mask) -> anyhow::Result<Vec<u8>> {
    let mut by_instance = serde_json::Map::new();
    by_instance.insert(GT_ID.to_string(), json!({"counts": mask.coco_rle(), "size": [mask.height, mask.width]}));
    Ok(serde_json::to_vec(&by_instance)?)
}

#[cfg(test)]
mod tests {
    use serde_json::Value;

    use super::*;

    #[test]
    fn keys_and_shard_names_follow_the_toolkit() {
        assert_eq!(image_key(4, 15), "000004_000015");
        assert_eq!(shard_name(12), "shard-000012.tar");
    }

    #[test]
    fn masks_are_instance_keyed_column_major_runs() {
        let mask = Mask { width: 3, height: 2, pixels: vec![true, true, false, false, true, true] };
        let json: Value = serde_json::from_slice(&masks_json(&mask).expect("json")).expect("parses");
        assert_eq!(json, json!({"0": {"counts": [0, 1, 1, 2, 1, 1], "size": [2, 3]}}));
    }

    #[test]
    fn members_drop_the_scene_prefix_and_name_images_by_folder() {
        let camera = json!({
            "K": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "width": 1, "height": 1,
            "R_w2c": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "t_w2c": [0.0, 0.0, 0.0],
            "R_m2c": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "t_m2c": [0.0, 0.0, 0.5],
        });
        let mask = Mask { width: 1, height: 1, pixels: vec![true] };
        let image = Image {
            view: bop::View::of(&camera).expect("view"),
            pngs: vec![("rgb", b"png".to_vec()), ("depth", b"depth".to_vec())],
            masks: Some((mask.clone(), mask)),
            records: vec![("scene_gt.json", json!([{"obj_id": 1}])), ("scene_touch.json", json!({"active": []}))],
        };
        let members = members(image).expect("members");
        let names: Vec<&str> = members.keys().map(String::as_str).collect();
        assert_eq!(names, ["depth.png", "gt.json", "mask.json", "mask_visib.json", "rgb.png", "touch.json"]);
        assert_eq!(members["gt.json"], br#"[{"obj_id":1}]"#);
    }
}
