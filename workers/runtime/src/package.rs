//! The package stage, in Rust: turns a shard's grasp, render and noise outputs into one record
//! per grasp and one directory per sample (`vint_core::contract::package`).
//!
//! A grasp's record, `<grasp_id>/grasp.json`, holds what its views share — the object and hand,
//! poses of every link, joints, contacts, the full touch reading, physics settings — once. A
//! sample's `<sample_id>/meta.json` holds its view (camera, visibility, object and hand poses) and
//! refers to its grasp's record by path and SHA-256; next to it are the requested image and depth
//! files. Packaging moves no pixels: those files are the render and noise artifacts themselves,
//! referenced by hash, so only the small JSON inputs are read and only JSON is written.

use std::collections::BTreeMap;

use serde_json::{Value, json};
use vint_artifacts::ArtifactStore;
use vint_core::contract::depth::DepthFormat;
use vint_core::contract::grasp::{GRASPS_FILE, TOUCH_FILE};
use vint_core::contract::package::{GRASP_RECORD_FILE, META_FILE, Modality, PackageResult, Params, model_path};
use vint_core::contract::render::{self, ViewFile};
use vint_core::plan::GraspChunk;
use vint_core::{GraspId, SampleId};

/// The package stage's engine identity (`vint_core::reuse`): a package task whose key matches a
/// finished one takes its files instead of running. Bump its number (in the contract) whenever the
/// files this module writes change for the same inputs; `tests::the_package_format_is_pinned`
/// fails until you do.
pub use vint_core::contract::package::ENGINE_IDENTITY as IDENTITY;

/// An input of the package task: an artifact of one of its dependencies.
#[derive(Clone, Debug)]
pub struct PackageInput {
    pub name: String,
    pub task_key: String,
    pub sha256: String,
    pub size: u64,
    pub media_type: String,
    pub key: String,
}

impl From<&vint_proto::v1::ArtifactRef> for PackageInput {
    fn from(a: &vint_proto::v1::ArtifactRef) -> PackageInput {
        PackageInput {
            name: a.name.clone(),
            task_key: a.task_key.clone(),
            sha256: a.sha256.clone(),
            size: a.size,
            media_type: a.media_type.clone(),
            key: a.key.clone(),
        }
    }
}

/// A file of a packaged sample, named `<sample_id>/<file>`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PackagedFile {
    pub name: String,
    pub sha256: String,
    pub size: u64,
    pub media_type: String,
    pub key: String,
}

#[derive(Debug, thiserror::Error)]
pub enum PackageError {
    #[error("package params: {0}")]
    Params(String),
    #[error("sample {sample}: input {name:?} of task {task_key} is missing")]
    MissingInput { sample: String, task_key: String, name: String },
    #[error("sample {sample}: {what}")]
    BadInput { sample: String, what: String },
    #[error(transparent)]
    Artifact(#[from] vint_artifacts::ArtifactError),
}

impl PackageError {
    /// Only storage trouble is worth a retry; a malformed input stays malformed.
    pub fn retryable(&self) -> bool {
        matches!(self, PackageError::Artifact(_))
    }
}

/// A package task's output files and its result (the samples and grasp records it made).
pub struct Packaged {
    pub files: Vec<PackagedFile>,
    pub result: PackageResult,
    /// Bytes read from and written to the object store (for the worker's metrics).
    pub bytes_read: u64,
    pub bytes_written: u64,
}

/// A package task's inputs by origin: (task key, file name).
pub(crate) struct Inputs<'a> {
    by_origin: BTreeMap<(&'a str, &'a str), &'a PackageInput>,
}

impl<'a> Inputs<'a> {
    pub(crate) fn new(inputs: &'a [PackageInput]) -> Inputs<'a> {
        Inputs { by_origin: inputs.iter().map(|i| ((i.task_key.as_str(), i.name.as_str()), i)).collect() }
    }

    fn find(&self, sample: &str, task_key: String, name: String) -> Result<&'a PackageInput, PackageError> {
        self.by_origin.get(&(task_key.as_str(), name.as_str())).copied().ok_or_else(|| PackageError::MissingInput {
            sample: sample.to_string(),
            task_key,
            name,
        })
    }
}

/// A sample's image and depth files: its render and noise tasks' artifacts for its view, named
/// `<sample_id>/<file>` and referenced by hash (packaging moves no pixels).
pub(crate) fn referenced_files(
    inputs: &Inputs<'_>,
    id: &SampleId,
    modalities: &[Modality],
    depth_format: DepthFormat,
) -> Result<Vec<PackagedFile>, PackageError> {
    let sample = id.to_string();
    let mut files = Vec::new();
    for modality in modalities {
        for file in modality.sample_files(depth_format) {
            let (task_key, name) = file.from.origin(id);
            let src = inputs.find(&sample, task_key, name)?;
            files.push(PackagedFile {
                name: format!("{sample}/{}", file.name),
                sha256: src.sha256.clone(),
                size: src.size,
                media_type: src.media_type.clone(),
                key: src.key.clone(),
            });
        }
    }
    Ok(files)
}

pub async fn package(params: &Value, inputs: &[PackageInput], store: &ArtifactStore) -> Result<Packaged, PackageError> {
    let params: Params = serde_json::from_value(params.clone()).map_err(|e| PackageError::Params(e.to_string()))?;
    let by_origin = Inputs::new(inputs);
    // Each (object, hand)'s grasp document, found once rather than by a scan of every input per sample.
    let grasp_inputs: BTreeMap<(String, String), &PackageInput> = inputs
        .iter()
        .filter(|i| i.name == GRASPS_FILE)
        .filter_map(|i| GraspChunk::from_key(&i.task_key).map(|c| ((c.object, c.hand), i)))
        .collect();
    let mut documents: BTreeMap<String, Value> = BTreeMap::new();
    let mut records: BTreeMap<GraspId, (String, PackagedFile)> = BTreeMap::new();
    let mut files = Vec::new();
    let mut samples = Vec::new();
    let (mut bytes_read, mut bytes_written) = (0, 0);
    for s in &params.samples {
        let id: SampleId =
            s.sample_id.parse().map_err(|e: vint_core::sample::BadSampleId| PackageError::Params(e.to_string()))?;
        files.extend(referenced_files(&by_origin, &id, &params.modalities, params.depth_format)?);
        let render = render::task_key(&id.object, &id.hand, id.grasp_index);
        let camera_ref = by_origin.find(&s.sample_id, render, ViewFile::Camera.name(id.view_index))?;
        let camera = read_json(store, camera_ref, &s.sample_id).await?;
        bytes_read += camera_ref.size;
        let grasp_ref = grasp_inputs.get(&(id.object.clone(), id.hand.clone())).copied().ok_or_else(|| {
            PackageError::MissingInput {
                sample: s.sample_id.clone(),
                task_key: format!("grasp/{}/{}/…", id.object, id.hand),
                name: GRASPS_FILE.into(),
            }
        })?;
        let touch_ref = by_origin.find(&s.sample_id, grasp_ref.task_key.clone(), TOUCH_FILE.to_string())?;
        for input in [grasp_ref, touch_ref] {
            if !documents.contains_key(&input.sha256) {
                let doc = read_json(store, input, &s.sample_id).await?;
                bytes_read += input.size;
                documents.insert(input.sha256.clone(), doc);
            }
        }
        let (grasps, touch) = (&documents[&grasp_ref.sha256], &documents[&touch_ref.sha256]);
        let grasp = id.grasp();
        if !records.contains_key(&grasp) {
            let record = grasp_record(&grasp, grasps, touch)?;
            let stored = store.put_bytes(to_json_bytes(&record)?.into()).await?;
            bytes_written += stored.size;
            let file = PackagedFile {
                name: format!("{grasp}/{GRASP_RECORD_FILE}"),
                sha256: stored.sha256.clone(),
                size: stored.size,
                media_type: "application/json".into(),
                key: stored.key,
            };
            records.insert(grasp.clone(), (stored.sha256, file));
        }
        let record_sha = &records[&grasp].0;
        let meta = sample_meta(&id, grasps, &camera, record_sha)?;
        let stored = store.put_bytes(to_json_bytes(&meta)?.into()).await?;
        bytes_written += stored.size;
        files.push(PackagedFile {
            name: format!("{}/{META_FILE}", s.sample_id),
            sha256: stored.sha256,
            size: stored.size,
            media_type: "application/json".into(),
            key: stored.key,
        });
        samples.push(s.sample_id.clone());
    }
    let grasps = records.keys().map(GraspId::to_string).collect();
    files.extend(records.into_values().map(|(_, file)| file));
    Ok(Packaged { files, result: PackageResult { samples, grasps }, bytes_read, bytes_written })
}

fn to_json_bytes(value: &Value) -> Result<Vec<u8>, PackageError> {
    serde_json::to_vec_pretty(value).map_err(|e| PackageError::Params(e.to_string()))
}

async fn read_json(store: &ArtifactStore, input: &PackageInput, sample: &str) -> Result<Value, PackageError> {
    let bytes = store.get(&input.sha256).await?;
    serde_json::from_slice(&bytes).map_err(|e| PackageError::BadInput {
        sample: sample.to_string(),
        what: format!("{} is not JSON: {e}", input.name),
    })
}

/// The entry of `grasp_index` in a document's `trials`.
fn trial_of<'a>(doc: &'a Value, grasp_index: u32, file: &str, sample: &str) -> Result<&'a Value, PackageError> {
    doc["trials"]
        .as_array()
        .and_then(|ts| ts.iter().find(|t| t["grasp_index"].as_u64() == Some(u64::from(grasp_index))))
        .ok_or_else(|| PackageError::BadInput {
            sample: sample.to_string(),
            what: format!("{file} has no trial {grasp_index}"),
        })
}

/// What every view of a grasp shares, stored once: the object (its full catalog entry and model),
/// the hand (its links' geometry and taxel layout), the trial (seed, every link's pose, joints,
/// contacts, hold, approach, stability), its full touch reading, and the physics and touch
/// settings it ran with.
fn grasp_record(grasp: &GraspId, grasps: &Value, touch: &Value) -> Result<Value, PackageError> {
    let name = grasp.to_string();
    let trial = trial_of(grasps, grasp.grasp_index, GRASPS_FILE, &name)?;
    if trial["accepted"].as_bool() != Some(true) {
        return Err(PackageError::BadInput {
            sample: name,
            what: format!("trial {} was not accepted", grasp.grasp_index),
        });
    }
    let reading = trial_of(touch, grasp.grasp_index, TOUCH_FILE, &name)?;
    let reading: serde_json::Map<String, Value> = reading
        .as_object()
        .into_iter()
        .flatten()
        .filter(|(k, _)| *k != "grasp_index")
        .map(|(k, v)| (k.clone(), v.clone()))
        .collect();
    let mut trial_fields = trial.as_object().cloned().unwrap_or_default();
    for summary_only in ["touch", "accepted", "reason", "grasp_index"] {
        trial_fields.remove(summary_only);
    }
    Ok(json!({
        "grasp_id": name,
        "object": with_model_path(&grasps["object"]),
        "hand": grasps["hand"],
        "grasp_index": grasp.grasp_index,
        "trial": trial_fields,
        "touch": reading,
        "physics": grasps["physics"],
        "touch_sensor": grasps["touch"],
        "conventions": {
            "units": "metres, kilograms, seconds, radians",
            "pose": "p = position, q = quaternion [w, x, y, z], world frame",
            "touch": "touch.active: the active taxels (position and outward normal in the palm frame, reading, \
                      local contact force in N, signed distance to the object); touch.readings: one per taxel \
                      of hand.taxels' layout; touch.contact_samples: the contacts whose forces were averaged",
        },
    }))
}

/// The object record with its model's file named as the dataset keeps it (`../models/<name>.ply`
/// from a grasp's or a sample's directory), not as the grasp task wrote it next to grasps.json.
fn with_model_path(object: &Value) -> Value {
    let mut object = object.clone();
    let file = object["name"].as_str().map(|name| format!("../{}", model_path(name)));
    if let Some(file) = file
        && let Some(model) = object.get_mut("model").and_then(Value::as_object_mut)
    {
        model.insert("file".into(), json!(file));
    }
    object
}

/// A sample's metadata: its view — camera, visibility, the object's and hand's poses — and a
/// reference to its grasp's record (`../<grasp_id>/grasp.json`, by SHA-256).
fn sample_meta(id: &SampleId, grasps: &Value, camera: &Value, record_sha256: &str) -> Result<Value, PackageError> {
    let trial = trial_of(grasps, id.grasp_index, GRASPS_FILE, &id.to_string())?;
    let object = &grasps["object"];
    let grasp = id.grasp();
    Ok(json!({
        "sample_id": id.to_string(),
        "grasp_id": grasp.to_string(),
        "object": {
            "name": object["name"],
            "ycb_id": object["ycb_id"],
            "material": object["material"],
            "texture": object["texture"],
            "symmetries_continuous": object["symmetries_continuous"],
            "symmetries_discrete": object["symmetries_discrete"],
            "model": with_model_path(object)["model"],
        },
        "hand": grasps["hand"]["name"],
        "grasp_index": id.grasp_index,
        "view_index": id.view_index,
        "camera": camera,
        "visibility": {
            "visible_px": camera["visible_px"],
            "full_px": camera["full_px"],
            "occlusion": camera["occlusion"],
        },
        "poses": {"object": trial["object_pose"], "hand": trial["hand_pose"]},
        "grasp": {
            "record": format!("../{grasp}/{GRASP_RECORD_FILE}"),
            "sha256": record_sha256,
            "seed": trial["seed"],
            "touch": trial["touch"],
        },
        "conventions": {
            "units": "metres, kilograms, seconds, radians",
            "pose": "p = position, q = quaternion [w, x, y, z], world frame",
            "camera": "OpenCV: x right, y down, z forward; R_w2c/t_w2c map world to camera",
            "depth": "along the optical axis, 0 = no return: depth.png and depth_noisy.png in uint16 steps of 0.1 mm (BOP's depth_scale 0.1), depth.npy and depth_noisy.npy in float32 metres",
            "masks": "mask.png: the object's visible pixels; mask_full.png: the object alone, as if the hand were not there",
            "segmentation": "segmentation.png: 0 background, 1 object, 2.. hand links, then the arm's flange and link and the table when shown; camera.segmentation maps id to name",
            "occlusion": "1 - visible_px / full_px: the share of the object the hand hides (1 when out of view)",
            "grasp": "grasp.record: the grasp's record shared by its views (link poses, joints, contacts, touch)",
        },
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grasps() -> Value {
        json!({
            "object": {"name": "mug", "ycb_id": "025", "material": "ceramic", "texture": {"kind": "glaze"},
                        "symmetries_continuous": [], "symmetries_discrete": [],
                       "shape": {"type": "mesh", "path": "m.obj", "scale": 0.001}, "model": {"extent_m": [0.1, 0.1, 0.1]}},
            "hand": {"name": "trx3", "links": [{"name": "palm"}]},
            "trials": [{"grasp_index": 3, "seed": 7, "accepted": true, "reason": null,
                        "object_pose": {"p": [0, 0, 0.1], "q": [1, 0, 0, 0]}, "hand_pose": {"p": [0, 0, 0.2], "q": [1, 0, 0, 0]},
                        "link_poses": {"palm": {"p": [0, 0, 0.2], "q": [1, 0, 0, 0]}}, "joints": {"f0_j0": 0.5},
                        "touch": {"contact_margin_m": 0.0005, "active_count": 1}}],
            "physics": {"timestep": 0.002},
            "touch": {"contact_margin_m": 0.0005},
        })
    }

    fn touch() -> Value {
        json!({"hand": "trx3", "trials": [
            {"grasp_index": 1, "contact_margin_m": 0.0005, "active_count": 0, "active": [], "readings": [0.0, 0.0, 0.0]},
            {"grasp_index": 3, "contact_margin_m": 0.0005, "active_count": 1, "active": [{"taxel": 2}], "readings": [0.0, 0.0, 0.5]},
        ]})
    }

    fn grasp() -> GraspId {
        "mug.trx3.g000003".parse().expect("a valid grasp id")
    }

    /// The bytes this module writes for a fixed input, pinned with `IDENTITY`: finished package
    /// tasks are reused by that identity, so output that changes under it would mix formats in a
    /// dataset. Changed the output on purpose? Bump `IDENTITY`'s number and pin the new digest.
    #[test]
    fn the_package_format_is_pinned() {
        let record = to_json_bytes(&grasp_record(&grasp(), &grasps(), &touch()).expect("record")).expect("bytes");
        let camera = json!({"K": [[600.5, 0, 320], [0, 600.5, 240], [0, 0, 1]], "visible_px": 5, "full_px": 10});
        let id: SampleId = "mug.trx3.g000003.v01".parse().expect("a valid sample id");
        let meta = to_json_bytes(&sample_meta(&id, &grasps(), &camera, "ab").expect("meta")).expect("bytes");
        use sha2::Digest;
        let digest = |b: &[u8]| hex::encode(sha2::Sha256::digest(b));
        let pinned = (IDENTITY, digest(&record), digest(&meta));
        let expected = (
            "vint-package-format-2",
            "9aa3352c29e474d87ab06a223e658422c057d1a9afff93343af9a3c5a632e0c8".to_string(),
            "d294d71eaa04f764b98bcc28a1aab4b2db2619debfad92b2350e69e882cefd3c".to_string(),
        );
        assert_eq!(pinned, expected, "the package output changed: see this test's doc comment");
    }

    #[test]
    fn the_grasp_record_holds_the_full_touch_reading_and_every_link_pose_once() {
        let record = grasp_record(&grasp(), &grasps(), &touch()).expect("record");
        assert_eq!(
            record["touch"],
            json!({"contact_margin_m": 0.0005, "active_count": 1, "active": [{"taxel": 2}], "readings": [0.0, 0.0, 0.5]})
        );
        assert_eq!(record["trial"]["link_poses"]["palm"]["p"][2], 0.2);
        assert_eq!(record["trial"]["joints"]["f0_j0"], 0.5);
        assert_eq!(record["object"]["shape"]["path"], "m.obj");
        assert!(record["trial"].get("accepted").is_none() && record["trial"].get("touch").is_none());
    }

    #[test]
    fn a_sample_refers_to_its_grasp_record_and_carries_no_touch_reading() {
        let id: SampleId = "mug.trx3.g000003.v01".parse().expect("a valid sample id");
        let camera = json!({"K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "visible_px": 5, "full_px": 10, "occlusion": 0.5});
        let meta = sample_meta(&id, &grasps(), &camera, &"a".repeat(64)).expect("meta");
        assert_eq!(meta["grasp"]["record"], "../mug.trx3.g000003/grasp.json");
        assert_eq!(meta["grasp"]["sha256"], "a".repeat(64));
        assert_eq!(meta["poses"]["object"]["p"][2], 0.1);
        assert!(meta["object"].get("shape").is_none(), "the object's shape lives in the grasp record");
        assert!(!meta.to_string().contains("readings"), "{meta}");
    }

    #[test]
    fn a_trial_missing_from_touch_json_is_bad_input() {
        let touch = json!({"trials": [{"grasp_index": 1, "active": []}]});
        let err = grasp_record(&grasp(), &grasps(), &touch).expect_err("no trial 3");
        assert!(!err.retryable() && err.to_string().contains("touch.json has no trial 3"), "{err}");
    }

    #[test]
    fn a_rejected_trial_is_not_packaged() {
        let mut doc = grasps();
        doc["trials"][0]["accepted"] = json!(false);
        let err = grasp_record(&grasp(), &doc, &touch()).expect_err("rejected");
        assert!(err.to_string().contains("was not accepted"), "{err}");
    }
}
