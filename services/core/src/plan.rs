//! The planner: how a job's spec becomes a DAG of tasks, materialized as inputs appear.
//!
//! At submit only the grasp-sim tasks exist (one per object × hand × chunk of trials). When a grasp
//! task completes, its accepted grasps fan out into a render task each (all views), a noise task
//! each (when noisy depth is requested), and one package task for the chunk (its shard) that waits
//! for all of them. So the task table grows with the work done, not with the job's size: a
//! 2-million-sample job starts with a few thousand rows.
//!
//! Task keys are deterministic and unique within a job; a task's parameters hold everything its
//! engine needs, seeds included, so a task can be re-run anywhere with the same result.

use serde_json::{Value, json};

use crate::asset::Asset;
use crate::catalog;
use crate::sample::SampleId;
use crate::seed;
use crate::spec::DatasetSpec;
use crate::stage::Stage;

/// A task to insert, with the keys of the tasks it depends on (all within the same job).
#[derive(Clone, Debug, PartialEq)]
pub struct NewTask {
    pub key: String,
    pub stage: Stage,
    pub params: Value,
    pub deps: Vec<String>,
}

/// One grasp-sim task's identity: a chunk of trial indices of one (object, hand) pair.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GraspChunk {
    pub object: String,
    pub hand: String,
    pub chunk: u32,
}

impl GraspChunk {
    pub fn key(&self) -> String {
        format!("grasp/{}/{}/c{:05}", self.object, self.hand, self.chunk)
    }

    pub fn package_key(&self) -> String {
        format!("package/{}/{}/c{:05}", self.object, self.hand, self.chunk)
    }

    /// Parses a grasp task key back into its identity.
    pub fn from_key(key: &str) -> Option<GraspChunk> {
        let rest = key.strip_prefix("grasp/")?;
        let mut it = rest.split('/');
        let (object, hand, chunk) = (it.next()?, it.next()?, it.next()?);
        if it.next().is_some() {
            return None;
        }
        let chunk = chunk.strip_prefix('c')?.parse().ok()?;
        Some(GraspChunk { object: object.to_string(), hand: hand.to_string(), chunk })
    }

    /// The trial indices this chunk runs.
    pub fn trials(&self, spec: &DatasetSpec) -> std::ops::Range<u32> {
        let start = self.chunk * spec.grasp.chunk_size;
        start..(start + spec.grasp.chunk_size).min(spec.grasp.trials_per_pair)
    }
}

pub fn render_key(object: &str, hand: &str, grasp_index: u32) -> String {
    format!("render/{object}/{hand}/g{grasp_index:06}")
}

pub fn noise_key(object: &str, hand: &str, grasp_index: u32) -> String {
    format!("noise/{object}/{hand}/g{grasp_index:06}")
}

/// The chunk a grasp index belongs to.
pub fn chunk_of(spec: &DatasetSpec, object: &str, hand: &str, grasp_index: u32) -> GraspChunk {
    GraspChunk { object: object.to_string(), hand: hand.to_string(), chunk: grasp_index / spec.grasp.chunk_size }
}

/// Why a spec cannot be planned.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum PlanError {
    #[error("{field}: the file {path:?} is not among the submitted assets")]
    MissingAsset { field: String, path: String },
}

/// The tasks that exist at submit: every grasp-sim chunk. `assets` are the stored files the
/// spec names (`DatasetSpec::asset_uses`); every one must be there.
pub fn initial_tasks(spec: &DatasetSpec, assets: &[Asset]) -> Result<Vec<NewTask>, PlanError> {
    if let Some(u) = spec.asset_uses().into_iter().find(|u| !assets.iter().any(|a| a.path == u.path)) {
        return Err(PlanError::MissingAsset { field: u.field, path: u.path });
    }
    let mut tasks = Vec::new();
    for object in &spec.objects {
        for hand in &spec.hands {
            for chunk in 0..spec.chunks_per_pair() {
                let c = GraspChunk { object: object.clone(), hand: hand.clone(), chunk };
                let params = grasp_params(spec, &c, assets);
                tasks.push(NewTask { key: c.key(), stage: Stage::Grasp, params, deps: vec![] });
            }
        }
    }
    Ok(tasks)
}

/// A grasp task's `hand` and `object` parameters, and the asset files they name by SHA-256 (the
/// task's `assets`, which the worker stages for the engine): a built-in hand is its name, a
/// user's hand adds its `mjcf` and `taxels` files; a built-in object is its catalog entry, a
/// user's object an entry of the same schema whose shape is a `mesh` asset.
fn hand_and_object(spec: &DatasetSpec, c: &GraspChunk, assets: &[Asset]) -> (Value, Value, Vec<Asset>) {
    let mut used: Vec<Asset> = Vec::new();
    let mut sha = |path: &str| -> String {
        let Some(a) = assets.iter().find(|a| a.path == path) else {
            return String::new(); // unreachable: `initial_tasks` checked every use
        };
        if !used.contains(a) {
            used.push(a.clone());
        }
        a.sha256.clone()
    };
    let hand = match spec.hand_defs.get(&c.hand) {
        Some(h) => json!({"name": c.hand, "mjcf": sha(&h.mjcf), "taxels": sha(&h.taxels)}),
        None => json!({"name": c.hand}),
    };
    let object = match spec.object_defs.get(&c.object) {
        Some(o) => json!({
            "name": c.object,
            "ycb_id": "",
            "mass_kg": o.mass_kg,
            "material": o.material,
            "symmetry": o.symmetry,
            "description": format!("user mesh {}", o.mesh),
            "shape": {"type": "mesh", "asset": sha(&o.mesh), "scale": o.scale()},
        }),
        None => json!(catalog::object(&c.object)),
    };
    (hand, object, used)
}

fn grasp_params(spec: &DatasetSpec, c: &GraspChunk, assets: &[Asset]) -> Value {
    let trials: Vec<Value> = c
        .trials(spec)
        .map(|g| json!({"grasp_index": g, "seed": seed::grasp_trial(spec.dataset.seed, &c.object, &c.hand, g)}))
        .collect();
    let (hand, object, used) = hand_and_object(spec, c, assets);
    let mut params = json!({
        "object": object,
        "hand": hand,
        "trials": trials,
        "touch": {
            "sensing_depth_m": spec.touch.sensing_depth_m,
            "response_depth_m": spec.touch.response_depth_m,
            "gain_sigma": spec.touch.gain_sigma,
            "aging": spec.touch.aging,
            "min_active_taxels": spec.touch.min_active_taxels,
            "gain_seed": seed::taxel_gains(spec.dataset.seed, &c.hand),
        },
        "physics": {
            "timestep": spec.grasp.timestep_s,
            "lift_height": spec.grasp.lift_height_m,
            "hold_s": spec.grasp.hold_s,
            "max_drop_m": spec.grasp.max_drop_m,
            "standoff_ratio": spec.grasp.standoff_ratio,
            "shake": {
                "enabled": spec.grasp.shake_accel_mps2 > 0.0,
                "accel_mps2": if spec.grasp.shake_accel_mps2 > 0.0 { spec.grasp.shake_accel_mps2 } else { 5.0 },
                "directions": spec.grasp.shake_directions,
                "duration_s": spec.grasp.shake_duration_s,
            },
        },
    });
    if !used.is_empty() {
        params["assets"] = json!(used);
    }
    params
}

/// The tasks a completed grasp chunk unlocks, given its accepted grasp indices. `assets` are the
/// job's stored files (render tasks name the spec's own HDRIs by SHA-256).
pub fn after_grasp(
    spec: &DatasetSpec,
    chunk: &GraspChunk,
    accepted: &[u32],
    assets: &[Asset],
) -> Result<Vec<NewTask>, PlanError> {
    let (object, hand) = (chunk.object.as_str(), chunk.hand.as_str());
    let noisy = spec.outputs.wants("depth_noisy");
    let environments = RenderEnvironments::new(spec, assets)?;
    let mut tasks = Vec::new();
    let mut package_deps = vec![chunk.key()];
    let mut samples = Vec::new();
    for &g in accepted {
        let render = render_key(object, hand, g);
        tasks.push(NewTask {
            key: render.clone(),
            stage: Stage::Render,
            params: render_params(spec, &environments, object, hand, g),
            deps: vec![chunk.key()],
        });
        package_deps.push(render.clone());
        if noisy {
            let noise = noise_key(object, hand, g);
            tasks.push(NewTask {
                key: noise.clone(),
                stage: Stage::Noise,
                params: noise_params(spec, object, hand, g),
                deps: vec![render],
            });
            package_deps.push(noise);
        }
        for v in 0..spec.render.views_per_grasp() {
            let id = SampleId { object: object.into(), hand: hand.into(), grasp_index: g, view_index: v };
            samples.push(json!({"sample_id": id.to_string(), "grasp_index": g, "view_index": v}));
        }
    }
    if !accepted.is_empty() {
        tasks.push(NewTask {
            key: chunk.package_key(),
            stage: Stage::Package,
            params: json!({"samples": samples, "modalities": spec.outputs.modalities}),
            deps: package_deps,
        });
    }
    Ok(tasks)
}

/// What the renderer must produce: only what the requested modalities need.
fn render_outputs(spec: &DatasetSpec) -> Vec<&'static str> {
    let o = &spec.outputs;
    let mut out = Vec::new();
    if o.wants("rgb") {
        out.push("rgb");
    }
    if o.wants("depth") || o.wants("depth_noisy") {
        out.push("depth");
    }
    if o.wants("mask") {
        out.push("mask");
    }
    if o.wants("segmentation") {
        out.push("segmentation");
    }
    out
}

/// A render task's `environments` and the files they need: a user's HDRI is named by its file's
/// SHA-256 (`asset`), and the file is among the task's `assets` (staged for the engine) only when
/// the task path-traces: without `rgb` no HDRI is read. Every render task renders every
/// environment (`views_per_environment` ≥ 1 each), so all of them share one list.
struct RenderEnvironments {
    list: Vec<Value>,
    assets: Vec<Asset>,
}

impl RenderEnvironments {
    fn new(spec: &DatasetSpec, assets: &[Asset]) -> Result<RenderEnvironments, PlanError> {
        let mut list = Vec::new();
        let mut used: Vec<Asset> = Vec::new();
        for e in &spec.render.environments {
            let mut entry = json!({"name": e.name, "rotation_deg": e.rotation_deg, "strength": e.strength});
            if let Some(file) = &e.file {
                let Some(a) = assets.iter().find(|a| a.path == file.path) else {
                    return Err(PlanError::MissingAsset { field: file.field.clone(), path: file.path.clone() });
                };
                entry["asset"] = json!(a.sha256);
                if !used.contains(a) {
                    used.push(a.clone());
                }
            }
            list.push(entry);
        }
        if !spec.outputs.wants("rgb") {
            used.clear();
        }
        Ok(RenderEnvironments { list, assets: used })
    }
}

fn render_params(spec: &DatasetSpec, environments: &RenderEnvironments, object: &str, hand: &str, g: u32) -> Value {
    let r = &spec.render;
    let views: Vec<Value> = (0..r.views_per_grasp())
        .map(|v| {
            json!({
                "view_index": v,
                "seed": seed::render_view(spec.dataset.seed, object, hand, g, v),
                "environment": r.environment_of_view(v).name,
            })
        })
        .collect();
    let mut params = json!({
        "grasp_index": g,
        "render": {
            "width": r.resolution[0],
            "height": r.resolution[1],
            "samples": r.samples,
            "denoise": r.denoise,
            "bounces": r.bounces,
            "fov_deg": r.fov_deg,
            "environment": r.environments[0].name,
            "radius_m": r.radius_m,
            "elevation_deg": r.elevation_deg,
        },
        "environments": environments.list,
        "views": views,
        "outputs": render_outputs(spec),
    });
    if !environments.assets.is_empty() {
        params["assets"] = json!(environments.assets);
    }
    params
}

fn noise_params(spec: &DatasetSpec, object: &str, hand: &str, g: u32) -> Value {
    let views: Vec<Value> = (0..spec.render.views_per_grasp())
        .map(|v| json!({"view_index": v, "seed": seed::noise_view(spec.dataset.seed, object, hand, g, v)}))
        .collect();
    json!({"noise": spec.noise, "views": views})
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(extra: &str) -> DatasetSpec {
        DatasetSpec::parse(&format!("objects = [\"tomato_soup_can\"]\n[dataset]\nname = \"t\"\nseed = 1\n{extra}"))
            .unwrap()
    }

    #[test]
    fn submit_materializes_only_grasp_chunks() {
        let s = spec("[grasp]\ntrials_per_pair = 10\nchunk_size = 4\n");
        let tasks = initial_tasks(&s, &[]).unwrap();
        assert_eq!(tasks.len(), 3);
        assert!(tasks.iter().all(|t| t.stage == Stage::Grasp && t.deps.is_empty()));
        let last = GraspChunk::from_key(&tasks[2].key).unwrap();
        assert_eq!(last.trials(&s), 8..10);
    }

    #[test]
    fn a_two_million_sample_job_starts_small() {
        let s = spec("[grasp]\ntrials_per_pair = 125000\nchunk_size = 64\n[render]\nviews_per_environment = 16\n");
        assert_eq!(s.max_samples(), 2_000_000);
        assert!(initial_tasks(&s, &[]).unwrap().len() < 2_000);
    }

    #[test]
    fn accepted_grasps_fan_out_into_render_noise_and_one_package() {
        let s = spec("[render]\nviews_per_environment = 3\n");
        let c = GraspChunk { object: "tomato_soup_can".into(), hand: "trx3".into(), chunk: 0 };
        let tasks = after_grasp(&s, &c, &[1, 4], &[]).unwrap();
        let count = |st| tasks.iter().filter(|t| t.stage == st).count();
        assert_eq!((count(Stage::Render), count(Stage::Noise), count(Stage::Package)), (2, 2, 1));
        let package = tasks.iter().find(|t| t.stage == Stage::Package).unwrap();
        assert_eq!(package.deps.len(), 5);
        assert_eq!(package.params["samples"].as_array().unwrap().len(), 6);
    }

    #[test]
    fn no_noise_tasks_when_noisy_depth_is_not_requested() {
        let s = spec("[outputs]\nmodalities = [\"rgb\", \"pose\"]\n");
        let c = GraspChunk { object: "tomato_soup_can".into(), hand: "trx3".into(), chunk: 0 };
        let tasks = after_grasp(&s, &c, &[0], &[]).unwrap();
        assert!(tasks.iter().all(|t| t.stage != Stage::Noise));
        let render = &tasks[0];
        assert_eq!(render.params["outputs"], json!(["rgb"]));
    }

    #[test]
    fn views_run_over_environments_times_views_per_environment() {
        let s = spec(
            "[render]\nviews_per_environment = 3\nenvironments = [\"studio\", \
             { name = \"forest\", rotation_deg = 30, strength = 1.2 }]\n",
        );
        let c = GraspChunk { object: "tomato_soup_can".into(), hand: "trx3".into(), chunk: 0 };
        let tasks = after_grasp(&s, &c, &[2], &[]).unwrap();
        let render = &tasks[0].params;
        let views = render["views"].as_array().unwrap();
        let names: Vec<&str> = views.iter().map(|v| v["environment"].as_str().unwrap()).collect();
        assert_eq!(names, ["studio", "studio", "studio", "forest", "forest", "forest"]);
        for (v, view) in views.iter().enumerate() {
            assert_eq!(view["view_index"], v);
            assert_eq!(view["seed"], seed::render_view(1, "tomato_soup_can", "trx3", 2, v as u32));
        }
        assert_eq!(render["environments"][1], json!({"name": "forest", "rotation_deg": 30.0, "strength": 1.2}));
        assert_eq!(render["render"]["bounces"]["transmission"], 12);
        let package = tasks.iter().find(|t| t.stage == Stage::Package).unwrap();
        let ids: Vec<&str> =
            package.params["samples"].as_array().unwrap().iter().map(|s| s["sample_id"].as_str().unwrap()).collect();
        assert_eq!(ids.first(), Some(&"tomato_soup_can.trx3.g000002.v00"));
        assert_eq!(ids.last(), Some(&"tomato_soup_can.trx3.g000002.v05"));
    }

    #[test]
    fn the_renderer_is_asked_only_for_what_the_modalities_need() {
        let s = spec("[outputs]\nmodalities = [\"depth_noisy\", \"segmentation\", \"pose\"]\n");
        let c = GraspChunk { object: "tomato_soup_can".into(), hand: "trx3".into(), chunk: 0 };
        assert_eq!(after_grasp(&s, &c, &[0], &[]).unwrap()[0].params["outputs"], json!(["depth", "segmentation"]));
    }

    #[test]
    fn a_chunk_with_no_accepted_grasp_unlocks_nothing() {
        let s = spec("");
        let c = GraspChunk { object: "tomato_soup_can".into(), hand: "trx3".into(), chunk: 0 };
        assert!(after_grasp(&s, &c, &[], &[]).unwrap().is_empty());
    }

    #[test]
    fn grasp_keys_round_trip() {
        let c = GraspChunk { object: "tuna_fish_can".into(), hand: "trx3".into(), chunk: 12 };
        assert_eq!(GraspChunk::from_key(&c.key()), Some(c));
        assert_eq!(GraspChunk::from_key("render/a/b/g000001"), None);
        assert_eq!(GraspChunk::from_key("grasp/a/b/c1/x"), None);
    }

    #[test]
    fn user_hands_and_objects_name_their_files_by_hash() {
        let s = DatasetSpec::parse(
            "hands = [\"grip\"]\nobjects = [\"bowl\"]\n[dataset]\nname = \"t\"\nseed = 1\n\
             [hand.grip]\nmjcf = \"a/grip.xml\"\ntaxels = \"a/grip.csv\"\n\
             [object.bowl]\nmesh = \"a/bowl.obj\"\nunit = \"mm\"\nmass_kg = 0.2\nmaterial = \"ceramic\"\n",
        )
        .unwrap();
        let asset = |p: &str, h: &str| Asset { path: p.into(), sha256: h.repeat(64), size: 10 };
        let assets = [asset("a/grip.xml", "a"), asset("a/grip.csv", "b"), asset("a/bowl.obj", "c")];
        let t = &initial_tasks(&s, &assets).unwrap()[0];
        assert_eq!(t.params["hand"], json!({"name": "grip", "mjcf": "a".repeat(64), "taxels": "b".repeat(64)}));
        assert_eq!(t.params["object"]["shape"], json!({"type": "mesh", "asset": "c".repeat(64), "scale": 0.001}));
        assert_eq!(t.params["object"]["symmetry"], "none");
        assert_eq!(t.params["assets"].as_array().unwrap().len(), 3);
        assert_eq!(
            initial_tasks(&s, &assets[..2]),
            Err(PlanError::MissingAsset { field: "object.bowl.mesh".into(), path: "a/bowl.obj".into() })
        );
        // Built-in hands and objects keep their parameters: no `assets` at all.
        assert!(initial_tasks(&spec(""), &[]).unwrap()[0].params.get("assets").is_none());
    }

    #[test]
    fn a_user_hdri_is_named_by_hash_in_render_params_and_staged_only_for_rgb() {
        let envs = "[render]\nviews_per_environment = 2\nenvironments = [\"studio\", \
                    { name = \"lab\", file = \"a/lab.hdr\", rotation_deg = 45, strength = 2 }]\n";
        let s = spec(envs);
        let lab = Asset { path: "a/lab.hdr".into(), sha256: "d".repeat(64), size: 160 };
        let c = GraspChunk { object: "tomato_soup_can".into(), hand: "trx3".into(), chunk: 0 };
        // The file is submitted with the job like a hand's or object's; the grasp tasks do not name it.
        let grasp = &initial_tasks(&s, std::slice::from_ref(&lab)).unwrap()[0];
        assert!(grasp.params.get("assets").is_none());
        assert_eq!(
            initial_tasks(&s, &[]),
            Err(PlanError::MissingAsset { field: "render.environments[1].file".into(), path: "a/lab.hdr".into() })
        );

        let tasks = after_grasp(&s, &c, &[0, 1], std::slice::from_ref(&lab)).unwrap();
        let renders: Vec<&NewTask> = tasks.iter().filter(|t| t.stage == Stage::Render).collect();
        assert_eq!(renders.len(), 2);
        for render in renders {
            let p = &render.params;
            assert_eq!(p["environments"][0], json!({"name": "studio", "rotation_deg": 0.0, "strength": 1.0}));
            assert_eq!(
                p["environments"][1],
                json!({"name": "lab", "rotation_deg": 45.0, "strength": 2.0, "asset": "d".repeat(64)})
            );
            assert_eq!(p["assets"], json!([{"path": "a/lab.hdr", "sha256": "d".repeat(64), "size": 160}]));
            let names: Vec<&str> =
                p["views"].as_array().unwrap().iter().map(|v| v["environment"].as_str().unwrap()).collect();
            assert_eq!(names, ["studio", "studio", "lab", "lab"]);
        }
        // Noise and package tasks never read it.
        assert!(tasks.iter().filter(|t| t.stage != Stage::Render).all(|t| t.params.get("assets").is_none()));

        // Without rgb nothing is path traced: the HDRI keeps its name and hash, the file stays home.
        let depth_only = spec(&format!("{envs}[outputs]\nmodalities = [\"depth\", \"pose\"]\n"));
        let render = &after_grasp(&depth_only, &c, &[0], std::slice::from_ref(&lab)).unwrap()[0];
        assert_eq!(render.params["environments"][1]["asset"], "d".repeat(64));
        assert!(render.params.get("assets").is_none());
        // Only built-in environments: no assets, exactly as before.
        assert!(after_grasp(&spec(""), &c, &[0], &[]).unwrap()[0].params.get("assets").is_none());
    }

    #[test]
    fn task_params_carry_seeds_from_the_sample_identity() {
        let s = spec("");
        let t = &initial_tasks(&s, &[]).unwrap()[0];
        let seed0 = t.params["trials"][0]["seed"].as_u64().unwrap();
        assert_eq!(seed0, seed::grasp_trial(1, "tomato_soup_can", "trx3", 0));
    }
}
