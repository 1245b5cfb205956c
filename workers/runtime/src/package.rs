//! The package stage, in Rust: turns a shard's grasp, render and noise outputs into one directory
//! per sample — the requested image/depth files plus `meta.json` (object, hand and link poses,
//! joints, contacts, camera intrinsics and extrinsics, seeds and physics settings).
//!
//! Packaging moves no pixels: a sample's image and depth files are the render and noise
//! artifacts themselves, referenced by hash, so only the small JSON inputs are read and only
//! `meta.json` is written.

use std::collections::BTreeMap;

use serde::Deserialize;
use serde_json::{Value, json};
use vint_artifacts::ArtifactStore;
use vint_core::plan::{noise_key, render_key};
use vint_core::{SampleId, SampleId as Sid};

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

#[derive(Deserialize)]
struct Params {
    samples: Vec<SampleRef>,
    modalities: Vec<String>,
}

#[derive(Deserialize)]
struct SampleRef {
    sample_id: String,
}

/// Which artifact each requested modality comes from: (file in the sample, producing stage, name
/// pattern with `{v}` for the two-digit view index).
const MODALITY_FILES: &[(&str, &str, &str, &str)] = &[
    ("rgb", "rgb.png", "render", "v{v}_rgb.png"),
    ("depth", "depth.npy", "render", "v{v}_depth.npy"),
    ("depth_noisy", "depth_noisy.npy", "noise", "v{v}_depth_noisy.npy"),
    ("mask", "mask.png", "render", "v{v}_mask.png"),
    ("mask", "mask_full.png", "render", "v{v}_mask_full.png"),
    ("segmentation", "segmentation.png", "render", "v{v}_segmentation.png"),
];

pub async fn package(
    params: &Value,
    inputs: &[PackageInput],
    store: &ArtifactStore,
) -> Result<Vec<PackagedFile>, PackageError> {
    let params: Params = serde_json::from_value(params.clone()).map_err(|e| PackageError::Params(e.to_string()))?;
    let by_origin: BTreeMap<(&str, &str), &PackageInput> =
        inputs.iter().map(|i| ((i.task_key.as_str(), i.name.as_str()), i)).collect();
    let mut grasp_docs: BTreeMap<String, Value> = BTreeMap::new();
    let mut files = Vec::new();
    for s in &params.samples {
        let id: SampleId =
            s.sample_id.parse().map_err(|e: vint_core::sample::BadSampleId| PackageError::Params(e.to_string()))?;
        let find = |task_key: String, name: String| {
            by_origin.get(&(task_key.as_str(), name.as_str())).copied().ok_or_else(|| PackageError::MissingInput {
                sample: s.sample_id.clone(),
                task_key,
                name,
            })
        };
        let view = format!("{:02}", id.view_index);
        for (modality, file, stage, pattern) in MODALITY_FILES {
            if !params.modalities.iter().any(|m| m == modality) {
                continue;
            }
            let task_key = match *stage {
                "noise" => noise_key(&id.object, &id.hand, id.grasp_index),
                _ => render_key(&id.object, &id.hand, id.grasp_index),
            };
            let src = find(task_key, pattern.replace("{v}", &view))?;
            files.push(PackagedFile {
                name: format!("{}/{file}", s.sample_id),
                sha256: src.sha256.clone(),
                size: src.size,
                media_type: src.media_type.clone(),
                key: src.key.clone(),
            });
        }
        let camera_ref = find(render_key(&id.object, &id.hand, id.grasp_index), format!("v{view}_camera.json"))?;
        let camera = read_json(store, camera_ref, &s.sample_id).await?;
        let grasp_ref = inputs
            .iter()
            .find(|i| i.name == "grasps.json" && i.task_key.starts_with(&format!("grasp/{}/{}/", id.object, id.hand)))
            .ok_or_else(|| PackageError::MissingInput {
                sample: s.sample_id.clone(),
                task_key: format!("grasp/{}/{}/…", id.object, id.hand),
                name: "grasps.json".into(),
            })?;
        // The touch readings come in their own artifact of the same grasp task (render tasks do not
        // fetch it); grasp outputs from before the split carry them in grasps.json.
        let touch_ref = by_origin.get(&(grasp_ref.task_key.as_str(), TOUCH_FILE)).copied();
        for input in std::iter::once(grasp_ref).chain(touch_ref) {
            if !grasp_docs.contains_key(&input.sha256) {
                let doc = read_json(store, input, &s.sample_id).await?;
                grasp_docs.insert(input.sha256.clone(), doc);
            }
        }
        let grasps = &grasp_docs[&grasp_ref.sha256];
        let touch = touch_ref.map(|t| &grasp_docs[&t.sha256]);
        let meta = sample_meta(&id, grasps, touch, &camera)?;
        let bytes = serde_json::to_vec_pretty(&meta).map_err(|e| PackageError::Params(e.to_string()))?;
        let stored = store.put_bytes(bytes.into()).await?;
        files.push(PackagedFile {
            name: format!("{}/meta.json", s.sample_id),
            sha256: stored.sha256,
            size: stored.size,
            media_type: "application/json".into(),
            key: stored.key,
        });
    }
    Ok(files)
}

async fn read_json(store: &ArtifactStore, input: &PackageInput, sample: &str) -> Result<Value, PackageError> {
    let bytes = store.get(&input.sha256).await?;
    serde_json::from_slice(&bytes).map_err(|e| PackageError::BadInput {
        sample: sample.to_string(),
        what: format!("{} is not JSON: {e}", input.name),
    })
}

/// The grasp task's artifact holding every accepted trial's full touch record.
const TOUCH_FILE: &str = "touch.json";

/// The touch record of the sample's trial in `touch.json` (its entry without `grasp_index`).
fn trial_touch(id: &Sid, touch: &Value) -> Result<Value, PackageError> {
    let entry = touch["trials"]
        .as_array()
        .and_then(|ts| ts.iter().find(|t| t["grasp_index"].as_u64() == Some(u64::from(id.grasp_index))))
        .and_then(Value::as_object)
        .ok_or_else(|| PackageError::BadInput {
            sample: id.to_string(),
            what: format!("{TOUCH_FILE} has no trial {}", id.grasp_index),
        })?;
    Ok(Value::Object(entry.iter().filter(|(k, _)| *k != "grasp_index").map(|(k, v)| (k.clone(), v.clone())).collect()))
}

/// The sample's metadata: everything a training pipeline needs besides the pixels. `touch` is the
/// grasp task's `touch.json`, when it wrote one.
fn sample_meta(id: &Sid, grasps: &Value, touch: Option<&Value>, camera: &Value) -> Result<Value, PackageError> {
    let trial = grasps["trials"]
        .as_array()
        .and_then(|ts| ts.iter().find(|t| t["grasp_index"].as_u64() == Some(u64::from(id.grasp_index))))
        .ok_or_else(|| PackageError::BadInput {
            sample: id.to_string(),
            what: format!("grasps.json has no trial {}", id.grasp_index),
        })?;
    if trial["accepted"].as_bool() != Some(true) {
        return Err(PackageError::BadInput {
            sample: id.to_string(),
            what: format!("trial {} was not accepted", id.grasp_index),
        });
    }
    let touch = match touch {
        Some(doc) => trial_touch(id, doc)?,
        None => trial["touch"].clone(),
    };
    Ok(json!({
        "sample_id": id.to_string(),
        "object": grasps["object"],
        "hand": grasps["hand"]["name"],
        "grasp_index": id.grasp_index,
        "view_index": id.view_index,
        "camera": camera,
        "visibility": {
            "visible_px": camera["visible_px"],
            "full_px": camera["full_px"],
            "occlusion": camera["occlusion"],
        },
        "grasp": {
            "seed": trial["seed"],
            "object_pose": trial["object_pose"],
            "hand_pose": trial["hand_pose"],
            "link_poses": trial["link_poses"],
            "joints": trial["joints"],
            "contacts": trial["contacts"],
            "hold": trial["hold"],
            "touch": touch,
        },
        "physics": grasps["physics"],
        "conventions": {
            "units": "metres, kilograms, seconds, radians",
            "pose": "p = position, q = quaternion [w, x, y, z], world frame",
            "camera": "OpenCV: x right, y down, z forward; R_w2c/t_w2c map world to camera",
            "depth": "float32 metres along the optical axis, 0 = no return",
            "masks": "mask.png: the object's visible pixels; mask_full.png: the object alone, as if the hand were not there",
            "segmentation": "segmentation.png: 0 background, 1 object, 2.. hand links; camera.segmentation maps id to name",
            "occlusion": "1 - visible_px / full_px: the share of the object the hand hides (1 when out of view)",
        },
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grasps(touch: Value) -> Value {
        json!({
            "object": {"name": "mug"},
            "hand": {"name": "trx3"},
            "trials": [{"grasp_index": 3, "seed": 7, "accepted": true, "reason": null, "touch": touch}],
            "physics": {},
        })
    }

    fn sample() -> Sid {
        "mug.trx3.g000003.v01".parse().expect("a valid sample id")
    }

    #[test]
    fn meta_takes_the_full_touch_record_from_touch_json() {
        let full =
            json!({"sensing_depth_m": 0.003, "active_count": 1, "active": [{"taxel": 2}], "readings": [0.0, 0.0, 0.5]});
        let touch = json!({"hand": "trx3", "trials": [
            {"grasp_index": 1, "sensing_depth_m": 0.003, "active_count": 0, "active": [], "readings": [0.0, 0.0, 0.0]},
            {"grasp_index": 3, "sensing_depth_m": 0.003, "active_count": 1, "active": [{"taxel": 2}], "readings": [0.0, 0.0, 0.5]},
        ]});
        let summary = grasps(json!({"sensing_depth_m": 0.003, "active_count": 1}));
        let meta = sample_meta(&sample(), &summary, Some(&touch), &json!({})).expect("meta");
        assert_eq!(meta["grasp"]["touch"], full);
        // Grasp outputs from before touch.json carry the full record in grasps.json.
        let meta = sample_meta(&sample(), &grasps(full.clone()), None, &json!({})).expect("meta");
        assert_eq!(meta["grasp"]["touch"], full);
    }

    #[test]
    fn a_trial_missing_from_touch_json_is_bad_input() {
        let touch = json!({"trials": [{"grasp_index": 1, "active": []}]});
        let summary = grasps(json!({"active_count": 1}));
        let err = sample_meta(&sample(), &summary, Some(&touch), &json!({})).expect_err("no trial 3");
        assert!(!err.retryable() && err.to_string().contains("touch.json has no trial 3"), "{err}");
    }
}
