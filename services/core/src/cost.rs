//! What a spec costs before anything runs, stage by stage: its tasks, counted by the planner
//! itself (the chunks a pair splits into and what each chunk's accepted grasps unlock), and each
//! stage's CPU time and object-store bytes from its own `cost` (`contract`). `vintctl validate`
//! and `vintctl plan` show it; no stage is named here.
//!
//! Every figure is an upper bound without a quota (every trial accepted) and the quota's target
//! with one (`Estimate::exact`).

use std::collections::{BTreeMap, BTreeSet};

use serde_json::Value;

use crate::asset::Asset;
use crate::contract::{self, BadParams, Cost, Workload};
use crate::plan::{GraspChunk, JobPlan, NewTask, PlanError, after_grasp, grasp_task};
use crate::spec::DatasetSpec;
use crate::stage::Stage;

/// One stage's share of a spec.
#[derive(Clone, Debug, PartialEq)]
pub struct StageCost {
    pub stage: Stage,
    pub tasks: u64,
    /// Whether `tasks` is fixed by the spec alone (tasks that exist at submit always are; the
    /// others when a quota fixes the grasps, or when there are none).
    pub tasks_exact: bool,
    pub cost: Cost,
    /// Bytes of one task's parameters as the planner makes them for this spec (0 without tasks).
    pub params_bytes: f64,
}

/// A spec's cost: what it asks for, counted, and every stage's share, in `Stage::ALL`'s order.
#[derive(Clone, Debug, PartialEq)]
pub struct SpecCost {
    pub work: Workload,
    /// Whether a quota fixes the grasps (the counts are exact) or they are an upper bound.
    pub exact: bool,
    pub stages: Vec<StageCost>,
    /// The job's plan, as the coordinator would store it.
    pub job: JobPlan,
    /// The job's grasp chunks, grouped: what the database's footprint is counted from.
    pub chunks: Vec<ChunkGroup>,
}

/// Chunks that accept the same number of grasps plan alike: one of them planned (its grasp task,
/// then what its completion unlocks) and how many chunks of the whole job it stands for.
#[derive(Clone, Debug, PartialEq)]
pub struct ChunkGroup {
    pub chunks: u64,
    pub tasks: Vec<NewTask>,
}

impl SpecCost {
    pub fn total(&self) -> Cost {
        self.stages
            .iter()
            .fold(Cost::default(), |a, s| Cost { cpu_s: a.cpu_s + s.cost.cpu_s, bytes: a.bytes + s.cost.bytes })
    }
}

/// Why a spec cannot be costed: it cannot be planned, or the planner made parameters its own
/// stage does not read (a defect).
#[derive(Debug, thiserror::Error)]
pub enum CostError {
    #[error(transparent)]
    Plan(#[from] PlanError),
    #[error(transparent)]
    Params(#[from] BadParams),
}

/// What `spec` asks for, counted.
pub fn workload(spec: &DatasetSpec) -> Workload {
    let pairs = (spec.hands.len() * spec.objects.len()) as u64;
    let budget = spec.grasp.budget();
    let views_per_grasp = u64::from(spec.render.views_per_grasp());
    let grasps = pairs * u64::from(budget.grasps());
    Workload {
        pairs,
        objects: spec.objects.len() as u64,
        chunks: pairs * u64::from(budget.chunks()),
        trials: pairs * u64::from(spec.grasp.trials_per_pair),
        grasps,
        views_per_grasp,
        samples: grasps * views_per_grasp,
        pixels: f64::from(spec.render.resolution[0]) * f64::from(spec.render.resolution[1]),
    }
}

/// The spec's user files as the planner sees them. A plan's shape (which tasks, which outputs)
/// does not depend on the files' content, only on which files the spec names, so they stand in
/// unread.
pub fn stand_in_assets(spec: &DatasetSpec) -> Vec<Asset> {
    spec.asset_uses().into_iter().map(|u| Asset { path: u.path, sha256: "0".repeat(64), size: 0 }).collect()
}

/// Every stage's tasks and cost for `spec`. Every pair splits alike, so one pair is planned:
/// its chunks by how many grasps each accepts (a handful of distinct counts), each count's
/// chunk through `after_grasp`.
pub fn of(spec: &DatasetSpec) -> Result<SpecCost, CostError> {
    let work = workload(spec);
    let assets = stand_in_assets(spec);
    let job = JobPlan::new(spec, &assets)?;
    let budget = job.budget();
    let mut tasks: BTreeMap<Stage, u64> = BTreeMap::new();
    let mut sample: BTreeMap<Stage, Value> = BTreeMap::new();
    let mut initial: BTreeSet<Stage> = BTreeSet::new();
    let mut chunks = Vec::new();
    let mut by_grasps: BTreeMap<u32, (u32, u64)> = BTreeMap::new();
    for c in 0..budget.chunks() {
        let grasps = budget.quota(c).unwrap_or_else(|| budget.trials(c).len() as u32);
        by_grasps.entry(grasps).or_insert((c, 0)).1 += 1;
    }
    // Chunk 0 first, so that each stage's sample task is the first chunk's.
    let mut groups: Vec<(u32, u32, u64)> = by_grasps.into_iter().map(|(g, (c, n))| (c, g, n)).collect();
    groups.sort();
    if let (Some(object), Some(hand)) = (spec.objects.first(), spec.hands.first()) {
        for (c, grasps, n) in groups {
            let chunk = GraspChunk { object: object.clone(), hand: hand.clone(), chunk: c };
            let at_submit = grasp_task(spec, &job, &chunk, &assets)?;
            initial.insert(at_submit.stage);
            let accepted: Vec<u32> = job.trials(&chunk).take(grasps as usize).collect();
            let mut planned = vec![at_submit];
            planned.extend(after_grasp(&job, &chunk, &accepted)?);
            for t in &planned {
                *tasks.entry(t.stage).or_default() += n * work.pairs;
                sample.entry(t.stage).or_insert_with(|| t.params.clone());
            }
            chunks.push(ChunkGroup { chunks: n * work.pairs, tasks: planned });
        }
    }
    let mut stages = Vec::new();
    for stage in Stage::ALL {
        let count = tasks.get(&stage).copied().unwrap_or(0);
        let (cost, params_bytes) = match sample.get(&stage) {
            Some(params) => (contract::cost(stage, &work, params)?, params.to_string().len() as f64),
            None => (Cost::default(), 0.0),
        };
        let exact = initial.contains(&stage) || spec.grasp.accepted_per_pair.is_some() || count == 0;
        stages.push(StageCost { stage, tasks: count, tasks_exact: exact, cost, params_bytes });
    }
    Ok(SpecCost { work, exact: spec.grasp.accepted_per_pair.is_some(), stages, job, chunks })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::initial_tasks;

    fn spec(extra: &str) -> DatasetSpec {
        DatasetSpec::parse(&format!(
            "objects = [\"mug\", \"tomato_soup_can\"]\n[dataset]\nname = \"t\"\nseed = 1\n{extra}"
        ))
        .unwrap()
    }

    /// The grouped count against planning every chunk of every pair, one by one.
    #[test]
    fn grouped_counts_are_every_chunk_planned() {
        for extra in [
            "[grasp]\ntrials_per_pair = 7\nchunk_size = 3\n",
            "[grasp]\ntrials_per_pair = 40\naccepted_per_pair = 10\nchunk_size = 4\n",
            "[grasp]\ntrials_per_pair = 5\nchunk_size = 2\n[outputs]\nmodalities = [\"rgb\", \"pose\"]\n",
        ] {
            let spec = spec(extra);
            let c = of(&spec).unwrap();
            let budget = c.job.budget();
            let mut every: BTreeMap<Stage, u64> = BTreeMap::new();
            for g in initial_tasks(&spec, &[]).unwrap() {
                let chunk = GraspChunk::from_key(&g.key).unwrap();
                let n = budget.quota(chunk.chunk).unwrap_or(c.job.trials(&chunk).len() as u32);
                let accepted: Vec<u32> = c.job.trials(&chunk).take(n as usize).collect();
                *every.entry(g.stage).or_default() += 1;
                for t in after_grasp(&c.job, &chunk, &accepted).unwrap() {
                    *every.entry(t.stage).or_default() += 1;
                }
            }
            for s in &c.stages {
                assert_eq!(s.tasks, every.get(&s.stage).copied().unwrap_or(0), "{} of {extra}", s.stage);
                assert_eq!(s.tasks == 0, s.cost == Cost::default(), "{} of {extra}", s.stage);
            }
            let grouped: u64 = c.chunks.iter().map(|g| g.chunks * g.tasks.len() as u64).sum();
            assert_eq!(grouped, every.values().sum::<u64>(), "{extra}");
        }
    }

    #[test]
    fn only_submitted_tasks_are_exact_without_a_quota() {
        let c = of(&spec("[grasp]\ntrials_per_pair = 7\nchunk_size = 3\n")).unwrap();
        let exact: Vec<bool> = c.stages.iter().map(|s| s.tasks_exact).collect();
        assert_eq!(exact, [true, false, false, false]);
        let c = of(&spec("[grasp]\ntrials_per_pair = 40\naccepted_per_pair = 10\nchunk_size = 4\n")).unwrap();
        assert!(c.exact && c.stages.iter().all(|s| s.tasks_exact));
    }
}
