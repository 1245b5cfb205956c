//! The BOP export (`--format bop`): a native dataset rewritten in the layout of the BOP toolkit's
//! `docs/bop_datasets_format.md`, so that its readers (`inout.load_scene_camera`, `load_scene_gt`,
//! `load_depth`, `load_ply`, `load_json(keys_to_int=True)`) and evaluation load it as they load
//! YCB-V. One scene per grasp (its views are the scene's images: `im_id` = view index), scene ids
//! the grasps' ordinals in sorted order, split folders from `dataset.json`'s split.
//!
//! BOP's own files carry millimetres and row-major matrices; what BOP has no file for goes beside
//! them in the same per-image JSON shape (`scene_touch.json`, `scene_hand.json`,
//! `scene_meta.json`, `depth_noisy/`, `segmentation/`). `docs/formats.md` describes the result.
//!
//! It reads one sample at a time and holds one scene's small JSON records, never the dataset.
//! Output is deterministic: sorted keys, images in id order, numbers rounded to fixed decimals,
//! PNGs from fixed encoder settings, no timestamps.

mod frames;
mod images;
mod model;
mod model_eval;
mod targets;

use std::collections::BTreeMap;
use std::fs;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow, bail};
use serde_json::{Value, json};
use vint_core::SampleId;

use super::Converted;
pub use frames::moved_symmetries;
use frames::{Mat3, Rigid, Vec3, row_major};
pub use images::DEPTH_SCALE_MM;
pub(super) use images::Mask;
use images::{depth_units, encode_depth};
use model::{Mesh, ModelGeometry};
use targets::ImageFacts;

/// Lengths are written in mm to 1 nm and unitless numbers (rotations, normals) to 1e-9: far below
/// anything measured, short and stable text.
const MM_DECIMALS: i32 = 6;
const UNIT_DECIMALS: i32 = 9;
/// `models_info.json` measures the shipped PLY (float32 mm); `dataset.json` the engine's float64
/// mesh. Both describe one surface, so they must agree to well under a micrometre per 100 mm;
/// 0.01 mm leaves room for float32 and still catches a unit or model mix-up.
const MODEL_TOLERANCE_MM: f64 = 0.01;
/// The one object instance of every image.
pub(super) const GT_ID: usize = 0;

/// Convert the native dataset at `native` into BOP's layout under `out` (an empty directory).
pub fn write(native: &Path, out: &Path) -> anyhow::Result<Converted> {
    let dataset = read_json(&native.join("dataset.json"))?;
    let objects = Objects::of(&dataset)?;
    let grasps = views_by_grasp(native)?;
    let scenes = scenes(&dataset, &grasps)?;
    let samples = grasps.values().map(BTreeMap::len).sum();
    let mut sink = Sink::new(out);

    let models_eval = write_models(native, &objects, &mut sink)?;
    // Scenes are independent (each writes only its own folder).
    let written = super::on_all_cores(&scenes, |scene| {
        let mut sink = Sink::new(out);
        let dir = format!("{}/{:06}", scene.split, scene.scene_id);
        let images = write_scene(native, scene.scene_id, &dir, scene.grasp_id, scene.views, &objects, &mut sink)
            .with_context(|| format!("grasp {}", scene.grasp_id))?;
        Ok((sink, scene.split, images))
    })?;
    let mut images = Vec::new();
    for (scene_sink, split, facts) in written {
        sink.add(&scene_sink);
        images.extend(facts.into_iter().map(|i| (split, i)));
    }
    images.sort_by_key(|(_, i)| (i.scene_id, i.im_id));
    let camera = write_dataset_files(&images, &mut sink)?;

    let mut described = described(&dataset, &objects)?;
    described["format"] = json!("vint-bop");
    described["bop"] = json!({
        "scenes": scenes.iter().map(Scene::record).collect::<Vec<_>>(),
        "models_eval": models_eval,
        "depth_scale": DEPTH_SCALE_MM,
        "conventions": {
            "scene": SCENE_CONVENTION,
            "units": UNITS_CONVENTION,
            "camera": CAMERA_CONVENTION,
            "camera.json": camera,
            "test_targets": format!(
                "test_targets_bop19.json: per test image, the objects at least {} visible (BOP 19's rule; absent without masks); test_targets_bop24.json: every test image",
                targets::MIN_VISIB_FRACT
            ),
        },
    });
    sink.put("dataset.json", &pretty(&described)?)?;
    Ok(Converted { samples, files: sink.files, bytes: sink.bytes })
}

/// What `dataset.json` says of scene and image ids, of units and of the camera frame; the
/// BOP-webdataset export says the same.
pub(super) const SCENE_CONVENTION: &str = "one scene per grasp: scene_id is the grasp's position in the sorted list of all grasp ids; im_id is the view index";
pub(super) const UNITS_CONVENTION: &str = "mm (models, cam_t_*, depth × depth_scale, touch *_mm); rotations row-major";
pub(super) const CAMERA_CONVENTION: &str = "OpenCV: x right, y down, z forward; pixel centres at integer coordinates";

/// One grasp as a BOP scene: its id (the grasp's position among all grasp ids, sorted), its split
/// and its views' sample ids by view index (`im_id`).
pub(super) struct Scene<'a> {
    pub scene_id: u64,
    pub split: &'static str,
    pub grasp_id: &'a str,
    pub views: &'a BTreeMap<u32, String>,
}

impl Scene<'_> {
    /// Its entry in `dataset.json`'s list of scenes.
    pub fn record(&self) -> Value {
        json!({
            "scene_id": self.scene_id,
            "split": self.split,
            "grasp_id": self.grasp_id,
            "im_ids": self.views.keys().collect::<Vec<_>>(),
        })
    }
}

/// Every grasp of `grasps` (`views_by_grasp`) as a scene, in scene id order, with its split from
/// `dataset.json`'s `split.grasps`.
pub(super) fn scenes<'a>(
    dataset: &Value,
    grasps: &'a BTreeMap<String, BTreeMap<u32, String>>,
) -> anyhow::Result<Vec<Scene<'a>>> {
    let assigned = &dataset["split"]["grasps"];
    grasps
        .iter()
        .enumerate()
        .map(|(scene_id, (grasp_id, views))| {
            let name = assigned[grasp_id.as_str()].as_str().unwrap_or_default();
            let split = vint_core::split::Split::NAMES.into_iter().find(|s| *s == name).ok_or_else(|| {
                anyhow!("dataset.json: split.grasps has no train/val/test entry for grasp {grasp_id}")
            })?;
            Ok(Scene { scene_id: scene_id as u64, split, grasp_id, views })
        })
        .collect()
}

/// The native `dataset.json` with each object's model where BOP's layout keeps it
/// (`models/obj_NNNNNN.ply`) and its symmetries in the frame that model is written in.
pub(super) fn described(dataset: &Value, objects: &Objects) -> anyhow::Result<Value> {
    let mut described = dataset.clone();
    for o in described["objects"].as_array_mut().into_iter().flatten() {
        if let Some(id) = o["obj_id"].as_u64() {
            o["model"] = json!(format!("models/obj_{id:06}.ply"));
            let c = objects.file_offset_m(id);
            if c != [0.0; 3] {
                for key in ["symmetries_continuous", "symmetries_discrete"] {
                    let moved = moved_symmetries(key, &o[key], c).ok_or_else(|| anyhow!("dataset.json: {key}"))?;
                    o[key] = moved;
                }
                o["frame"] = json!("mesh file");
            }
        }
    }
    Ok(described)
}

/// `camera.json` and the test targets; returns what `camera.json` is (`dataset.json` says so).
fn write_dataset_files(images: &[(&str, ImageFacts)], sink: &mut Sink) -> anyhow::Result<&'static str> {
    let all: Vec<ImageFacts> = images.iter().map(|(_, i)| i.clone()).collect();
    let test: Vec<ImageFacts> = images.iter().filter(|(split, _)| *split == "test").map(|(_, i)| i.clone()).collect();
    let what = match targets::camera(&all) {
        Some((camera, shared)) => {
            sink.put("camera.json", &pretty(&camera)?)?;
            if shared {
                "the camera every image shares"
            } else {
                "each intrinsic's median over the images, whose cameras vary (scene_camera.json)"
            }
        }
        None => "absent: no image",
    };
    if let Some(bop19) = targets::bop19(&test) {
        sink.put("test_targets_bop19.json", &pretty(&bop19)?)?;
    }
    sink.put("test_targets_bop24.json", &pretty(&targets::bop24(&test))?)?;
    Ok(what)
}

/// Files written, counted as they go.
pub(super) struct Sink {
    root: PathBuf,
    pub files: usize,
    pub bytes: u64,
}

impl Sink {
    pub fn new(root: &Path) -> Sink {
        Sink { root: root.to_path_buf(), files: 0, bytes: 0 }
    }

    /// Counts what another sink wrote.
    pub fn add(&mut self, other: &Sink) {
        self.files += other.files;
        self.bytes += other.bytes;
    }

    pub fn put(&mut self, name: &str, bytes: &[u8]) -> anyhow::Result<()> {
        let path = self.root.join(name);
        if let Some(parent) = path.parent() {
            fs::create_dir_all(parent).with_context(|| format!("creating {}", parent.display()))?;
        }
        fs::write(&path, bytes).with_context(|| format!("writing {}", path.display()))?;
        self.files += 1;
        self.bytes += bytes.len() as u64;
        Ok(())
    }
}

/// The dataset's objects by BOP id, from `dataset.json`.
pub(super) struct Objects {
    by_id: BTreeMap<u64, Value>,
    ids: BTreeMap<String, u64>,
}

impl Objects {
    pub fn of(dataset: &Value) -> anyhow::Result<Objects> {
        let list = dataset["objects"].as_array().ok_or_else(|| anyhow!("dataset.json has no objects list"))?;
        let (mut by_id, mut ids) = (BTreeMap::new(), BTreeMap::new());
        for o in list {
            let name = o["name"].as_str().ok_or_else(|| anyhow!("dataset.json: an object has no name"))?;
            let id = o["obj_id"].as_u64().ok_or_else(|| anyhow!("dataset.json: object {name} has no obj_id"))?;
            if by_id.insert(id, o.clone()).is_some() || ids.insert(name.to_string(), id).is_some() {
                bail!("dataset.json: object {name} (obj_id {id}) is listed twice");
            }
        }
        Ok(Objects { by_id, ids })
    }

    fn id(&self, name: &str) -> anyhow::Result<u64> {
        self.ids.get(name).copied().ok_or_else(|| anyhow!("object {name} is not in dataset.json's objects"))
    }

    /// Where the object's mesh file has its origin, as `dataset.json`'s `file_offset_mm` says (a
    /// BOP dataset's model: the bounding-box centre in the file's coordinates), in metres; zero for
    /// every other object, whose frame is the native one. This layout writes the model, its poses
    /// and symmetries in the file's frame: `x_file = x + c`, `t_file = t − R·c`.
    fn file_offset_m(&self, id: u64) -> Vec3 {
        let offset = self.by_id.get(&id).and_then(|o| numbers(&o["file_offset_mm"], 3));
        offset.map_or([0.0; 3], |c| [c[0] / 1000.0, c[1] / 1000.0, c[2] / 1000.0])
    }
}

/// Every grasp (sorted by id) with its views' sample ids by view index, from `manifest.jsonl`.
pub(super) fn views_by_grasp(native: &Path) -> anyhow::Result<BTreeMap<String, BTreeMap<u32, String>>> {
    let path = native.join("manifest.jsonl");
    let file = fs::File::open(&path).with_context(|| format!("opening {}", path.display()))?;
    let mut grasps: BTreeMap<String, BTreeMap<u32, String>> = BTreeMap::new();
    for (n, line) in BufReader::new(file).lines().enumerate() {
        let line = line.with_context(|| format!("reading {}", path.display()))?;
        if line.trim().is_empty() {
            continue;
        }
        let entry: Value =
            serde_json::from_str(&line).with_context(|| format!("{} line {}: not JSON", path.display(), n + 1))?;
        if let Some(sample) = entry["sample_id"].as_str() {
            let id: SampleId = sample.parse().map_err(|e| anyhow!("{} line {}: {e}", path.display(), n + 1))?;
            grasps.entry(id.grasp().to_string()).or_default().insert(id.view_index, sample.to_string());
        }
    }
    if grasps.is_empty() {
        bail!("{} lists no samples", path.display());
    }
    Ok(grasps)
}

/// `models/obj_NNNNNN.ply` (the native model's vertices and triangles, with BOP's vertex normals
/// added) and `models/models_info.json`, whose geometry is measured on those bytes and checked
/// against what `dataset.json` declares; and `models_eval/`, the same models resampled uniformly
/// (`model_eval`) with their own `models_info.json`. Returns what `dataset.json` says of
/// `models_eval` (the sampling, and each model's spacing and point count).
pub(super) fn write_models(native: &Path, objects: &Objects, sink: &mut Sink) -> anyhow::Result<Value> {
    let (mut info, mut info_eval, mut sampled) = (BTreeMap::new(), BTreeMap::new(), Vec::new());
    for (&id, o) in &objects.by_id {
        let name = o["name"].as_str().unwrap_or_default();
        let file = o["model"].as_str().ok_or_else(|| anyhow!("dataset.json: object {name} has no model file"))?;
        let path = native.join(file);
        let bytes = fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
        let c = objects.file_offset_m(id);
        let mesh = Mesh::parse(&bytes).with_context(|| format!("{}", path.display()))?.moved(c.map(|v| v * 1000.0));
        // Both meshes' geometry is measured on their vertices as written (float32).
        let written = mesh.ply_with_normals();
        let geometry = ModelGeometry::of(&mesh.vertices).with_context(|| format!("{}", path.display()))?;
        check_declared(name, &geometry, o)?;
        sink.put(&format!("models/obj_{id:06}.ply"), &written)?;

        let resampled = model_eval::resample(&mesh, &written);
        let eval_vertices: Vec<_> = resampled.mesh.vertices.iter().map(|&v| model::as_float32(v)).collect();
        let eval_geometry = ModelGeometry::of(&eval_vertices).with_context(|| format!("{name}'s models_eval"))?;
        sink.put(&format!("models_eval/obj_{id:06}.ply"), &resampled.mesh.ply_with_normals())?;
        sampled.push(json!({"obj_id": id, "spacing_mm": round(resampled.spacing_mm, MM_DECIMALS),
                            "points": eval_vertices.len(), "triangles": resampled.mesh.triangles.len()}));

        let mut symmetries = serde_json::Map::new();
        // BOP lists symmetry keys only for symmetric objects.
        for key in ["symmetries_continuous", "symmetries_discrete"] {
            if o[key].as_array().is_some_and(|s| !s.is_empty()) {
                let in_file = if c == [0.0; 3] {
                    o[key].clone()
                } else {
                    moved_symmetries(key, &o[key], c)
                        .ok_or_else(|| anyhow!("dataset.json: object {name}'s {key} is not in BOP's form"))?
                };
                symmetries.insert(key.to_string(), symmetries_in_mm(key, &in_file, name)?);
            }
        }
        info.insert(id, info_entry(&geometry, &symmetries));
        info_eval.insert(id, info_entry(&eval_geometry, &symmetries));
    }
    sink.put("models/models_info.json", &by_id(&info)?)?;
    sink.put("models_eval/models_info.json", &by_id(&info_eval)?)?;
    Ok(json!({
        "sampling": format!(
            "Poisson-disk resampling of models/: candidates are the model's vertices, then the corners of every triangle's pieces cut by longest-edge bisection to edges <= spacing/3, visited in an order keyed by the hash of the model's file in models/; a candidate is kept when no kept one is closer than the spacing ({} mm, or sqrt(area / {}) if larger); triangles join the kept points nearest each piece's corners",
            model_eval::SPACING_MM,
            model_eval::MAX_AREA_PER_R2
        ),
        "objects": sampled,
    }))
}

/// One `models_info.json` entry: the geometry measured on the written PLY, then the symmetries.
fn info_entry(geometry: &ModelGeometry, symmetries: &serde_json::Map<String, Value>) -> Value {
    let mut entry = json!({
        "diameter": round(geometry.diameter, MM_DECIMALS),
        "min_x": round(geometry.min[0], MM_DECIMALS),
        "min_y": round(geometry.min[1], MM_DECIMALS),
        "min_z": round(geometry.min[2], MM_DECIMALS),
        "size_x": round(geometry.size[0], MM_DECIMALS),
        "size_y": round(geometry.size[1], MM_DECIMALS),
        "size_z": round(geometry.size[2], MM_DECIMALS),
    });
    for (key, value) in symmetries {
        entry[key] = value.clone();
    }
    entry
}

/// The model PLY's geometry against what `dataset.json` declares. An object none of whose grasps
/// was accepted has no grasp record to take the facts from: its `diameter_mm` is null, and its
/// model is written as measured.
fn check_declared(name: &str, geometry: &ModelGeometry, o: &Value) -> anyhow::Result<()> {
    let declared = match o.get("diameter_mm") {
        Some(Value::Null) => return Ok(()),
        Some(v) => v.as_f64(),
        None => None,
    };
    let declared = declared.ok_or_else(|| anyhow!("dataset.json: object {name} has no diameter_mm"))?;
    if (declared - geometry.diameter).abs() > MODEL_TOLERANCE_MM {
        bail!(
            "object {name}: the model PLY's diameter is {:.4} mm, dataset.json declares {declared:.4} mm",
            geometry.diameter
        );
    }
    if let Some(extent) = o["extent_mm"].as_array() {
        let extent: Vec<f64> = extent.iter().filter_map(Value::as_f64).collect();
        let agrees =
            extent.len() == 3 && extent.iter().zip(geometry.size).all(|(e, s)| (e - s).abs() <= MODEL_TOLERANCE_MM);
        if !agrees {
            bail!(
                "object {name}: the model PLY's extent is {:?} mm, dataset.json declares {extent:?} mm",
                geometry.size
            );
        }
    }
    Ok(())
}

/// Native symmetries are in BOP's form but metres, like every native length; BOP's are in mm:
/// a continuous symmetry's `offset`, a discrete one's translation column (entries 3, 7, 11 of the
/// row-major 4×4).
fn symmetries_in_mm(key: &str, symmetries: &Value, name: &str) -> anyhow::Result<Value> {
    let bad = || anyhow!("dataset.json: object {name}'s {key} is not in BOP's form");
    let list = symmetries.as_array().ok_or_else(bad)?;
    let converted: anyhow::Result<Vec<Value>> = list
        .iter()
        .map(|s| {
            if key == "symmetries_continuous" {
                let axis = numbers(&s["axis"], 3).ok_or_else(bad)?;
                let offset = numbers(&s["offset"], 3).ok_or_else(bad)?;
                Ok(json!({
                    "axis": axis.iter().map(|v| round(*v, UNIT_DECIMALS)).collect::<Vec<_>>(),
                    "offset": offset.iter().map(|v| round(v * 1000.0, MM_DECIMALS)).collect::<Vec<_>>(),
                }))
            } else {
                let m = numbers(s, 16).ok_or_else(bad)?;
                let mm: Vec<f64> = m
                    .iter()
                    .enumerate()
                    .map(|(i, v)| {
                        if matches!(i, 3 | 7 | 11) { round(v * 1000.0, MM_DECIMALS) } else { round(*v, UNIT_DECIMALS) }
                    })
                    .collect();
                Ok(json!(mm))
            }
        })
        .collect();
    Ok(Value::Array(converted?))
}

/// One grasp's scene: its images and the per-image JSON files; what the dataset-level files need
/// of each image.
fn write_scene(
    native: &Path,
    scene_id: u64,
    dir: &str,
    grasp_id: &str,
    views: &BTreeMap<u32, String>,
    objects: &Objects,
    sink: &mut Sink,
) -> anyhow::Result<Vec<ImageFacts>> {
    let grasp_path = native.join(grasp_id).join("grasp.json");
    let grasp = read_json(&grasp_path)?;
    let grasp = Grasp::of(&grasp, objects).with_context(|| format!("{}", grasp_path.display()))?;
    let mut files: BTreeMap<&str, BTreeMap<u64, Value>> = BTreeMap::new();
    let mut images = Vec::new();
    let mut coco_images = Vec::new();
    let mut annotations = Vec::new();
    for (&view, sample_id) in views {
        let im = u64::from(view);
        let (records, view) =
            write_image(native, dir, im, sample_id, &grasp, sink).with_context(|| format!("sample {sample_id}"))?;
        let visib_fract = visib_fract(&records);
        images.push(ImageFacts {
            scene_id,
            im_id: im,
            obj_id: grasp.obj_id,
            visib_fract,
            intrinsics: [view.k[0][0], view.k[1][1], view.k[0][2], view.k[1][2]],
            size: (view.width, view.height),
        });
        coco_images.push(json!({
            "file_name": format!("rgb/{im:06}.png"), "height": view.height, "id": im, "width": view.width,
        }));
        for (file, record) in records {
            if file == COCO {
                annotations.push(record);
            } else {
                files.entry(file).or_default().insert(im, record);
            }
        }
    }
    for (file, records) in files {
        sink.put(&format!("{dir}/{file}"), &by_id(&records)?)?;
    }
    // The masks an annotation is made from: any image with a visibility had them.
    if images.iter().any(|i| i.visib_fract.is_some()) {
        for (n, a) in annotations.iter_mut().enumerate() {
            a["id"] = json!(n + 1);
        }
        let categories: Vec<Value> =
            objects.by_id.keys().map(|id| json!({"id": id, "name": id.to_string(), "supercategory": "vint"})).collect();
        let coco = json!({
            "annotations": annotations,
            "categories": categories,
            "images": coco_images,
            "info": {"contributor": "vint", "description": dir},
            "licenses": [],
        });
        sink.put(&format!("{dir}/{COCO}"), &pretty(&coco)?)?;
    }
    Ok(images)
}

/// What every view of a grasp shares, read once from its `grasp.json`.
pub(super) struct Grasp<'a> {
    record: &'a Value,
    obj_id: u64,
    /// The model's file frame in the native object frame (`Objects::file_offset_m`).
    file_offset_m: Vec3,
    /// Palm frame → world, for the taxels (`touch.active[].p_palm` is in the palm frame).
    palm_to_world: Rigid,
    /// Every link's pose in the world.
    links: BTreeMap<String, Rigid>,
}

impl<'a> Grasp<'a> {
    pub fn of(record: &'a Value, objects: &Objects) -> anyhow::Result<Grasp<'a>> {
        let object = record["object"]["name"].as_str().ok_or_else(|| anyhow!("no object.name"))?;
        let trial = &record["trial"];
        let poses = trial["link_poses"].as_object().ok_or_else(|| anyhow!("no trial.link_poses"))?;
        let links = poses
            .iter()
            .map(|(name, p)| Ok((name.clone(), pose(p).with_context(|| format!("trial.link_poses.{name}"))?)))
            .collect::<anyhow::Result<BTreeMap<_, _>>>()?;
        // The hand's root body is its palm (the grasp engine names it so and reports its pose as
        // trial.hand_pose); the taxels' p_palm/n_palm are in its frame.
        let palm_to_world = pose(&trial["hand_pose"]).context("trial.hand_pose")?;
        if let Some(palm) = links.get("palm")
            && palm != &palm_to_world
        {
            bail!("trial.link_poses.palm differs from trial.hand_pose: which frame is the palm's is unclear");
        }
        let obj_id = objects.id(object)?;
        Ok(Grasp { record, obj_id, file_offset_m: objects.file_offset_m(obj_id), palm_to_world, links })
    }
}

/// One view as BOP has it, in memory: its images, its masks and its record for each per-image
/// file. The BOP export lays these out in scene folders, BOP-webdataset as one key's members.
pub(super) struct Image {
    pub view: View,
    /// PNG bytes by BOP's folder name: `rgb`, `segmentation`, `depth`, `depth_noisy` (each when
    /// the sample has it).
    pub pngs: Vec<(&'static str, Vec<u8>)>,
    /// The object's full silhouette and its visible part, when the sample has both masks.
    pub masks: Option<(Mask, Mask)>,
    /// Each per-image record by the scene file that gathers it (`scene_gt.json`, …).
    pub records: Vec<(&'static str, Value)>,
}

impl Image {
    /// `scene_gt_info.json`'s visible fraction of the object (none without masks).
    pub fn visib_fract(&self) -> Option<f64> {
        visib_fract(&self.records)
    }
}

fn visib_fract(records: &[(&str, Value)]) -> Option<f64> {
    records.iter().find(|(file, _)| *file == "scene_gt_info.json").and_then(|(_, r)| r[GT_ID]["visib_fract"].as_f64())
}

/// One view: its images into the scene's folders, and its record for each per-image JSON file.
fn write_image(
    native: &Path,
    dir: &str,
    im: u64,
    sample_id: &str,
    grasp: &Grasp<'_>,
    sink: &mut Sink,
) -> anyhow::Result<(Vec<(&'static str, Value)>, View)> {
    let image = image(native, sample_id, grasp)?;
    let visib_fract = image.visib_fract();
    let Image { view, pngs, masks, mut records } = image;
    for (folder, bytes) in &pngs {
        sink.put(&format!("{dir}/{folder}/{im:06}.png"), bytes)?;
    }
    if let Some((full, visible)) = &masks {
        sink.put(&format!("{dir}/mask/{im:06}_{GT_ID:06}.png"), &full.encode()?)?;
        sink.put(&format!("{dir}/mask_visib/{im:06}_{GT_ID:06}.png"), &visible.encode()?)?;
        if let Some(annotation) = coco_annotation(im, grasp.obj_id, full, visible, visib_fract) {
            records.push((COCO, annotation));
        }
    }
    Ok((records, view))
}

/// One native sample in BOP's terms (`Image`): its images re-encoded as BOP has them, its masks,
/// and its records. The one place a sample's files are read for both BOP layouts.
pub(super) fn image(native: &Path, sample_id: &str, grasp: &Grasp<'_>) -> anyhow::Result<Image> {
    let sample = native.join(sample_id);
    let meta_path = sample.join("meta.json");
    let meta = read_json(&meta_path)?;
    let camera = &meta["camera"];
    let view = View::of(camera).with_context(|| format!("{}: camera", meta_path.display()))?;
    // The model's pose in its file's frame: x_cam = R·x + t = R·x_file + (t − R·c).
    let model_to_camera =
        Rigid { r: view.model_to_camera.r, t: view.model_to_camera.point(grasp.file_offset_m.map(|v| -v)) };

    let mut pngs = Vec::new();
    for (file, folder) in [("rgb.png", "rgb"), ("segmentation.png", "segmentation")] {
        let path = sample.join(file);
        if path.is_file() {
            pngs.push((folder, fs::read(&path).with_context(|| format!("reading {}", path.display()))?));
        }
    }
    let mut depth = None;
    for folder in ["depth", "depth_noisy"] {
        if let Some(path) = crate::depth::find(&sample, folder) {
            let units = read_depth(&path, &view)?;
            pngs.push((folder, encode_depth(view.width, view.height, &units)?));
            if folder == "depth" {
                depth = Some(units);
            }
        }
    }

    let mut records = vec![
        ("scene_camera.json", view.scene_camera()),
        (
            "scene_gt.json",
            json!([{
                "cam_R_m2c": row_major(&model_to_camera.r).map(|v| round(v, UNIT_DECIMALS)),
                "cam_t_m2c": model_to_camera.t.map(mm),
                "obj_id": grasp.obj_id,
            }]),
        ),
        ("scene_touch.json", touch_record(grasp, &view)?),
        ("scene_hand.json", hand_record(grasp, &view)),
        ("scene_meta.json", meta_record(&meta, sample_id, grasp.obj_id)),
    ];
    let (visible, full) = (sample.join("mask.png"), sample.join("mask_full.png"));
    let mut masks = None;
    if visible.is_file() && full.is_file() {
        let visible = read_mask(&visible, &view)?;
        // The renderer counts full_px over the full mask joined with the visible one; writing that
        // union keeps mask_visib ⊆ mask and px_count_all = full_px.
        let full = read_mask(&full, &view)?.union(&visible);
        records.push(("scene_gt_info.json", json!([gt_info(&full, &visible, depth.as_deref())])));
        masks = Some((full, visible));
    }
    Ok(Image { view, pngs, masks, records })
}

/// The camera of one view, from `meta.json`'s `camera` (metres, OpenCV).
pub(super) struct View {
    k: Mat3,
    /// OpenCV's lens distortion [k1, k2, p1, p2, k3] of a distorted view (the record's `dist`);
    /// `None` for a pinhole (no `dist`, or all zero).
    dist: Option<[f64; 5]>,
    width: usize,
    height: usize,
    world_to_camera: Rigid,
    model_to_camera: Rigid,
}

impl View {
    pub fn of(camera: &Value) -> anyhow::Result<View> {
        let size =
            |key: &str| camera[key].as_u64().and_then(|v| usize::try_from(v).ok()).ok_or_else(|| anyhow!("no {key}"));
        let dist = match camera.get("dist") {
            None => None,
            Some(value) => {
                let v = numbers(value, 5).ok_or_else(|| anyhow!("dist: expected 5 numbers, found {value}"))?;
                Some([v[0], v[1], v[2], v[3], v[4]]).filter(|d| d.iter().any(|&k| k != 0.0))
            }
        };
        Ok(View {
            k: mat3(&camera["K"]).context("K")?,
            dist,
            width: size("width")?,
            height: size("height")?,
            world_to_camera: Rigid {
                r: mat3(&camera["R_w2c"]).context("R_w2c")?,
                t: vec3(&camera["t_w2c"]).context("t_w2c")?,
            },
            model_to_camera: Rigid {
                r: mat3(&camera["R_m2c"]).context("R_m2c")?,
                t: vec3(&camera["t_m2c"]).context("t_m2c")?,
            },
        })
    }

    /// BOP's camera record. BOP has no lens distortion: a distorted view adds `cam_dist`
    /// (OpenCV's order, as the native `dist`), a key BOP's own tools pass over and which
    /// `cam_K` alone does not describe (`docs/formats.md`).
    fn scene_camera(&self) -> Value {
        let mut camera = json!({
            "cam_K": row_major(&self.k).map(|v| round(v, UNIT_DECIMALS)),
            "cam_R_w2c": row_major(&self.world_to_camera.r).map(|v| round(v, UNIT_DECIMALS)),
            "cam_t_w2c": self.world_to_camera.t.map(mm),
            "depth_scale": DEPTH_SCALE_MM,
            "width": self.width,
            "height": self.height,
        });
        if let Some(dist) = self.dist {
            camera["cam_dist"] = json!(dist.map(|v| round(v, UNIT_DECIMALS)));
        }
        camera
    }
}

/// The per-image record `write_scene` gathers into `scene_gt_coco.json` rather than a file by id.
const COCO: &str = "scene_gt_coco.json";

/// The object's COCO annotation, as the toolkit's `calc_gt_coco.py` makes it (amodal box, the
/// default): the visible mask as uncompressed RLE, its pixel count as `area`, the box of the full
/// silhouette, `ignore` when less than a tenth is visible. `None` when either mask is empty (the
/// toolkit writes none then); `id` is numbered by the scene.
fn coco_annotation(im: u64, obj_id: u64, full: &Mask, visible: &Mask, visib_fract: Option<f64>) -> Option<Value> {
    let bbox = full.coco_bbox()?;
    let area = visible.count();
    (area > 0).then(|| {
        json!({
            "area": area,
            "bbox": bbox,
            "category_id": obj_id,
            "height": visible.height,
            "ignore": visib_fract.unwrap_or(0.0) < targets::MIN_VISIB_FRACT,
            "image_id": im,
            "iscrowd": 0,
            "segmentation": {"counts": visible.coco_rle(), "size": [visible.height, visible.width]},
            "width": visible.width,
        })
    })
}

/// BOP's `scene_gt_info` entry, from the masks (and the depth image for `px_count_valid`: the
/// silhouette's pixels with a non-zero depth, as the toolkit's `calc_gt_info.py` counts them).
fn gt_info(full: &Mask, visible: &Mask, depth: Option<&[u16]>) -> Value {
    let (all, visib) = (full.count(), visible.count());
    let mut info = json!({
        "bbox_obj": full.bbox(),
        "bbox_visib": visible.bbox(),
        "px_count_all": all,
        "px_count_visib": visib,
        "visib_fract": if all > 0 { visib as f64 / all as f64 } else { 0.0 },
    });
    if let Some(depth) = depth {
        let valid = full.pixels.iter().zip(depth).filter(|(inside, d)| **inside && **d > 0).count();
        info["px_count_valid"] = json!(valid);
    }
    info
}

/// The grasp's touch seen from this view: each active taxel in the camera frame and the palm
/// frame (mm), and the full reading vector.
fn touch_record(grasp: &Grasp<'_>, view: &View) -> anyhow::Result<Value> {
    let touch = &grasp.record["touch"];
    let palm_to_camera = grasp.palm_to_world.then(&view.world_to_camera);
    let active = touch["active"].as_array().ok_or_else(|| anyhow!("grasp.json has no touch.active"))?;
    let active = active
        .iter()
        .enumerate()
        .map(|(i, a)| {
            let p = vec3(&a["p_palm"]).with_context(|| format!("touch.active[{i}].p_palm"))?;
            let n = vec3(&a["n_palm"]).with_context(|| format!("touch.active[{i}].n_palm"))?;
            let mut entry = json!({
                "taxel": a["taxel"],
                "link": a["link"],
                "region": a["region"],
                "p_cam_mm": palm_to_camera.point(p).map(mm),
                "n_cam": palm_to_camera.direction(n).map(|v| round(v, UNIT_DECIMALS)),
                "p_palm_mm": p.map(mm),
                "n_palm": n.map(|v| round(v, UNIT_DECIMALS)),
                "reading": a["reading"],
                "force_n": a["force_n"],
            });
            if let Some(d) = a["distance_m"].as_f64() {
                entry["distance_mm"] = json!(mm(d));
            }
            Ok(entry)
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    Ok(json!({"active": active, "readings": touch["readings"]}))
}

/// The hand in this view: joint angles (radians, as recorded) and every link's pose in the camera
/// frame (row-major R, t in mm).
fn hand_record(grasp: &Grasp<'_>, view: &View) -> Value {
    let links: serde_json::Map<String, Value> = grasp
        .links
        .iter()
        .map(|(name, link)| {
            let in_camera = link.then(&view.world_to_camera);
            let pose = json!({
                "R": row_major(&in_camera.r).map(|v| round(v, UNIT_DECIMALS)),
                "t_mm": in_camera.t.map(mm),
            });
            (name.clone(), pose)
        })
        .collect();
    json!({
        "hand": grasp.record["hand"]["name"],
        "joints": grasp.record["trial"]["joints"],
        "link_poses_cam": links,
    })
}

/// What identifies the image and what BOP's files do not say: sample and grasp ids, visibility,
/// the environment, the segmentation's and materials' id maps.
fn meta_record(meta: &Value, sample_id: &str, obj_id: u64) -> Value {
    let camera = &meta["camera"];
    json!({
        "sample_id": sample_id,
        "grasp_id": meta["grasp_id"],
        "object": meta["object"]["name"],
        "obj_id": obj_id,
        "hand": meta["hand"],
        "grasp_index": meta["grasp_index"],
        "view_index": meta["view_index"],
        "occlusion": camera["occlusion"],
        "visible_px": camera["visible_px"],
        "full_px": camera["full_px"],
        "environment": camera["environment"],
        "segmentation": camera["segmentation"],
        "materials": camera["materials"],
        "scene": camera["scene"],
    })
}

/// A native depth file in BOP's units (`depth_units`), checked against the view's size: the one
/// reader of native depth for both BOP layouts.
fn read_depth(path: &Path, view: &View) -> anyhow::Result<Vec<u16>> {
    let array = crate::depth::read(path)?;
    if array.shape != [view.height, view.width] {
        bail!("{}: expected {}×{} depth, found {:?}", path.display(), view.height, view.width, array.shape);
    }
    Ok(array.values.iter().map(|&m| depth_units(m)).collect())
}

fn read_mask(path: &Path, view: &View) -> anyhow::Result<Mask> {
    let bytes = fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let mask = Mask::decode(&bytes).with_context(|| format!("{}", path.display()))?;
    if (mask.width, mask.height) != (view.width, view.height) {
        bail!(
            "{}: {}×{} pixels, the camera has {}×{}",
            path.display(),
            mask.width,
            mask.height,
            view.width,
            view.height
        );
    }
    Ok(mask)
}

pub(super) fn read_json(path: &Path) -> anyhow::Result<Value> {
    let bytes = fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_slice(&bytes).with_context(|| format!("{} is not JSON", path.display()))
}

/// A per-id JSON file as the toolkit's `save_json` lays it out: one line per id, ids in numeric
/// order (the readers turn the keys back into integers).
fn by_id(records: &BTreeMap<u64, Value>) -> anyhow::Result<Vec<u8>> {
    let mut text = String::from("{\n");
    for (i, (id, record)) in records.iter().enumerate() {
        let comma = if i + 1 < records.len() { "," } else { "" };
        text += &format!("  \"{id}\": {}{comma}\n", serde_json::to_string(record)?);
    }
    text += "}\n";
    Ok(text.into_bytes())
}

pub(super) fn pretty(value: &Value) -> anyhow::Result<Vec<u8>> {
    let mut bytes = serde_json::to_vec_pretty(value)?;
    bytes.push(b'\n');
    Ok(bytes)
}

fn round(value: f64, decimals: i32) -> f64 {
    let scale = 10f64.powi(decimals);
    (value * scale).round() / scale + 0.0 // + 0.0 turns -0.0 into 0.0
}

/// Metres to millimetres, rounded.
fn mm(metres: f64) -> f64 {
    round(metres * 1000.0, MM_DECIMALS)
}

fn numbers(value: &Value, len: usize) -> Option<Vec<f64>> {
    let list = value.as_array()?;
    let numbers: Vec<f64> = list.iter().filter_map(Value::as_f64).collect();
    (numbers.len() == len && list.len() == len).then_some(numbers)
}

fn vec3(value: &Value) -> anyhow::Result<Vec3> {
    let v = numbers(value, 3).ok_or_else(|| anyhow!("expected 3 numbers, found {value}"))?;
    Ok([v[0], v[1], v[2]])
}

/// A 3×3 matrix given as three rows.
fn mat3(value: &Value) -> anyhow::Result<Mat3> {
    let rows = value.as_array().filter(|r| r.len() == 3).ok_or_else(|| anyhow!("expected 3 rows, found {value}"))?;
    Ok([vec3(&rows[0])?, vec3(&rows[1])?, vec3(&rows[2])?])
}

/// `{p: [x, y, z], q: [w, x, y, z]}`.
fn pose(value: &Value) -> anyhow::Result<Rigid> {
    let q = numbers(&value["q"], 4).ok_or_else(|| anyhow!("expected q = [w, x, y, z], found {}", value["q"]))?;
    Ok(Rigid::from_pose(vec3(&value["p"])?, [q[0], q[1], q[2], q[3]]))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn per_id_files_list_ids_in_numeric_order_one_per_line() {
        let records: BTreeMap<u64, Value> =
            [(10, json!({"b": 1, "a": [1.5]})), (2, json!([])), (0, json!({"z": null}))].into_iter().collect();
        let text = String::from_utf8(by_id(&records).expect("json")).expect("utf-8");
        assert_eq!(text, "{\n  \"0\": {\"z\":null},\n  \"2\": [],\n  \"10\": {\"a\":[1.5],\"b\":1}\n}\n");
        let parsed: Value = serde_json::from_str(&text).expect("valid JSON");
        assert_eq!(parsed["10"]["a"][0], 1.5);
    }

    #[test]
    fn a_model_without_declared_facts_is_taken_as_measured_and_a_missing_key_is_an_error() {
        let geometry = ModelGeometry { min: [0.0; 3], size: [10.0, 20.0, 30.0], diameter: 37.4 };
        check_declared("never_grasped", &geometry, &json!({"diameter_mm": null})).expect("no facts to check");
        check_declared("can", &geometry, &json!({"diameter_mm": 37.4})).expect("agrees");
        let wrong = check_declared("can", &geometry, &json!({"diameter_mm": 40.0})).expect_err("disagrees");
        assert!(wrong.to_string().contains("declares 40.0000 mm"), "{wrong}");
        let missing = check_declared("can", &geometry, &json!({})).expect_err("malformed");
        assert!(missing.to_string().contains("has no diameter_mm"), "{missing}");
    }

    #[test]
    fn lengths_round_to_nanometres_without_negative_zero() {
        assert_eq!(mm(0.123_456_789_4), 123.456789);
        assert_eq!(mm(0.1 + 0.2), 300.0);
        assert_eq!(mm(-1e-12).to_string(), "0");
        assert_eq!(round(-0.000_000_000_1, UNIT_DECIMALS).to_string(), "0");
    }

    #[test]
    fn symmetries_move_to_millimetres_and_keep_their_rotation() {
        let continuous = json!([{"axis": [0.0, 0.0, 1.0], "offset": [0.0, 0.001, -0.002]}]);
        assert_eq!(
            symmetries_in_mm("symmetries_continuous", &continuous, "can").expect("bop form"),
            json!([{"axis": [0.0, 0.0, 1.0], "offset": [0.0, 1.0, -2.0]}])
        );
        let flip = json!([[1.0, 0.0, 0.0, 0.01, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0]]);
        assert_eq!(
            symmetries_in_mm("symmetries_discrete", &flip, "box").expect("bop form"),
            json!([[1.0, 0.0, 0.0, 10.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0]])
        );
        assert!(symmetries_in_mm("symmetries_discrete", &json!([[1.0, 0.0]]), "box").is_err());
    }

    #[test]
    fn gt_info_counts_and_boxes_come_from_the_masks() {
        let mask = |rows: &[&str]| Mask {
            width: rows[0].len(),
            height: rows.len(),
            pixels: rows.iter().flat_map(|r| r.chars().map(|c| c == '#')).collect(),
        };
        let full = mask(&[".##.", ".###", "...."]);
        let visible = mask(&["..#.", "..##", "...."]);
        let depth = [0, 5, 0, 0, 0, 5, 5, 0, 0, 0, 0, 0];
        let info = gt_info(&full, &visible, Some(&depth));
        assert_eq!(info["bbox_obj"], json!([1, 0, 2, 1]));
        assert_eq!(info["bbox_visib"], json!([2, 0, 1, 1]));
        assert_eq!((info["px_count_all"].as_u64(), info["px_count_visib"].as_u64()), (Some(5), Some(3)));
        assert_eq!(info["px_count_valid"], 3, "silhouette pixels with non-zero depth (index 7 is outside it)");
        assert_eq!(info["visib_fract"], 0.6);
        let empty = mask(&["...."]);
        let none = gt_info(&empty, &empty, None);
        assert_eq!((none["visib_fract"].as_f64(), none["bbox_obj"].clone()), (Some(0.0), json!([-1, -1, -1, -1])));
        assert!(none.get("px_count_valid").is_none());
    }

    #[test]
    fn a_view_reads_nested_rows_and_writes_bop_camera_units() {
        let camera = json!({
            "K": [[100.0, 0.0, 63.5], [0.0, 100.0, 63.5], [0.0, 0.0, 1.0]], "width": 128, "height": 96,
            "R_w2c": [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]], "t_w2c": [0.01, 0.0, 0.5],
            "R_m2c": [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], "t_m2c": [0.0, 0.02, 0.45],
        });
        let view = View::of(&camera).expect("view");
        let written = view.scene_camera();
        assert_eq!(written["cam_K"], json!([100.0, 0.0, 63.5, 0.0, 100.0, 63.5, 0.0, 0.0, 1.0]));
        assert_eq!(written["cam_R_w2c"], json!([1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0]));
        assert_eq!(written["cam_t_w2c"], json!([10.0, 0.0, 500.0]));
        assert_eq!(written["depth_scale"], 0.1);
        assert_eq!((view.width, view.height), (128, 96));
        assert!(written.get("cam_dist").is_none(), "a pinhole's record is BOP's own");
        assert!(View::of(&json!({"K": [[1.0, 0.0]]})).is_err());
    }

    #[test]
    fn a_distorted_view_adds_its_lens_as_cam_dist_and_a_zero_lens_adds_nothing() {
        let mut camera = json!({
            "K": [[100.0, 0.0, 63.5], [0.0, 100.0, 47.5], [0.0, 0.0, 1.0]], "width": 128, "height": 96,
            "R_w2c": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "t_w2c": [0.0, 0.0, 0.5],
            "R_m2c": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "t_m2c": [0.0, 0.0, 0.5],
            "dist": [-0.2, 0.05, 0.001, -0.002, 0.01],
        });
        let written = View::of(&camera).expect("view").scene_camera();
        assert_eq!(written["cam_dist"], json!([-0.2, 0.05, 0.001, -0.002, 0.01]));
        assert_eq!(written["cam_K"], json!([100.0, 0.0, 63.5, 0.0, 100.0, 47.5, 0.0, 0.0, 1.0]));
        camera["dist"] = json!([0.0, 0.0, 0.0, 0.0, 0.0]);
        assert!(View::of(&camera).expect("view").scene_camera().get("cam_dist").is_none());
        camera["dist"] = json!([0.1, 0.0]);
        let error = View::of(&camera).err().expect("a short dist is refused");
        assert!(error.to_string().contains("dist: expected 5 numbers"), "{error}");
    }
}
