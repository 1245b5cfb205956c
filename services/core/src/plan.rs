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

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::asset::Asset;
pub use crate::budget::PairBudget;
use crate::catalog;
use crate::contract::depth::DepthFormat;
use crate::contract::object::{ObjectEntry, Shape, Texture};
use crate::contract::package::{self, Modality, SampleRef};
use crate::contract::render::{self, RenderOutput};
use crate::contract::{grasp, noise};
use crate::sample::SampleId;
use crate::seed;
use crate::spec::DatasetSpec;
use crate::stage::Stage;

/// A task to insert, with the keys of the tasks it depends on (all within the same job). Its
/// parameters are the stage contract's type, serialized.
#[derive(Clone, Debug, PartialEq)]
pub struct NewTask {
    pub key: String,
    pub stage: Stage,
    pub params: Value,
    pub deps: Vec<String>,
}

impl NewTask {
    fn new<P: Serialize>(key: String, stage: Stage, params: &P, deps: Vec<String>) -> Result<NewTask, PlanError> {
        let params =
            serde_json::to_value(params).map_err(|e| PlanError::Params { key: key.clone(), reason: e.to_string() })?;
        Ok(NewTask { key, stage, params, deps })
    }
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
}

/// The keys of the tasks one accepted grasp of (object, hand) gets, with their stages (a stage
/// the job does not ask for has no such task): what a sample's lineage and a forecast look up.
pub fn grasp_keys(object: &str, hand: &str, grasp_index: u32) -> [(Stage, String); 2] {
    [
        (Stage::Render, render::task_key(object, hand, grasp_index)),
        (Stage::Noise, noise::task_key(object, hand, grasp_index)),
    ]
}

/// Why a spec cannot be planned.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum PlanError {
    #[error("{field}: the file {path:?} is not among the submitted assets")]
    MissingAsset { field: String, path: String },
    #[error("{object}: not in the built-in catalog and not defined by the spec")]
    UnknownObject { object: String },
    #[error("task {key}: parameters do not serialize: {reason}")]
    Params { key: String, reason: String },
}

/// Everything a job's later tasks need, fixed at submit from the spec and the job's stored files
/// and kept with the job, so that a completion plans its children without re-reading the spec.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JobPlan {
    pub seed: u64,
    pub trials_per_pair: u32,
    pub chunk_size: u32,
    /// Stop each pair at this many accepted grasps (`PairBudget`); absent in plans stored before
    /// it existed, which ran every trial.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub accepted_per_pair: Option<u32>,
    /// View `v` renders under `environments[v / views_per_environment]`.
    pub views_per_environment: u32,
    pub render: render::Settings,
    pub environments: Vec<render::Environment>,
    /// The HDRI files render tasks stage: a user's HDRIs, only when RGB is path traced.
    pub render_assets: Vec<Asset>,
    /// Per user object, the files its render tasks stage to texture it: the mesh and its
    /// sidecars, only when the object lists sidecars and RGB is path traced (absent in plans
    /// stored before textured meshes).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub object_assets: BTreeMap<String, Vec<Asset>>,
    /// Only what the requested modalities need.
    pub render_outputs: Vec<RenderOutput>,
    /// How depth images are stored (`.npy` in plans stored before 16-bit PNG depth, which wrote it).
    #[serde(default = "stored_before_png_depth")]
    pub depth_format: DepthFormat,
    /// The noise model, when noisy depth is requested (no noise tasks otherwise).
    pub noise: Option<noise::NoiseModel>,
    pub modalities: Vec<Modality>,
    /// The job's objects, when its views stand distractors: none may be one of them (absent in
    /// plans stored before distractors, and when there are none).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub dataset_objects: Vec<String>,
}

impl JobPlan {
    /// The plan of `spec`, whose user files are `assets` (`DatasetSpec::asset_uses`: every one must
    /// be there).
    pub fn new(spec: &DatasetSpec, assets: &[Asset]) -> Result<JobPlan, PlanError> {
        let r = &spec.render;
        let mut environments = Vec::new();
        let mut render_assets: Vec<Asset> = Vec::new();
        for e in &r.environments {
            let mut environment = render::Environment {
                name: e.name.clone(),
                rotation_deg: e.rotation_deg,
                strength: e.strength,
                asset: None,
            };
            if let Some(file) = &e.file {
                let a = find_asset(assets, &file.field, &file.path)?;
                environment.asset = Some(a.sha256.clone());
                if !render_assets.contains(a) {
                    render_assets.push(a.clone());
                }
            }
            environments.push(environment);
        }
        let wants = |m| spec.outputs.wants(m);
        let mut object_assets = BTreeMap::new();
        for name in &spec.objects {
            let Some(o) = spec.object_defs.get(name).filter(|o| !o.files.is_empty()) else { continue };
            let mut files = vec![find_asset(assets, &format!("object.{name}.mesh"), &o.mesh)?.clone()];
            for (i, file) in o.files.iter().enumerate() {
                files.push(find_asset(assets, &format!("object.{name}.files[{i}]"), file)?.clone());
            }
            object_assets.insert(name.clone(), files);
        }
        // Without RGB nothing is path traced, so no HDRI or texture file is read: none is staged.
        if !wants(Modality::Rgb) {
            render_assets.clear();
            object_assets.clear();
        }
        let mut render_outputs: Vec<RenderOutput> =
            spec.outputs.modalities.iter().flat_map(|m| m.render_outputs().iter().copied()).collect();
        // The noise model reads each pixel's material from the segmentation: rendered for the noise
        // stage even when the segmentation modality is not requested (and then not packaged).
        if wants(Modality::DepthNoisy) && spec.noise.model.materials {
            render_outputs.push(RenderOutput::Segmentation);
        }
        render_outputs.sort();
        render_outputs.dedup();
        Ok(JobPlan {
            seed: spec.dataset.seed,
            trials_per_pair: spec.grasp.trials_per_pair,
            chunk_size: spec.grasp.chunk_size,
            accepted_per_pair: spec.grasp.accepted_per_pair,
            views_per_environment: r.views_per_environment,
            render: render::Settings {
                width: r.resolution[0],
                height: r.resolution[1],
                samples: r.samples,
                denoise: r.denoise,
                despeckle: r.despeckle,
                clamp_indirect: r.clamp_indirect,
                bounces: r.bounces.clone(),
                prune_bounces: true,
                fov_deg: r.fov_deg,
                environment: environments
                    .first()
                    .map_or_else(|| render::DEFAULT_ENVIRONMENT.into(), |e| e.name.clone()),
                radius_m: r.radius_m,
                elevation_deg: r.elevation_deg,
                roll_deg: r.roll_deg,
                offcentre: r.offcentre,
                intrinsics_jitter: r.intrinsics_jitter,
                distortion: r.distortion,
                occlusion: r.occlusion,
                palm_side: r.palm_side,
                scene: r.scene.clone(),
                sensor: r.sensor.clone(),
                light: r.light.clone(),
            },
            environments,
            render_assets,
            object_assets,
            render_outputs,
            depth_format: spec.outputs.depth_format,
            noise: wants(Modality::DepthNoisy).then(|| spec.noise.model.clone()),
            modalities: spec.outputs.modalities.clone(),
            dataset_objects: if r.scene.distractors > 0 { spec.objects.clone() } else { Vec::new() },
        })
    }

    pub fn views_per_grasp(&self) -> u32 {
        self.views_per_environment * self.environments.len() as u32
    }

    /// How a pair's trials and accepted grasps split into chunks.
    pub fn budget(&self) -> PairBudget {
        PairBudget { trials: self.trials_per_pair, accepted: self.accepted_per_pair, chunk_size: self.chunk_size }
    }

    /// The trial indices a chunk may run.
    pub fn trials(&self, chunk: &GraspChunk) -> std::ops::Range<u32> {
        self.budget().trials(chunk.chunk)
    }

    /// The chunk a grasp index belongs to.
    pub fn chunk_of(&self, object: &str, hand: &str, grasp_index: u32) -> GraspChunk {
        GraspChunk { object: object.to_string(), hand: hand.to_string(), chunk: self.budget().chunk_of(grasp_index) }
    }

    fn environment_of_view(&self, v: u32) -> &str {
        let i = (v / self.views_per_environment.max(1)) as usize;
        self.environments.get(i).map_or(render::DEFAULT_ENVIRONMENT, |e| e.name.as_str())
    }
}

fn find_asset<'a>(assets: &'a [Asset], field: &str, path: &str) -> Result<&'a Asset, PlanError> {
    assets
        .iter()
        .find(|a| a.path == path)
        .ok_or_else(|| PlanError::MissingAsset { field: field.to_string(), path: path.to_string() })
}

/// The tasks that exist at submit: every grasp-sim chunk. `assets` are the stored files the
/// spec names (`DatasetSpec::asset_uses`); every one must be there.
pub fn initial_tasks(spec: &DatasetSpec, assets: &[Asset]) -> Result<Vec<NewTask>, PlanError> {
    if let Some(u) = spec.asset_uses().into_iter().find(|u| !assets.iter().any(|a| a.path == u.path)) {
        return Err(PlanError::MissingAsset { field: u.field, path: u.path });
    }
    let plan = JobPlan::new(spec, assets)?;
    let chunks = plan.budget().chunks();
    let mut tasks = Vec::with_capacity(spec.objects.len() * spec.hands.len() * chunks as usize);
    for object in &spec.objects {
        for hand in &spec.hands {
            for chunk in 0..chunks {
                let c = GraspChunk { object: object.clone(), hand: hand.clone(), chunk };
                tasks.push(grasp_task(spec, &plan, &c, assets)?);
            }
        }
    }
    Ok(tasks)
}

/// The grasp task of one chunk (`initial_tasks` makes every chunk's).
pub fn grasp_task(spec: &DatasetSpec, plan: &JobPlan, c: &GraspChunk, assets: &[Asset]) -> Result<NewTask, PlanError> {
    NewTask::new(c.key(), Stage::Grasp, &grasp_params(spec, plan, c, assets)?, vec![])
}

/// A grasp task's parameters. A built-in hand is its name, a user's hand adds its `mjcf` and
/// `taxels` files; a built-in object is its catalog entry, a user's object an entry of the same
/// schema whose shape is a `mesh` asset. The files they name, and a user hand's mesh `files`, are
/// the task's `assets`.
fn grasp_params(
    spec: &DatasetSpec,
    plan: &JobPlan,
    c: &GraspChunk,
    assets: &[Asset],
) -> Result<grasp::Params, PlanError> {
    let mut used: Vec<Asset> = Vec::new();
    let mut sha = |field: String, path: &str| -> Result<String, PlanError> {
        let a = find_asset(assets, &field, path)?;
        if !used.contains(a) {
            used.push(a.clone());
        }
        Ok(a.sha256.clone())
    };
    let hand = match spec.hand_defs.get(&c.hand) {
        Some(h) => {
            let hand = grasp::HandRef {
                name: c.hand.clone(),
                mjcf: Some(sha(format!("hand.{}.mjcf", c.hand), &h.mjcf)?),
                taxels: Some(sha(format!("hand.{}.taxels", c.hand), &h.taxels)?),
            };
            // The MJCF's mesh files: the engine finds them among the task's assets by spec path.
            for (i, file) in h.files.iter().enumerate() {
                sha(format!("hand.{}.files[{i}]", c.hand), file)?;
            }
            hand
        }
        None => grasp::HandRef { name: c.hand.clone(), mjcf: None, taxels: None },
    };
    let object = match spec.object_defs.get(&c.object) {
        Some(o) => {
            let (symmetries_continuous, symmetries_discrete) = o.symmetry_sets();
            ObjectEntry {
                name: c.object.clone(),
                ycb_id: String::new(),
                mass_kg: o.mass_kg,
                material: o.material,
                texture: Texture::Plain,
                colours: None,
                symmetries_continuous,
                symmetries_discrete,
                description: format!("user mesh {}", o.mesh),
                shape: Shape::Mesh {
                    path: None,
                    asset: Some(sha(format!("object.{}.mesh", c.object), &o.mesh)?),
                    scale: o.scale(),
                },
                obj_id: o.obj_id,
            }
        }
        None => {
            catalog::object(&c.object).cloned().ok_or_else(|| PlanError::UnknownObject { object: c.object.clone() })?
        }
    };
    let g = &spec.grasp;
    let shake = g.shake_accel_mps2 > 0.0;
    Ok(grasp::Params {
        object,
        hand,
        accept: plan.budget().quota(c.chunk),
        trials: plan
            .trials(c)
            .map(|i| grasp::Trial { grasp_index: i, seed: seed::grasp_trial(plan.seed, &c.object, &c.hand, i) })
            .collect(),
        physics: grasp::Physics {
            timestep: g.timestep_s,
            lift_height: g.lift_height_m,
            hold_s: g.hold_s,
            max_drop_m: g.max_drop_m,
            standoff_ratio: g.standoff_ratio,
            shake: grasp::Shake {
                enabled: shake,
                accel_mps2: if shake { g.shake_accel_mps2 } else { grasp::SHAKE_ACCEL_MPS2.default },
                directions: g.shake_directions,
                duration_s: g.shake_duration_s,
            },
            grasp_type: g.r#type,
            ..grasp::Physics::default()
        },
        touch: grasp::Touch {
            contact_margin_m: spec.touch.contact_margin_m,
            contact_window_s: spec.touch.contact_window_s,
            activation_force_n: spec.touch.activation_force_n,
            half_force_n: spec.touch.half_force_n,
            response_exponent: spec.touch.response_exponent,
            gain_sigma: spec.touch.gain_sigma,
            aging: spec.touch.aging,
            position_sigma_m: spec.touch.position_sigma_m,
            gain_seed: seed::taxel_gains(plan.seed, &c.hand),
            min_active_taxels: spec.touch.min_active_taxels,
        },
        assets: used,
    })
}

/// The tasks a completed grasp chunk unlocks, given its accepted grasp indices (each one of the
/// chunk's trials: the caller checks): a render task per grasp, a noise task per grasp when noisy
/// depth is requested, and one package task for the chunk that waits for all of them.
pub fn after_grasp(plan: &JobPlan, chunk: &GraspChunk, accepted: &[u32]) -> Result<Vec<NewTask>, PlanError> {
    let (object, hand) = (chunk.object.as_str(), chunk.hand.as_str());
    let mut tasks = Vec::new();
    let mut package_deps = vec![chunk.key()];
    let mut samples = Vec::new();
    for &g in accepted {
        let render = render::task_key(object, hand, g);
        tasks.push(NewTask::new(
            render.clone(),
            Stage::Render,
            &render_params(plan, object, hand, g),
            vec![chunk.key()],
        )?);
        package_deps.push(render.clone());
        if let Some(model) = &plan.noise {
            let noise = noise::task_key(object, hand, g);
            let params = noise_params(plan, model, object, hand, g);
            tasks.push(NewTask::new(noise.clone(), Stage::Noise, &params, vec![render])?);
            package_deps.push(noise);
        }
        for v in 0..plan.views_per_grasp() {
            let id = SampleId { object: object.into(), hand: hand.into(), grasp_index: g, view_index: v };
            samples.push(SampleRef { sample_id: id.to_string(), grasp_index: g, view_index: v });
        }
    }
    if !accepted.is_empty() {
        let params = package::Params { samples, modalities: plan.modalities.clone(), depth_format: plan.depth_format };
        tasks.push(NewTask::new(chunk.package_key(), Stage::Package, &params, package_deps)?);
    }
    Ok(tasks)
}

fn render_params(plan: &JobPlan, object: &str, hand: &str, g: u32) -> render::Params {
    let views = (0..plan.views_per_grasp())
        .map(|v| render::View {
            view_index: v,
            seed: seed::render_view(plan.seed, object, hand, g, v),
            environment: Some(plan.environment_of_view(v).to_string()),
            camera: None,
        })
        .collect();
    render::Params {
        grasp_index: g,
        render: plan.render.clone(),
        environments: plan.environments.clone(),
        assets: plan
            .render_assets
            .iter()
            .chain(plan.object_assets.get(object).into_iter().flatten())
            .cloned()
            .collect(),
        views,
        outputs: plan.render_outputs.clone(),
        depth_format: plan.depth_format,
        dataset_objects: plan.dataset_objects.clone(),
    }
}

fn noise_params(plan: &JobPlan, model: &noise::NoiseModel, object: &str, hand: &str, g: u32) -> noise::Params {
    let views = (0..plan.views_per_grasp())
        .map(|v| noise::View { view_index: v, seed: seed::noise_view(plan.seed, object, hand, g, v) })
        .collect();
    noise::Params { noise: model.clone(), views, depth_format: plan.depth_format }
}

fn stored_before_png_depth() -> DepthFormat {
    DepthFormat::Npy
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    /// The plan of a spec with no user files.
    fn plan(s: &DatasetSpec) -> JobPlan {
        JobPlan::new(s, &[]).unwrap()
    }

    fn spec(extra: &str) -> DatasetSpec {
        DatasetSpec::parse(&format!("objects = [\"tomato_soup_can\"]\n[dataset]\nname = \"t\"\nseed = 1\n{extra}"))
            .unwrap()
    }

    #[test]
    fn grasp_keys_name_every_per_grasp_task_the_planner_makes() {
        let s = spec("[grasp]\ntrials_per_pair = 4\nchunk_size = 4\n");
        let p = plan(&s);
        let chunk = GraspChunk { object: "tomato_soup_can".into(), hand: "trx3".into(), chunk: 0 };
        let tasks = after_grasp(&p, &chunk, &[1, 3]).unwrap();
        let per_grasp: Vec<(Stage, String)> =
            tasks.iter().filter(|t| t.key != chunk.package_key()).map(|t| (t.stage, t.key.clone())).collect();
        let named: Vec<(Stage, String)> =
            [1, 3].iter().flat_map(|&g| grasp_keys("tomato_soup_can", "trx3", g)).collect();
        assert!(!per_grasp.is_empty() && per_grasp.iter().all(|t| named.contains(t)), "{per_grasp:?} {named:?}");
        assert_eq!(per_grasp.len(), named.len(), "the spec asks for every per-grasp stage");
    }

    #[test]
    fn submit_materializes_only_grasp_chunks() {
        let s = spec("[grasp]\ntrials_per_pair = 10\nchunk_size = 4\n");
        let tasks = initial_tasks(&s, &[]).unwrap();
        assert_eq!(tasks.len(), 3);
        assert!(tasks.iter().all(|t| t.stage == Stage::Grasp && t.deps.is_empty()));
        let last = GraspChunk::from_key(&tasks[2].key).unwrap();
        assert_eq!(plan(&s).trials(&last), 8..10);
        assert_eq!(tasks[2].params["trials"].as_array().unwrap().len(), 2);
    }

    #[test]
    fn a_quota_reaches_the_grasp_tasks() {
        let s = spec("[grasp]\ntrials_per_pair = 12\naccepted_per_pair = 3\nchunk_size = 2\n");
        let tasks = initial_tasks(&s, &[]).unwrap();
        assert_eq!(tasks.len(), 2);
        assert_eq!(tasks[0].params["accept"], 2);
        assert_eq!(tasks[0].params["trials"].as_array().unwrap().len(), 8);
        assert_eq!(tasks[1].params["accept"], 1);
        assert_eq!(tasks[1].params["trials"][0]["grasp_index"], 8);
        assert_eq!(s.max_samples(), 3 * u64::from(s.render.views_per_grasp()));
        let without = spec("[grasp]\ntrials_per_pair = 12\nchunk_size = 2\n");
        assert!(initial_tasks(&without, &[]).unwrap().iter().all(|t| t.params.get("accept").is_none()));
    }

    #[test]
    fn render_tasks_name_the_jobs_objects_only_when_distractors_stand() {
        let with = DatasetSpec::parse(
            "objects = [\"mug\", \"tomato_soup_can\"]\n[dataset]\nname = \"t\"\nseed = 1\n\
             [render]\nscene = { distractors = 2 }\n",
        )
        .unwrap();
        let params = serde_json::to_value(render_params(&plan(&with), "mug", "trx3", 0)).unwrap();
        assert_eq!(params["dataset_objects"], json!(["mug", "tomato_soup_can"]));
        assert_eq!(params["render"]["scene"]["distractors"], 2);
        let params = serde_json::to_value(render_params(&plan(&spec("")), "tomato_soup_can", "trx3", 0)).unwrap();
        assert!(params.get("dataset_objects").is_none(), "{params}");
        assert!(params["render"]["scene"].get("distractors").is_none(), "a task without them is unchanged");
    }

    #[test]
    fn a_quota_that_would_overfill_a_task_is_refused() {
        let e = DatasetSpec::parse(
            "objects = [\"mug\"]\n[dataset]\nname = \"t\"\nseed = 1\n[grasp]\ntrials_per_pair = 100000\naccepted_per_pair = 10\nchunk_size = 8\n",
        )
        .unwrap_err();
        assert_eq!(e.0.len(), 1, "{e}");
        assert_eq!(e.0[0].path, "grasp.chunk_size");
        assert!(e.0[0].rule.contains("80000 trials"), "{}", e.0[0].rule);
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
        let tasks = after_grasp(&plan(&s), &c, &[1, 4]).unwrap();
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
        let tasks = after_grasp(&plan(&s), &c, &[0]).unwrap();
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
        let tasks = after_grasp(&plan(&s), &c, &[2]).unwrap();
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
    fn the_spec_lens_distortion_reaches_the_render_task_and_a_pinhole_adds_nothing() {
        let c = GraspChunk { object: "tomato_soup_can".into(), hand: "trx3".into(), chunk: 0 };
        let s = spec("[render]\ndistortion = [-0.1, 0.02, 0.001, -0.002, 0.0]\n");
        let render = &after_grasp(&plan(&s), &c, &[0]).unwrap()[0].params["render"];
        assert_eq!(render["distortion"], json!([-0.1, 0.02, 0.001, -0.002, 0.0]));
        let render = &after_grasp(&plan(&spec("")), &c, &[0]).unwrap()[0].params["render"];
        assert!(render.get("distortion").is_none(), "{render}");
    }

    #[test]
    fn the_renderer_is_asked_only_for_what_the_modalities_need() {
        let s = spec("[outputs]\nmodalities = [\"depth_noisy\", \"segmentation\", \"pose\"]\n");
        let c = GraspChunk { object: "tomato_soup_can".into(), hand: "trx3".into(), chunk: 0 };
        assert_eq!(after_grasp(&plan(&s), &c, &[0]).unwrap()[0].params["outputs"], json!(["depth", "segmentation"]));
    }

    #[test]
    fn noisy_depth_renders_the_segmentation_its_materials_need_but_packages_only_what_was_asked() {
        let c = GraspChunk { object: "tomato_soup_can".into(), hand: "trx3".into(), chunk: 0 };
        let s = spec("[outputs]\nmodalities = [\"depth_noisy\", \"pose\"]\n");
        let tasks = after_grasp(&plan(&s), &c, &[0]).unwrap();
        let render = tasks.iter().find(|t| t.stage == Stage::Render).unwrap();
        assert_eq!(render.params["outputs"], json!(["depth", "segmentation"]));
        let noise = tasks.iter().find(|t| t.stage == Stage::Noise).unwrap();
        assert_eq!(noise.params["noise"]["mode"], "nfov_unbinned");
        let package = tasks.iter().find(|t| t.stage == Stage::Package).unwrap();
        assert_eq!(package.params["modalities"], json!(["depth_noisy", "pose"]), "no segmentation.png in samples");
        // Without the materials piece the noise model reads no segmentation: none is rendered.
        let s = spec("[noise]\nmaterials = false\n[outputs]\nmodalities = [\"depth_noisy\", \"pose\"]\n");
        let tasks = after_grasp(&plan(&s), &c, &[0]).unwrap();
        assert_eq!(tasks.iter().find(|t| t.stage == Stage::Render).unwrap().params["outputs"], json!(["depth"]));
        // Without noisy depth: no segmentation and no noise task.
        let s = spec("[outputs]\nmodalities = [\"depth\", \"pose\"]\n");
        let tasks = after_grasp(&plan(&s), &c, &[0]).unwrap();
        assert_eq!(tasks.iter().find(|t| t.stage == Stage::Render).unwrap().params["outputs"], json!(["depth"]));
        assert!(tasks.iter().all(|t| t.stage != Stage::Noise));
    }

    #[test]
    fn a_chunk_with_no_accepted_grasp_unlocks_nothing() {
        let s = spec("");
        let c = GraspChunk { object: "tomato_soup_can".into(), hand: "trx3".into(), chunk: 0 };
        assert!(after_grasp(&plan(&s), &c, &[]).unwrap().is_empty());
    }

    #[test]
    fn grasp_keys_round_trip() {
        let c = GraspChunk { object: "tuna_fish_can".into(), hand: "trx3".into(), chunk: 12 };
        assert_eq!(GraspChunk::from_key(&c.key()), Some(c));
        assert_eq!(GraspChunk::from_key("render/a/b/g000001"), None);
        assert_eq!(GraspChunk::from_key("grasp/a/b/c1/x"), None);
    }

    #[test]
    fn a_textured_objects_mesh_and_sidecars_reach_its_render_tasks_only_with_rgb() {
        let text = |extra: &str| {
            format!(
                "objects = [\"box\", \"tomato_soup_can\"]\n[dataset]\nname = \"t\"\nseed = 1\n{extra}\
                 [object.box]\nmesh = \"a/box.obj\"\nfiles = [\"a/box.mtl\", \"a/box.png\"]\nunit = \"mm\"\n\
                 mass_kg = 0.2\nmaterial = \"cardboard\"\n"
            )
        };
        let s = DatasetSpec::parse(&text("")).unwrap();
        assert_eq!(
            s.asset_uses().iter().map(|u| u.field.as_str()).collect::<Vec<_>>(),
            ["object.box.mesh", "object.box.files[0]", "object.box.files[1]"]
        );
        let asset = |p: &str, h: &str| Asset { path: p.into(), sha256: h.repeat(64), size: 10 };
        let assets = [asset("a/box.obj", "a"), asset("a/box.mtl", "b"), asset("a/box.png", "c")];
        // The grasp task reads the geometry alone.
        let grasp = &initial_tasks(&s, &assets).unwrap()[0];
        assert_eq!(grasp.params["assets"], json!([{"path": "a/box.obj", "sha256": "a".repeat(64), "size": 10}]));
        let job = JobPlan::new(&s, &assets).unwrap();
        let box_chunk = GraspChunk { object: "box".into(), hand: "trx3".into(), chunk: 0 };
        let render = &after_grasp(&job, &box_chunk, &[0]).unwrap()[0];
        let staged: Vec<&str> =
            render.params["assets"].as_array().unwrap().iter().map(|a| a["path"].as_str().unwrap()).collect();
        assert_eq!(staged, ["a/box.obj", "a/box.mtl", "a/box.png"]);
        // Another object's render tasks stage none of them.
        let soup = GraspChunk { object: "tomato_soup_can".into(), hand: "trx3".into(), chunk: 0 };
        assert!(after_grasp(&job, &soup, &[0]).unwrap()[0].params.get("assets").is_none());
        assert_eq!(
            JobPlan::new(&s, &assets[..2]),
            Err(PlanError::MissingAsset { field: "object.box.files[1]".into(), path: "a/box.png".into() })
        );
        // Without rgb no texture is read: nothing is staged.
        let depth = DatasetSpec::parse(&text("[outputs]\nmodalities = [\"depth\", \"pose\"]\n")).unwrap();
        let render = &after_grasp(&JobPlan::new(&depth, &assets).unwrap(), &box_chunk, &[0]).unwrap()[0];
        assert!(render.params.get("assets").is_none());
    }

    #[test]
    fn a_user_hands_mesh_files_reach_its_grasp_tasks() {
        let s = DatasetSpec::parse(
            "hands = [\"grip\"]\nobjects = [\"tomato_soup_can\"]\n[dataset]\nname = \"t\"\nseed = 1\n\
             [hand.grip]\nmjcf = \"a/grip.xml\"\ntaxels = \"a/grip.csv\"\n\
             files = [\"a/meshes/palm.stl\", \"a/meshes/link.obj\"]\n",
        )
        .unwrap();
        let uses: Vec<String> = s.asset_uses().into_iter().map(|u| u.field).collect();
        assert_eq!(uses, ["hand.grip.mjcf", "hand.grip.taxels", "hand.grip.files[0]", "hand.grip.files[1]"]);
        let asset = |p: &str, h: &str| Asset { path: p.into(), sha256: h.repeat(64), size: 10 };
        let assets = [
            asset("a/grip.xml", "a"),
            asset("a/grip.csv", "b"),
            asset("a/meshes/palm.stl", "c"),
            asset("a/meshes/link.obj", "d"),
        ];
        let t = &initial_tasks(&s, &assets).unwrap()[0];
        let staged: Vec<&str> =
            t.params["assets"].as_array().unwrap().iter().map(|a| a["path"].as_str().unwrap()).collect();
        assert_eq!(staged, ["a/grip.xml", "a/grip.csv", "a/meshes/palm.stl", "a/meshes/link.obj"]);
        // The hand's reference is unchanged: the engine finds the meshes by path among the assets.
        assert_eq!(t.params["hand"], json!({"name": "grip", "mjcf": "a".repeat(64), "taxels": "b".repeat(64)}));
        assert_eq!(
            initial_tasks(&s, &assets[..3]),
            Err(PlanError::MissingAsset { field: "hand.grip.files[1]".into(), path: "a/meshes/link.obj".into() })
        );
        let job = JobPlan::new(&s, &assets).unwrap();
        let chunk = GraspChunk { object: s.objects[0].clone(), hand: "grip".into(), chunk: 0 };
        let render = &after_grasp(&job, &chunk, &[0]).unwrap()[0];
        assert!(render.params.get("assets").is_none(), "grasps.json carries the hand's meshes to render");
    }

    #[test]
    fn user_hands_and_objects_name_their_files_by_hash() {
        let s = DatasetSpec::parse(
            "hands = [\"grip\"]\nobjects = [\"vase\"]\n[dataset]\nname = \"t\"\nseed = 1\n\
             [hand.grip]\nmjcf = \"a/grip.xml\"\ntaxels = \"a/grip.csv\"\n\
             [object.vase]\nmesh = \"a/vase.obj\"\nunit = \"mm\"\nmass_kg = 0.2\nmaterial = \"ceramic\"\n",
        )
        .unwrap();
        let asset = |p: &str, h: &str| Asset { path: p.into(), sha256: h.repeat(64), size: 10 };
        let assets = [asset("a/grip.xml", "a"), asset("a/grip.csv", "b"), asset("a/vase.obj", "c")];
        let t = &initial_tasks(&s, &assets).unwrap()[0];
        assert_eq!(t.params["hand"], json!({"name": "grip", "mjcf": "a".repeat(64), "taxels": "b".repeat(64)}));
        assert_eq!(t.params["object"]["shape"], json!({"type": "mesh", "asset": "c".repeat(64), "scale": 0.001}));
        assert_eq!(t.params["object"]["symmetries_continuous"], serde_json::json!([]));
        assert_eq!(t.params["object"]["texture"]["kind"], "plain");
        assert_eq!(t.params["assets"].as_array().unwrap().len(), 3);
        assert_eq!(
            initial_tasks(&s, &assets[..2]),
            Err(PlanError::MissingAsset { field: "object.vase.mesh".into(), path: "a/vase.obj".into() })
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

        let tasks = after_grasp(&JobPlan::new(&s, std::slice::from_ref(&lab)).unwrap(), &c, &[0, 1]).unwrap();
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
        let render =
            &after_grasp(&JobPlan::new(&depth_only, std::slice::from_ref(&lab)).unwrap(), &c, &[0]).unwrap()[0];
        assert_eq!(render.params["environments"][1]["asset"], "d".repeat(64));
        assert!(render.params.get("assets").is_none());
        // Only built-in environments: no assets, exactly as before.
        assert!(after_grasp(&plan(&spec("")), &c, &[0]).unwrap()[0].params.get("assets").is_none());
    }

    #[test]
    fn task_params_carry_seeds_from_the_sample_identity() {
        let s = spec("");
        let t = &initial_tasks(&s, &[]).unwrap()[0];
        let seed0 = t.params["trials"][0]["seed"].as_u64().unwrap();
        assert_eq!(seed0, seed::grasp_trial(1, "tomato_soup_can", "trx3", 0));
    }
}
