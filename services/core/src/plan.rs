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

/// The tasks that exist at submit: every grasp-sim chunk.
pub fn initial_tasks(spec: &DatasetSpec) -> Vec<NewTask> {
    let mut tasks = Vec::new();
    for object in &spec.objects {
        for hand in &spec.hands {
            for chunk in 0..spec.chunks_per_pair() {
                let c = GraspChunk { object: object.clone(), hand: hand.clone(), chunk };
                tasks.push(NewTask { key: c.key(), stage: Stage::Grasp, params: grasp_params(spec, &c), deps: vec![] });
            }
        }
    }
    tasks
}

fn grasp_params(spec: &DatasetSpec, c: &GraspChunk) -> Value {
    let trials: Vec<Value> = c
        .trials(spec)
        .map(|g| json!({"grasp_index": g, "seed": seed::grasp_trial(spec.dataset.seed, &c.object, &c.hand, g)}))
        .collect();
    json!({
        "object": catalog::object(&c.object),
        "hand": {"name": c.hand},
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
    })
}

/// The tasks a completed grasp chunk unlocks, given its accepted grasp indices.
pub fn after_grasp(spec: &DatasetSpec, chunk: &GraspChunk, accepted: &[u32]) -> Vec<NewTask> {
    let (object, hand) = (chunk.object.as_str(), chunk.hand.as_str());
    let noisy = spec.outputs.wants("depth_noisy");
    let mut tasks = Vec::new();
    let mut package_deps = vec![chunk.key()];
    let mut samples = Vec::new();
    for &g in accepted {
        let render = render_key(object, hand, g);
        tasks.push(NewTask {
            key: render.clone(),
            stage: Stage::Render,
            params: render_params(spec, object, hand, g),
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
        for v in 0..spec.render.views_per_grasp {
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
    tasks
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
    out
}

fn render_params(spec: &DatasetSpec, object: &str, hand: &str, g: u32) -> Value {
    let r = &spec.render;
    let views: Vec<Value> = (0..r.views_per_grasp)
        .map(|v| {
            json!({
                "view_index": v,
                "seed": seed::render_view(spec.dataset.seed, object, hand, g, v),
                "environment": r.environments[v as usize % r.environments.len()],
            })
        })
        .collect();
    json!({
        "grasp_index": g,
        "render": {
            "width": r.resolution[0],
            "height": r.resolution[1],
            "samples": r.samples,
            "fov_deg": r.fov_deg,
            "environment": r.environments[0],
            "radius_m": r.radius_m,
            "elevation_deg": r.elevation_deg,
        },
        "views": views,
        "outputs": render_outputs(spec),
    })
}

fn noise_params(spec: &DatasetSpec, object: &str, hand: &str, g: u32) -> Value {
    let views: Vec<Value> = (0..spec.render.views_per_grasp)
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
        let tasks = initial_tasks(&s);
        assert_eq!(tasks.len(), 3);
        assert!(tasks.iter().all(|t| t.stage == Stage::Grasp && t.deps.is_empty()));
        let last = GraspChunk::from_key(&tasks[2].key).unwrap();
        assert_eq!(last.trials(&s), 8..10);
    }

    #[test]
    fn a_two_million_sample_job_starts_small() {
        let s = spec("[grasp]\ntrials_per_pair = 125000\nchunk_size = 64\n[render]\nviews_per_grasp = 16\n");
        assert_eq!(s.max_samples(), 2_000_000);
        assert!(initial_tasks(&s).len() < 2_000);
    }

    #[test]
    fn accepted_grasps_fan_out_into_render_noise_and_one_package() {
        let s = spec("[render]\nviews_per_grasp = 3\n");
        let c = GraspChunk { object: "tomato_soup_can".into(), hand: "trx3".into(), chunk: 0 };
        let tasks = after_grasp(&s, &c, &[1, 4]);
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
        let tasks = after_grasp(&s, &c, &[0]);
        assert!(tasks.iter().all(|t| t.stage != Stage::Noise));
        let render = &tasks[0];
        assert_eq!(render.params["outputs"], json!(["rgb"]));
    }

    #[test]
    fn a_chunk_with_no_accepted_grasp_unlocks_nothing() {
        let s = spec("");
        let c = GraspChunk { object: "tomato_soup_can".into(), hand: "trx3".into(), chunk: 0 };
        assert!(after_grasp(&s, &c, &[]).is_empty());
    }

    #[test]
    fn grasp_keys_round_trip() {
        let c = GraspChunk { object: "tuna_fish_can".into(), hand: "trx3".into(), chunk: 12 };
        assert_eq!(GraspChunk::from_key(&c.key()), Some(c));
        assert_eq!(GraspChunk::from_key("render/a/b/g000001"), None);
        assert_eq!(GraspChunk::from_key("grasp/a/b/c1/x"), None);
    }

    #[test]
    fn task_params_carry_seeds_from_the_sample_identity() {
        let s = spec("");
        let t = &initial_tasks(&s)[0];
        let seed0 = t.params["trials"][0]["seed"].as_u64().unwrap();
        assert_eq!(seed0, seed::grasp_trial(1, "tomato_soup_can", "trx3", 0));
    }
}
