//! The parts of a BOP dataset that scoring reads (the BOP toolkit's docs/bop_datasets_format.md):
//! the models folder's `models_info.json` (diameter, symmetries) and `obj_NNNNNN.ply` (the points
//! ADD is measured on, millimetres), and per split and scene `scene_gt.json` (poses) and
//! `scene_gt_info.json` (`visib_fract`); object names from `dataset.json` when it has them.
//! The models folder is `models_eval/` — the uniformly resampled models the toolkit scores on —
//! when the dataset has one, else `models/` (whose vertices may be anything but uniform: the
//! report says which it used). Reads only; any problem is an error naming the file.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow, bail};
use serde_json::Value;

use super::metrics::Pose;
use super::ply;

/// An object as scoring sees it.
pub struct Model {
    pub obj_id: u32,
    /// From dataset.json; `obj_NNNNNN` when it has none.
    pub name: String,
    pub diameter_mm: f64,
    /// models_info lists symmetries_continuous or symmetries_discrete: ADD(S) is ADD-S.
    pub symmetric: bool,
    /// The PLY's vertices (mm).
    pub points: Vec<[f64; 3]>,
}

/// One annotated object instance in one image.
pub struct Instance {
    pub split: String,
    pub scene_id: u32,
    pub im_id: u32,
    /// Its position in the image's scene_gt list.
    pub gt_index: usize,
    pub obj_id: u32,
    pub pose: Pose,
    pub visib_fract: f64,
}

pub struct Dataset {
    pub models: BTreeMap<u32, Model>,
    /// The folder the models were read from: `models_eval` or `models`.
    pub models_dir: &'static str,
    /// Sorted by (scene_id, im_id, gt_index).
    pub instances: Vec<Instance>,
    pub splits: Vec<String>,
}

/// The dataset at `dir`, over `splits` (all splits present when empty).
pub fn read(dir: &Path, splits: &[String]) -> anyhow::Result<Dataset> {
    if !dir.join("models/models_info.json").is_file() {
        bail!("{} is not a BOP dataset: it has no models/models_info.json", dir.display());
    }
    let present = splits_in(dir)?;
    let splits = if splits.is_empty() {
        present
    } else {
        for s in splits {
            if !present.contains(s) {
                bail!("split {s:?} is not in {} (it has: {})", dir.display(), present.join(", "));
            }
        }
        splits.to_vec()
    };
    let mut instances = Vec::new();
    let mut scene_split: BTreeMap<u32, String> = BTreeMap::new();
    for split in &splits {
        for (scene_id, scene_dir) in scenes(&dir.join(split))? {
            if let Some(other) = scene_split.insert(scene_id, split.clone()) {
                bail!(
                    "scene {scene_id} is in both split {other:?} and split {split:?}: a results CSV cannot tell \
                     them apart; choose one with --split"
                );
            }
            read_scene(&scene_dir, split, scene_id, &mut instances)?;
        }
    }
    instances.sort_by_key(|i| (i.scene_id, i.im_id, i.gt_index));
    let models_dir = if dir.join("models_eval/models_info.json").is_file() { "models_eval" } else { "models" };
    let models = read_models(dir, models_dir, &instances)?;
    Ok(Dataset { models, models_dir, instances, splits })
}

/// Directories directly under `dir` (but models/) that hold at least one scene.
fn splits_in(dir: &Path) -> anyhow::Result<Vec<String>> {
    let mut splits = Vec::new();
    for entry in read_dir_sorted(dir)? {
        let name = entry.file_name().and_then(|n| n.to_str()).unwrap_or_default().to_string();
        if entry.is_dir() && name != "models" && name != "models_eval" && !scenes(&entry)?.is_empty() {
            splits.push(name);
        }
    }
    if splits.is_empty() {
        bail!("{} has no split with scenes (<split>/<scene_id>/scene_gt.json)", dir.display());
    }
    Ok(splits)
}

/// The scene directories of a split: numeric names holding scene_gt.json, by scene id.
fn scenes(split_dir: &Path) -> anyhow::Result<Vec<(u32, PathBuf)>> {
    let mut scenes = Vec::new();
    for entry in read_dir_sorted(split_dir)? {
        let Some(id) = entry.file_name().and_then(|n| n.to_str()).and_then(|n| n.parse::<u32>().ok()) else {
            continue;
        };
        if entry.join("scene_gt.json").is_file() {
            scenes.push((id, entry));
        }
    }
    scenes.sort();
    Ok(scenes)
}

fn read_dir_sorted(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let entries = std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))?;
    let mut paths = entries.map(|e| e.map(|e| e.path())).collect::<Result<Vec<_>, _>>()?;
    paths.sort();
    Ok(paths)
}

fn read_json(path: &Path) -> anyhow::Result<Value> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("{} is not valid JSON", path.display()))
}

fn read_scene(scene_dir: &Path, split: &str, scene_id: u32, out: &mut Vec<Instance>) -> anyhow::Result<()> {
    let gt_path = scene_dir.join("scene_gt.json");
    let info_path = scene_dir.join("scene_gt_info.json");
    let gt = read_json(&gt_path)?;
    let info = read_json(&info_path)?;
    let (Some(gt), Some(info)) = (gt.as_object(), info.as_object()) else {
        bail!("{} and {} must be objects keyed by image id", gt_path.display(), info_path.display());
    };
    for (im_key, annotations) in gt {
        let im_id: u32 =
            im_key.parse().map_err(|_| anyhow!("{}: image id {im_key:?} is no integer", gt_path.display()))?;
        let annotations =
            annotations.as_array().ok_or_else(|| anyhow!("{}: {im_key} is no list", gt_path.display()))?;
        let infos = info
            .get(im_key)
            .and_then(Value::as_array)
            .ok_or_else(|| anyhow!("{}: image {im_key} is missing (scene_gt.json has it)", info_path.display()))?;
        if infos.len() != annotations.len() {
            bail!(
                "image {im_key} of scene {scene_id}: scene_gt.json lists {} instances, scene_gt_info.json {}",
                annotations.len(),
                infos.len()
            );
        }
        for (gt_index, (a, i)) in annotations.iter().zip(infos).enumerate() {
            let at = || format!("{} image {im_key} instance {gt_index}", gt_path.display());
            let obj_id = a["obj_id"].as_u64().and_then(|v| u32::try_from(v).ok());
            let obj_id = obj_id.ok_or_else(|| anyhow!("{}: obj_id is no non-negative integer", at()))?;
            let r = numbers(&a["cam_R_m2c"], 9).with_context(|| format!("{}: cam_R_m2c", at()))?;
            let t = numbers(&a["cam_t_m2c"], 3).with_context(|| format!("{}: cam_t_m2c", at()))?;
            let visib_fract = i["visib_fract"].as_f64().filter(|v| (0.0..=1.0).contains(v)).ok_or_else(|| {
                anyhow!("{} image {im_key} instance {gt_index}: visib_fract is no number in 0..1", info_path.display())
            })?;
            out.push(Instance {
                split: split.to_string(),
                scene_id,
                im_id,
                gt_index,
                obj_id,
                pose: Pose { r: [[r[0], r[1], r[2]], [r[3], r[4], r[5]], [r[6], r[7], r[8]]], t: [t[0], t[1], t[2]] },
                visib_fract,
            });
        }
    }
    Ok(())
}

fn numbers(v: &Value, count: usize) -> anyhow::Result<Vec<f64>> {
    let values: Option<Vec<f64>> = v.as_array().map(|a| a.iter().map(Value::as_f64).collect()).unwrap_or(None);
    match values {
        Some(values) if values.len() == count && values.iter().all(|x| x.is_finite()) => Ok(values),
        _ => bail!("expected {count} numbers, found {v}"),
    }
}

/// The models of the objects the instances show (others are not read).
fn read_models(dir: &Path, models_dir: &str, instances: &[Instance]) -> anyhow::Result<BTreeMap<u32, Model>> {
    let info_path = dir.join(models_dir).join("models_info.json");
    let info = read_json(&info_path)?;
    let names = object_names(dir)?;
    let mut models = BTreeMap::new();
    for obj_id in instances.iter().map(|i| i.obj_id) {
        if models.contains_key(&obj_id) {
            continue;
        }
        let entry = &info[obj_id.to_string()];
        if !entry.is_object() {
            bail!("{} has no entry for object {obj_id}, which the ground truth shows", info_path.display());
        }
        let diameter_mm = entry["diameter"].as_f64().filter(|d| d.is_finite() && *d > 0.0);
        let diameter_mm = diameter_mm
            .ok_or_else(|| anyhow!("{}: object {obj_id}: diameter is no positive number", info_path.display()))?;
        let listed = |key: &str| entry.get(key).and_then(Value::as_array).is_some_and(|a| !a.is_empty());
        let symmetric = listed("symmetries_continuous") || listed("symmetries_discrete");
        let ply_path = dir.join(models_dir).join(format!("obj_{obj_id:06}.ply"));
        let bytes = std::fs::read(&ply_path).with_context(|| format!("reading {}", ply_path.display()))?;
        let points = ply::vertices(&bytes).with_context(|| format!("reading {}", ply_path.display()))?;
        if points.is_empty() {
            bail!("{} has no vertices", ply_path.display());
        }
        let name = names.get(&obj_id).cloned().unwrap_or_else(|| format!("obj_{obj_id:06}"));
        models.insert(obj_id, Model { obj_id, name, diameter_mm, symmetric, points });
    }
    Ok(models)
}

/// obj_id → name from dataset.json's `objects`, when the dataset has one.
fn object_names(dir: &Path) -> anyhow::Result<BTreeMap<u32, String>> {
    let path = dir.join("dataset.json");
    if !path.is_file() {
        return Ok(BTreeMap::new());
    }
    let doc = read_json(&path)?;
    let objects = doc["objects"].as_array().map(Vec::as_slice).unwrap_or_default();
    Ok(objects
        .iter()
        .filter_map(|o| {
            let id = o["obj_id"].as_u64().and_then(|v| u32::try_from(v).ok())?;
            Some((id, o["name"].as_str()?.to_string()))
        })
        .collect())
}
