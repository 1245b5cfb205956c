//! What a completed task unlocks: the coordinator's side of `vint_core::plan`.
//!
//! Grasp tasks report their accepted grasp indices in `result_json`; the planner turns them into
//! render, noise and package tasks (whose parameters name the job's stored files they need). Package tasks report their samples through their output names
//! (`<sample_id>/<file>`). Every other stage unlocks nothing new: its dependents already exist.

use std::collections::BTreeSet;

use serde::Deserialize;
use vint_core::asset::Asset;
use vint_core::plan::{self, GraspChunk, NewTask};
use vint_core::{DatasetSpec, SampleId, Stage};
use vint_store::{JobRecord, NewArtifact, TaskRecord};

#[derive(Debug, thiserror::Error)]
pub enum PlanError {
    #[error("job {job}: stored spec no longer parses: {errors}")]
    Spec { job: String, errors: vint_core::SpecErrors },
    #[error("task {task}: grasp result is not {{\"accepted\": [indices]}}: {reason}")]
    GraspResult { task: String, reason: String },
    #[error("task {task}: accepted grasp {grasp} is not one of the chunk's trials")]
    ForeignGrasp { task: String, grasp: u32 },
    #[error("task {task}: key is not a grasp chunk key")]
    BadKey { task: String },
    #[error("task {task}: output {name:?} is not <sample_id>/<file> of a sample the task was asked to make")]
    UnknownSampleFile { task: String, name: String },
    #[error("job {job}: {source}")]
    Plan { job: String, source: plan::PlanError },
}

#[derive(Deserialize)]
struct GraspResult {
    accepted: Vec<u32>,
}

/// Children of a completed task and the samples it made.
pub struct Unlocked {
    pub children: Vec<NewTask>,
    pub samples: Vec<String>,
}

/// What `task`'s completion unlocks. `assets` are the job's stored files; only a grasp task's
/// completion needs them (pass none for other stages).
pub fn on_complete(
    job: &JobRecord,
    task: &TaskRecord,
    result_json: &str,
    outputs: &[NewArtifact],
    assets: &[Asset],
) -> Result<Unlocked, PlanError> {
    match task.stage {
        Stage::Grasp => {
            let spec =
                DatasetSpec::parse(&job.spec_toml).map_err(|errors| PlanError::Spec { job: job.id.clone(), errors })?;
            let chunk = GraspChunk::from_key(&task.key).ok_or_else(|| PlanError::BadKey { task: task.id.clone() })?;
            let result: GraspResult = serde_json::from_str(result_json)
                .map_err(|e| PlanError::GraspResult { task: task.id.clone(), reason: e.to_string() })?;
            let trials = chunk.trials(&spec);
            let accepted: BTreeSet<u32> = result.accepted.into_iter().collect();
            if let Some(&grasp) = accepted.iter().find(|g| !trials.contains(g)) {
                return Err(PlanError::ForeignGrasp { task: task.id.clone(), grasp });
            }
            let accepted: Vec<u32> = accepted.into_iter().collect();
            let children = plan::after_grasp(&spec, &chunk, &accepted, assets)
                .map_err(|source| PlanError::Plan { job: job.id.clone(), source })?;
            Ok(Unlocked { children, samples: vec![] })
        }
        Stage::Package => {
            let expected: BTreeSet<String> = serde_json::from_str::<serde_json::Value>(&task.params_json)
                .ok()
                .and_then(|p| p["samples"].as_array().cloned())
                .unwrap_or_default()
                .iter()
                .filter_map(|s| s["sample_id"].as_str().map(str::to_string))
                .collect();
            let mut samples = BTreeSet::new();
            for o in outputs {
                let Some((sample, _file)) = o.name.split_once('/') else {
                    continue;
                };
                if !expected.contains(sample) || sample.parse::<SampleId>().is_err() {
                    return Err(PlanError::UnknownSampleFile { task: task.id.clone(), name: o.name.clone() });
                }
                samples.insert(sample.to_string());
            }
            Ok(Unlocked { children: vec![], samples: samples.into_iter().collect() })
        }
        Stage::Render | Stage::Noise => Ok(Unlocked { children: vec![], samples: vec![] }),
    }
}
