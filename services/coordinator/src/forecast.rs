//! What a spec would run and what it would reuse, before it is submitted (`vintctl plan SPEC
//! --against JOB`).
//!
//! The forecast plans the spec as a submission would, keys each task as a lease would
//! (`reuse::key_of`'s rule, with the engine identities given), and looks each key up among the
//! store's finished results. A reused grasp chunk's stored result says which trials it accepted, so
//! the render, noise and package tasks it unlocks are planned and keyed in turn, with the stored
//! outputs of their reused dependencies as inputs. A task that will run says why, by comparison
//! with the task of the same key in JOB: new, its parameters (the first field that differs), its
//! engine, its inputs, or an upstream task that runs. What follows a grasp chunk that runs cannot
//! be known before its trials are (their count in JOB is given instead).
//!
//! Early cutoff is not foreseen: a re-run whose outputs come out byte-identical still lets its
//! dependents be reused when the job runs, which the forecast counts as "will run".

use std::collections::{BTreeMap, HashMap, HashSet};

use serde::Serialize;
use serde_json::Value;
use vint_core::asset::Asset;
use vint_core::plan::{self, GraspChunk, JobPlan, NewTask};
use vint_core::reuse::{self, Input};
use vint_core::{DatasetSpec, Stage, TaskState};
use vint_store::{NewArtifact, Store, StoreError, StoredResult, TaskRecord};

use crate::planner;

#[derive(Debug, thiserror::Error)]
pub enum ForecastError {
    #[error("job {0} not found in this store")]
    NoJob(String),
    #[error("the spec cannot be planned: {0}")]
    Plan(#[from] plan::PlanError),
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("a stored result does not plan: {0}")]
    Stored(String),
}

/// One stage's forecast.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct StageForecast {
    /// Tasks planned now (those after a grasp chunk that runs are not, see `after_runs`).
    pub planned: u64,
    pub reused: u64,
    pub run: u64,
    /// Why the tasks that run do, with how many tasks each reason covers.
    pub reasons: BTreeMap<String, u64>,
    /// Tasks of this stage in JOB that follow grasp chunks which run: planned when those finish.
    pub after_runs: u64,
}

/// What submitting the spec would do, stage by stage.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Forecast {
    pub against: String,
    pub stages: BTreeMap<String, StageForecast>,
}

impl Forecast {
    fn stage(&mut self, stage: Stage) -> &mut StageForecast {
        self.stages.entry(stage.as_str().to_string()).or_default()
    }

    fn reused(&mut self, stage: Stage) {
        let s = self.stage(stage);
        s.planned += 1;
        s.reused += 1;
    }

    fn runs(&mut self, stage: Stage, reason: String) {
        let s = self.stage(stage);
        s.planned += 1;
        s.run += 1;
        *s.reasons.entry(reason).or_default() += 1;
    }
}

/// The forecast of `spec` (with its user files `assets`) against the finished job `against`,
/// for workers whose engines have `identities` (a stage without one is forecast to run).
pub async fn forecast(
    store: &Store,
    spec: &DatasetSpec,
    assets: &[Asset],
    identities: &HashMap<Stage, String>,
    against: &str,
) -> Result<Forecast, ForecastError> {
    store.job(against).await?.ok_or_else(|| ForecastError::NoJob(against.to_string()))?;
    let old: HashMap<String, TaskRecord> =
        store.tasks_of_job(against).await?.into_iter().map(|t| (t.key.clone(), t)).collect();
    let job_plan = JobPlan::new(spec, assets)?;
    let grasps = plan::initial_tasks(spec, assets)?;
    let mut f = Forecast { against: against.to_string(), ..Forecast::default() };
    // Outputs of the tasks that will be reused, by task key.
    let mut outputs: HashMap<String, Vec<NewArtifact>> = HashMap::new();
    let mut running: HashSet<String> = HashSet::new();
    let mut next: Vec<NewTask> = Vec::new();

    let found = lookup(store, &grasps, identities, &outputs).await?;
    for task in &grasps {
        match found.get(&task.key) {
            Some(stored) => {
                f.reused(Stage::Grasp);
                let params_json = task.params.to_string();
                let unlocked = planner::on_complete(
                    Some(&job_plan),
                    done(task, &params_json),
                    &stored.result_json,
                    &stored.outputs,
                )
                .map_err(|e| ForecastError::Stored(e.to_string()))?;
                next.extend(unlocked.children);
                outputs.insert(task.key.clone(), stored.outputs.clone());
            }
            None => {
                f.runs(Stage::Grasp, why(task, identities, old.get(&task.key), &running));
                running.insert(task.key.clone());
                count_after_runs(&mut f, &job_plan, task, &old);
            }
        }
    }
    // The rest in pipeline order: a task's dependencies are forecast before it.
    for stage in Stage::ALL.into_iter().filter(|s| *s != Stage::Grasp) {
        let tasks: Vec<NewTask> = next.iter().filter(|t| t.stage == stage).cloned().collect();
        let ready: Vec<NewTask> =
            tasks.iter().filter(|t| !t.deps.iter().any(|d| running.contains(d))).cloned().collect();
        let found = lookup(store, &ready, identities, &outputs).await?;
        for task in &tasks {
            match found.get(&task.key) {
                Some(stored) => {
                    f.reused(stage);
                    outputs.insert(task.key.clone(), stored.outputs.clone());
                }
                None => {
                    f.runs(stage, why(task, identities, old.get(&task.key), &running));
                    running.insert(task.key.clone());
                }
            }
        }
    }
    Ok(f)
}

/// The stored results of the tasks whose reuse key has one, by task key.
async fn lookup(
    store: &Store,
    tasks: &[NewTask],
    identities: &HashMap<Stage, String>,
    outputs: &HashMap<String, Vec<NewArtifact>>,
) -> Result<HashMap<String, StoredResult>, ForecastError> {
    let keyed: Vec<(String, String)> =
        tasks.iter().filter_map(|t| key_of(t, identities, outputs).map(|k| (t.key.clone(), k))).collect();
    let keys: Vec<String> = keyed.iter().map(|(_, k)| k.clone()).collect();
    let mut found = store.stored_results(&keys).await?;
    Ok(keyed.into_iter().filter_map(|(task, k)| found.remove(&k).map(|r| (task, r))).collect())
}

/// A planned task's reuse key, when its stage has an identity and its inputs are known (every
/// dependency reused).
fn key_of(
    task: &NewTask,
    identities: &HashMap<Stage, String>,
    outputs: &HashMap<String, Vec<NewArtifact>>,
) -> Option<String> {
    let identity = identities.get(&task.stage)?;
    let mut inputs = Vec::new();
    for dep in &task.deps {
        inputs.extend(outputs.get(dep)?.iter().map(|a| Input { task_key: dep, name: &a.name, sha256: &a.sha256 }));
    }
    Some(reuse::task_key(task.stage, identity, &task.params.to_string(), &inputs))
}

/// Why a planned task will run, compared with the task of the same key in the earlier job.
fn why(
    task: &NewTask,
    identities: &HashMap<Stage, String>,
    old: Option<&TaskRecord>,
    running: &HashSet<String>,
) -> String {
    if let Some(dep) = task.deps.iter().find(|d| running.contains(*d)) {
        let stage = dep.split('/').next().unwrap_or("upstream");
        return format!("its {stage} task runs");
    }
    let Some(identity) = identities.get(&task.stage) else {
        return "no engine identity known here".into();
    };
    let Some(old) = old else {
        return "new task".into();
    };
    let old_params: Value = serde_json::from_str(&old.params_json).unwrap_or(Value::Null);
    if let Some(path) = first_difference(&task.params, &old_params, String::new()) {
        return format!("parameter {path} changed");
    }
    let old_identity = old
        .engine_json
        .as_deref()
        .and_then(|e| serde_json::from_str::<Value>(e).ok())
        .and_then(|e| e.get("identity").and_then(Value::as_str).map(str::to_string));
    match old_identity {
        Some(id) if &id != identity => return "engine changed".into(),
        None if old.state == TaskState::Succeeded => return "engine identity not recorded in that job".into(),
        _ => {}
    }
    if old.state != TaskState::Succeeded {
        return format!("{} in that job", old.state.as_str());
    }
    "inputs changed".into()
}

/// The path of the first leaf where `a` and `b` differ (array indices written `[]`, so that one
/// change repeated over every view reads as one reason), or `None` when they are equal.
fn first_difference(a: &Value, b: &Value, path: String) -> Option<String> {
    let here = || if path.is_empty() { "(all)".to_string() } else { path.clone() };
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            let keys: std::collections::BTreeSet<&String> = x.keys().chain(y.keys()).collect();
            keys.into_iter().find_map(|k| {
                let sub = if path.is_empty() { k.clone() } else { format!("{path}.{k}") };
                first_difference(x.get(k).unwrap_or(&Value::Null), y.get(k).unwrap_or(&Value::Null), sub)
            })
        }
        (Value::Array(x), Value::Array(y)) if x.len() == y.len() => {
            x.iter().zip(y).find_map(|(p, q)| first_difference(p, q, format!("{path}[]")))
        }
        _ if a == b => None,
        _ => Some(here()),
    }
}

/// The earlier job's tasks downstream of a grasp chunk (its grasps' and its package task) that
/// will run.
fn count_after_runs(f: &mut Forecast, job_plan: &JobPlan, grasp: &NewTask, old: &HashMap<String, TaskRecord>) {
    let Some(chunk) = GraspChunk::from_key(&grasp.key) else { return };
    for g in job_plan.trials(&chunk) {
        for (stage, key) in plan::grasp_keys(&chunk.object, &chunk.hand, g) {
            if old.contains_key(&key) {
                f.stage(stage).after_runs += 1;
            }
        }
    }
    if old.contains_key(&chunk.package_key()) {
        f.stage(Stage::Package).after_runs += 1;
    }
}

/// A planned task as the planner reads it (its id is its key: the forecast belongs to no job).
fn done<'a>(task: &'a NewTask, params_json: &'a str) -> planner::Done<'a> {
    planner::Done { id: &task.key, job_id: "", key: &task.key, stage: task.stage, params_json }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn the_first_difference_names_the_field_and_collapses_indices() {
        let a = json!({"noise": {"sigma": 1.0, "mode": "nfov"}, "views": [{"seed": 1}, {"seed": 2}]});
        let b = json!({"noise": {"sigma": 2.0, "mode": "nfov"}, "views": [{"seed": 1}, {"seed": 2}]});
        assert_eq!(first_difference(&a, &b, String::new()).as_deref(), Some("noise.sigma"));
        let c = json!({"noise": {"sigma": 1.0, "mode": "nfov"}, "views": [{"seed": 1}, {"seed": 3}]});
        assert_eq!(first_difference(&a, &c, String::new()).as_deref(), Some("views[].seed"));
        let d = json!({"noise": {"sigma": 1.0, "mode": "nfov"}, "views": [{"seed": 1}]});
        assert_eq!(first_difference(&a, &d, String::new()).as_deref(), Some("views"));
        assert_eq!(first_difference(&a, &a, String::new()), None);
        let e = json!({"noise": {"sigma": 1.0, "mode": "nfov", "extra": 1}, "views": [{"seed": 1}, {"seed": 2}]});
        assert_eq!(first_difference(&a, &e, String::new()).as_deref(), Some("noise.extra"));
    }
}
