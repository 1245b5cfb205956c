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
use vint_core::asset::Asset;
use vint_core::contract::grasp::GraspResult;
use vint_core::contract::package::{self, GRASP_RECORD_FILE, META_FILE, PackageResult};
use vint_core::contract::{self, BadResult};
use vint_core::plan::{self, GraspChunk, JobPlan, NewTask};
use vint_core::{DatasetSpec, GraspId, SampleId, Stage};
use vint_store::{JobRecord, NewArtifact, Store, TaskRecord};

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
    #[error("task {task}: {what}")]
    GraspMismatch { task: String, what: String },
    #[error("job {job}: {source}")]
    Planning { job: String, source: plan::PlanError },
}

/// What the planner reads of a completed task: whoever holds it (a task row, a leased task being
/// reused, a planned task being forecast) lends these fields, nothing else.
#[derive(Clone, Copy, Debug)]
pub struct Done<'a> {
    pub id: &'a str,
    pub job_id: &'a str,
    pub key: &'a str,
    pub stage: Stage,
    pub params_json: &'a str,
}

impl<'a> From<&'a TaskRecord> for Done<'a> {
    fn from(t: &'a TaskRecord) -> Done<'a> {
        Done { id: &t.id, job_id: &t.job_id, key: &t.key, stage: t.stage, params_json: &t.params_json }
    }
}

/// Children of a completed task and the samples it made.
pub struct Unlocked {
    pub children: Vec<NewTask>,
    pub samples: Vec<String>,
}

/// The job's plan: kept with the job since it was submitted, or, for a job from before plans were
/// kept, derived from its spec and stored files.
pub async fn job_plan(store: &Store, job: &JobRecord) -> Result<JobPlan, tonic::Status> {
    let bad = |reason: String| tonic::Status::internal(PlanError::Plan { job: job.id.clone(), reason }.to_string());
    if let Some(text) = &job.plan_json {
        return serde_json::from_str(text).map_err(|e| bad(e.to_string()));
    }
    let assets: Vec<Asset> = store
        .job_assets(&job.id)
        .await
        .map_err(crate::convert::status)?
        .into_iter()
        .map(|a| Asset { path: a.path, sha256: a.sha256, size: a.size })
        .collect();
    let spec = DatasetSpec::parse(&job.spec_toml).map_err(|e| bad(e.to_string()))?;
    JobPlan::new(&spec, &assets).map_err(|e| bad(e.to_string()))
}

/// What `task`'s completion unlocks, given its result and outputs. `plan` is needed for a grasp
/// task only (pass `None` for the others).
pub fn on_complete(
    plan: Option<&JobPlan>,
    task: Done<'_>,
    result_json: &str,
    outputs: &[NewArtifact],
) -> Result<Unlocked, PlanError> {
    let result: Value = serde_json::from_str(result_json)
        .map_err(|e| PlanError::ResultJson { task: task.id.to_string(), reason: e.to_string() })?;
    let typed = |stage| PlanError::Result { task: task.id.to_string(), source: stage };
    match task.stage {
        Stage::Grasp => {
            let result: GraspResult = contract::result(Stage::Grasp, &result).map_err(typed)?;
            let plan =
                plan.ok_or_else(|| PlanError::Plan { job: task.job_id.to_string(), reason: "not given".into() })?;
            let chunk =
                GraspChunk::from_key(task.key).ok_or_else(|| PlanError::BadKey { task: task.id.to_string() })?;
            let trials = plan.trials(&chunk);
            check_grasp_counts(task.id, &result, trials.len())?;
            let accepted: BTreeSet<u32> = result.accepted.into_iter().collect();
            if let Some(&grasp) = accepted.iter().find(|g| !trials.contains(g)) {
                return Err(PlanError::ForeignGrasp { task: task.id.to_string(), grasp });
            }
            let accepted: Vec<u32> = accepted.into_iter().collect();
            let children = plan::after_grasp(plan, &chunk, &accepted)
                .map_err(|source| PlanError::Planning { job: task.job_id.to_string(), source })?;
            Ok(Unlocked { children, samples: vec![] })
        }
        Stage::Package => {
            let result: PackageResult = contract::result(Stage::Package, &result).map_err(typed)?;
            let samples = package_samples(task, &result, outputs)?;
            Ok(Unlocked { children: vec![], samples })
        }
        // The others unlock nothing: their dependants exist already.
        other => {
            contract::check_result(other, &result).map_err(typed)?;
            Ok(Unlocked { children: vec![], samples: vec![] })
        }
    }
}

/// A grasp result's counts against what its chunk can have produced: each trial accepted at
/// most once, no more trials accepted and rejected (a quota may stop a chunk early) than the
/// chunk has, summed without overflow, and the active taxels, when given, one entry per accepted
/// trial in its order.
fn check_grasp_counts(task: &str, result: &GraspResult, trials: usize) -> Result<(), PlanError> {
    let mismatch = |what: String| PlanError::GraspMismatch { task: task.to_string(), what };
    let distinct: BTreeSet<u32> = result.accepted.iter().copied().collect();
    if distinct.len() != result.accepted.len() {
        return Err(mismatch("accepts a trial twice".to_string()));
    }
    let rejected = result.rejected.values().try_fold(0u64, |sum, &n| sum.checked_add(u64::from(n)));
    let reported = rejected.and_then(|r| r.checked_add(result.accepted.len() as u64));
    if reported.is_none_or(|n| n > trials as u64) {
        return Err(mismatch(format!(
            "reports {} accepted and {} rejected trials, more than the chunk's {trials}",
            result.accepted.len(),
            rejected.map_or_else(|| "overflowing".to_string(), |r| r.to_string())
        )));
    }
    if !result.active_taxels.is_empty() {
        let order: Vec<u32> = result.active_taxels.iter().map(|a| a.grasp_index).collect();
        if order != result.accepted {
            return Err(mismatch(format!(
                "active_taxels name trials {order:?}, not the accepted {:?} in their order",
                result.accepted
            )));
        }
    }
    Ok(())
}

/// The samples a package task made, after checking its result against its parameters and its
/// outputs: every sample it was asked for has a `meta.json`, every grasp record is one of those
/// samples' grasps, and every output belongs to one of them.
fn package_samples(task: Done<'_>, result: &PackageResult, outputs: &[NewArtifact]) -> Result<Vec<String>, PlanError> {
    let mismatch = |what: String| PlanError::PackageMismatch { task: task.id.to_string(), what };
    let params: package::Params = serde_json::from_str(task.params_json)
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
    let (mut with_meta, mut written) = (BTreeSet::new(), BTreeSet::new());
    for o in outputs {
        let Some((owner, file)) = o.name.split_once('/') else {
            return Err(mismatch(format!("output {:?} is not <sample_id>/<file> or <grasp_id>/<file>", o.name)));
        };
        if made.contains(owner) {
            if file == META_FILE {
                with_meta.insert(owner);
            }
        } else if recorded.contains(owner) && file == GRASP_RECORD_FILE && owner.parse::<GraspId>().is_ok() {
            written.insert(owner.to_string());
        } else {
            return Err(mismatch(format!("output {:?} belongs to no sample or grasp record it made", o.name)));
        }
    }
    if with_meta != made {
        let missing: Vec<_> = made.difference(&with_meta).collect();
        return Err(mismatch(format!("samples without {META_FILE}: {missing:?}")));
    }
    if written != recorded {
        let missing: Vec<_> = recorded.difference(&written).collect();
        return Err(mismatch(format!("grasp records not written: {missing:?}")));
    }
    Ok(result.samples.clone())
}

#[cfg(test)]
mod tests {
    use serde_json::json;
    use vint_core::TaskState;
    use vint_store::RetryPolicy;

    use super::*;

    const SPEC: &str = "objects = [\"tomato_soup_can\"]\n[dataset]\nname = \"t\"\nseed = 1\n\
                        [grasp]\ntrials_per_pair = 4\nchunk_size = 2\n[render]\nviews_per_environment = 2\n";

    fn job(plan_json: Option<String>) -> JobRecord {
        JobRecord {
            id: "j".into(),
            name: "t".into(),
            seed: 1,
            spec_toml: SPEC.into(),
            plan_json,
            state: vint_core::JobState::Running,
            created_ms: 0,
            finished_ms: None,
            timing_only: false,
        }
    }

    fn task(key: &str, stage: Stage, params: serde_json::Value) -> TaskRecord {
        TaskRecord {
            id: format!("j/{key}"),
            job_id: "j".into(),
            key: key.into(),
            stage,
            state: TaskState::Running,
            params_json: params.to_string(),
            attempt: 1,
            max_attempts: 4,
            not_before_ms: 0,
            lease_owner: Some("w".into()),
            lease_deadline_ms: Some(1),
            last_error: None,
            engine_json: None,
            result_json: None,
            reused_from: None,
        }
    }

    fn plan() -> JobPlan {
        JobPlan::new(&DatasetSpec::parse(SPEC).unwrap(), &[]).unwrap()
    }

    fn artifact(name: &str) -> NewArtifact {
        NewArtifact {
            name: name.into(),
            sha256: "a".repeat(64),
            size: 1,
            media_type: "application/json".into(),
            object_key: String::new(),
        }
    }

    #[test]
    fn a_grasp_result_unlocks_render_noise_and_package_tasks_for_its_accepted_trials() {
        let grasp = task("grasp/tomato_soup_can/trx3/c00001", Stage::Grasp, json!({}));
        let result = r#"{"accepted": [3], "rejected": {"no_contact": 1}}"#;
        let unlocked = on_complete(Some(&plan()), (&grasp).into(), result, &[]).unwrap();
        let keys: Vec<&str> = unlocked.children.iter().map(|t| t.key.as_str()).collect();
        assert_eq!(
            keys,
            [
                "render/tomato_soup_can/trx3/g000003",
                "noise/tomato_soup_can/trx3/g000003",
                "package/tomato_soup_can/trx3/c00001"
            ]
        );
    }

    #[test]
    fn a_grasp_result_naming_a_trial_of_another_chunk_or_of_the_wrong_shape_is_refused() {
        let grasp = task("grasp/tomato_soup_can/trx3/c00001", Stage::Grasp, json!({}));
        let foreign = on_complete(Some(&plan()), (&grasp).into(), r#"{"accepted": [0]}"#, &[]);
        assert!(matches!(foreign, Err(PlanError::ForeignGrasp { grasp: 0, .. })));
        // The worker of old read grasps.json itself and sent a count: not the contract.
        let shape = on_complete(Some(&plan()), (&grasp).into(), r#"{"accepted": 2}"#, &[]);
        assert!(matches!(shape, Err(PlanError::Result { .. })), "{:?}", shape.err());
        let render = task("render/tomato_soup_can/trx3/g000003", Stage::Render, json!({}));
        assert!(on_complete(None, (&render).into(), r#"{"views": 2, "device": "CPU"}"#, &[]).is_ok());
        assert!(on_complete(None, (&render).into(), "{}", &[]).is_err());
    }

    /// The chunk c00001 of SPEC's plan holds trials 2 and 3: a report of more trials than that,
    /// a trial accepted twice, counts that overflow a u32 sum, or taxel counts for other trials
    /// are refused.
    #[test]
    fn a_grasp_result_reporting_more_than_its_chunk_can_have_run_is_refused() {
        let grasp = task("grasp/tomato_soup_can/trx3/c00001", Stage::Grasp, json!({}));
        assert_eq!(plan().trials(&GraspChunk::from_key(&grasp.key).unwrap()), 2..4);
        let done = |result: serde_json::Value| on_complete(Some(&plan()), (&grasp).into(), &result.to_string(), &[]);
        let refused = |result: serde_json::Value, says: &str| match done(result) {
            Err(PlanError::GraspMismatch { what, .. }) => assert!(what.contains(says), "{what}"),
            other => panic!("expected a mismatch saying {says:?}, got {:?}", other.err()),
        };
        assert!(done(json!({"accepted": [3], "rejected": {"no_contact": 1}})).is_ok());
        assert!(done(json!({"accepted": [], "rejected": {"no_contact": 1}})).is_ok(), "a quota may stop early");
        refused(json!({"accepted": [3], "rejected": {"no_contact": 2}}), "more than the chunk's 2");
        refused(json!({"accepted": [3, 3]}), "twice");
        refused(json!({"accepted": [], "rejected": {"a": u32::MAX, "b": u32::MAX}}), "more than the chunk's 2");
        let taxels = |index: u32| json!([{"grasp_index": index, "by_region": {"tip": 3}}]);
        assert!(done(json!({"accepted": [3], "active_taxels": taxels(3)})).is_ok());
        refused(json!({"accepted": [3], "active_taxels": taxels(2)}), "active_taxels");
    }

    #[test]
    fn a_package_result_must_name_exactly_its_samples_and_their_grasp_records() {
        let params = json!({"samples": [
            {"sample_id": "tomato_soup_can.trx3.g000003.v00", "grasp_index": 3, "view_index": 0},
            {"sample_id": "tomato_soup_can.trx3.g000003.v01", "grasp_index": 3, "view_index": 1}],
            "modalities": ["pose"]});
        let package = task("package/tomato_soup_can/trx3/c00001", Stage::Package, params);
        let outputs = [
            artifact("tomato_soup_can.trx3.g000003/grasp.json"),
            artifact("tomato_soup_can.trx3.g000003.v00/meta.json"),
            artifact("tomato_soup_can.trx3.g000003.v01/meta.json"),
        ];
        let result = json!({"samples": ["tomato_soup_can.trx3.g000003.v00", "tomato_soup_can.trx3.g000003.v01"],
                            "grasps": ["tomato_soup_can.trx3.g000003"]});
        let unlocked = on_complete(None, (&package).into(), &result.to_string(), &outputs).unwrap();
        assert_eq!(unlocked.samples.len(), 2);

        let mut missing_sample = result.clone();
        missing_sample["samples"] = json!(["tomato_soup_can.trx3.g000003.v00"]);
        let stray_output = [&outputs[..], &[artifact("elsewhere/meta.json")]].concat();
        let mut no_record = result.clone();
        no_record["grasps"] = json!([]);
        for (result, outputs) in [
            (missing_sample, &outputs[..]),
            (result.clone(), &stray_output[..]),
            (no_record, &outputs[..]),
            (result.clone(), &outputs[1..]),
        ] {
            let refused = on_complete(None, (&package).into(), &result.to_string(), outputs);
            assert!(matches!(refused, Err(PlanError::PackageMismatch { .. })), "{result}: {:?}", refused.err());
        }
    }

    #[tokio::test]
    async fn a_job_from_before_plans_were_kept_is_planned_from_its_spec() {
        let dir = tempfile::tempdir().unwrap();
        let url = format!("sqlite://{}", dir.path().join("vint.db").display());
        let store = Store::open(&url, RetryPolicy::default()).await.unwrap();
        let stored = serde_json::to_string(&plan()).unwrap();
        assert_eq!(job_plan(&store, &job(Some(stored))).await.unwrap(), plan());
        assert_eq!(job_plan(&store, &job(None)).await.unwrap(), plan());
        assert!(job_plan(&store, &job(Some("{\"seed\": 1}".into()))).await.is_err());
    }
}
