//! What a completed task unlocks: the coordinator's side of `vint_core::plan`.
//!
//! Every task reports its result in the contract's type for its stage (`vint_core::contract`),
//! forwarded by the worker from the engine's reply. A grasp task's result names its accepted
//! trials, which the planner turns into render, noise and package tasks from the job's stored
//! plan (`JobPlan`, fixed at submit); a package task's result names the samples and grasp records
//! it made, which must match its outputs. Render and noise tasks unlock nothing new: their
//! dependents already exist.

use std::collections::BTreeSet;

use serde_json::Value;
use vint_core::contract::grasp::GraspResult;
use vint_core::contract::package::{self, GRASP_RECORD_FILE, META_FILE, PackageResult};
use vint_core::contract::{self, BadResult};
use vint_core::plan::{self, GraspChunk, JobPlan, NewTask};
use vint_core::{DatasetSpec, GraspId, SampleId, Stage};
use vint_store::{JobRecord, NewArtifact, TaskRecord};

#[derive(Debug, thiserror::Error)]
pub enum PlanError {
    #[error("job {job}: its stored plan is unreadable: {reason}")]
    Plan { job: String, reason: String },
    #[error("task {task}: result is not JSON: {reason}")]
    ResultJson { task: String, reason: String },
    #[error("task {task}: {source}")]
    Result { task: String, source: BadResult },
    #[error("task {task}: accepted grasp {grasp} is not one of the chunk's trials")]
    ForeignGrasp { task: String, grasp: u32 },
    #[error("task {task}: key is not a grasp chunk key")]
    BadKey { task: String },
    #[error("task {task}: {what}")]
    PackageMismatch { task: String, what: String },
    #[error("job {job}: {source}")]
    Planning { job: String, source: plan::PlanError },
}

/// Children of a completed task and the samples it made.
pub struct Unlocked {
    pub children: Vec<NewTask>,
    pub samples: Vec<String>,
}

/// The job's plan: kept with the job since it was submitted, or derived from its spec for jobs
/// from before plans were kept (their specs name no user files: `assets` are the job's files).
pub fn job_plan(job: &JobRecord, assets: &[vint_core::asset::Asset]) -> Result<JobPlan, PlanError> {
    let bad = |reason: String| PlanError::Plan { job: job.id.clone(), reason };
    match &job.plan_json {
        Some(text) => serde_json::from_str(text).map_err(|e| bad(e.to_string())),
        None => {
            let spec = DatasetSpec::parse(&job.spec_toml).map_err(|e| bad(e.to_string()))?;
            JobPlan::new(&spec, assets).map_err(|e| bad(e.to_string()))
        }
    }
}

/// What `task`'s completion unlocks, given its result and outputs. `plan` is needed for a grasp
/// task only (pass `None` for the others).
pub fn on_complete(
    job: &JobRecord,
    plan: Option<&JobPlan>,
    task: &TaskRecord,
    result_json: &str,
    outputs: &[NewArtifact],
) -> Result<Unlocked, PlanError> {
    let result: Value = serde_json::from_str(result_json)
        .map_err(|e| PlanError::ResultJson { task: task.id.clone(), reason: e.to_string() })?;
    let typed = |stage| PlanError::Result { task: task.id.clone(), source: stage };
    match task.stage {
        Stage::Grasp => {
            let result: GraspResult = contract::result(Stage::Grasp, &result).map_err(typed)?;
            let plan = plan.ok_or_else(|| PlanError::Plan { job: job.id.clone(), reason: "not given".into() })?;
            let chunk = GraspChunk::from_key(&task.key).ok_or_else(|| PlanError::BadKey { task: task.id.clone() })?;
            let trials = plan.trials(&chunk);
            let accepted: BTreeSet<u32> = result.accepted.into_iter().collect();
            if let Some(&grasp) = accepted.iter().find(|g| !trials.contains(g)) {
                return Err(PlanError::ForeignGrasp { task: task.id.clone(), grasp });
            }
            let accepted: Vec<u32> = accepted.into_iter().collect();
            let children = plan::after_grasp(plan, &chunk, &accepted)
                .map_err(|source| PlanError::Planning { job: job.id.clone(), source })?;
            Ok(Unlocked { children, samples: vec![] })
        }
        Stage::Package => {
            let result: PackageResult = contract::result(Stage::Package, &result).map_err(typed)?;
            let samples = package_samples(task, &result, outputs)?;
            Ok(Unlocked { children: vec![], samples })
        }
        Stage::Render | Stage::Noise => {
            contract::check_result(task.stage, &result).map_err(typed)?;
            Ok(Unlocked { children: vec![], samples: vec![] })
        }
    }
}

/// The samples a package task made, after checking its result against its parameters and its
/// outputs: every sample it was asked for has a `meta.json`, every grasp record is one of those
/// samples' grasps, and every output belongs to one of them.
fn package_samples(
    task: &TaskRecord,
    result: &PackageResult,
    outputs: &[NewArtifact],
) -> Result<Vec<String>, PlanError> {
    let mismatch = |what: String| PlanError::PackageMismatch { task: task.id.clone(), what };
    let params: package::Params = serde_json::from_str(&task.params_json)
        .map_err(|e| mismatch(format!("parameters are not the package contract's: {e}")))?;
    let asked: BTreeSet<&str> = params.samples.iter().map(|s| s.sample_id.as_str()).collect();
    let made: BTreeSet<&str> = result.samples.iter().map(String::as_str).collect();
    if made != asked {
        return Err(mismatch(format!("made samples {made:?}, was asked for {asked:?}")));
    }
    let mut grasps = BTreeSet::new();
    for s in &result.samples {
        let id: SampleId = s.parse().map_err(|e: vint_core::sample::BadSampleId| mismatch(e.to_string()))?;
        grasps.insert(id.grasp().to_string());
    }
    let recorded: BTreeSet<String> = result.grasps.iter().cloned().collect();
    if recorded != grasps {
        return Err(mismatch(format!("grasp records {recorded:?} are not its samples' grasps {grasps:?}")));
    }
    let mut with_meta = BTreeSet::new();
    for o in outputs {
        let Some((owner, file)) = o.name.split_once('/') else {
            return Err(mismatch(format!("output {:?} is not <sample_id>/<file> or <grasp_id>/<file>", o.name)));
        };
        if made.contains(owner) {
            if file == META_FILE {
                with_meta.insert(owner);
            }
        } else if !(recorded.contains(owner) && file == GRASP_RECORD_FILE && owner.parse::<GraspId>().is_ok()) {
            return Err(mismatch(format!("output {:?} belongs to no sample or grasp record it made", o.name)));
        }
    }
    if with_meta != made {
        return Err(mismatch(format!(
            "samples without {META_FILE}: {:?}",
            made.difference(&with_meta).collect::<Vec<_>>()
        )));
    }
    Ok(result.samples.clone())
}
