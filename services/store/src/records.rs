//! Plain records the store reads and writes.

use std::collections::BTreeMap;

use vint_core::{AttemptOutcome, JobState, Stage, TaskState};

#[derive(Clone, Debug, PartialEq)]
pub struct NewJob {
    pub id: String,
    pub name: String,
    pub seed: u64,
    pub spec_toml: String,
    pub idempotency_key: String,
    /// `vint_core::plan::JobPlan` as JSON.
    pub plan_json: String,
    /// The user files the spec names, already in object storage.
    pub assets: Vec<JobAsset>,
    /// Whether timing-only workers may serve it (its output is then not data); never by default.
    pub timing_only: bool,
    /// The name of the token that submitted it (`None` without tokens).
    pub submitted_by: Option<String>,
}

/// A user file of a job (a hand's MJCF model or taxel layout, an object's mesh; see
/// `vint_core::asset`), stored content-addressed under `object_key`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct JobAsset {
    /// As the spec names it, relative to the spec file.
    pub path: String,
    pub sha256: String,
    pub size: u64,
    pub media_type: String,
    pub object_key: String,
}

#[derive(Clone, Debug, PartialEq)]
pub struct JobRecord {
    pub id: String,
    pub name: String,
    pub seed: u64,
    pub spec_toml: String,
    /// `vint_core::plan::JobPlan` as JSON; `None` for jobs from before it was kept.
    pub plan_json: Option<String>,
    pub state: JobState,
    pub created_ms: i64,
    pub finished_ms: Option<i64>,
    /// Submitted for timing-only workers (migration 0014): its files are stand-ins, not data.
    pub timing_only: bool,
}

#[derive(Clone, Debug, PartialEq)]
pub struct TaskRecord {
    pub id: String,
    pub job_id: String,
    pub key: String,
    pub stage: Stage,
    pub state: TaskState,
    pub params_json: String,
    pub attempt: u32,
    pub max_attempts: u32,
    pub not_before_ms: i64,
    pub lease_owner: Option<String>,
    pub lease_deadline_ms: Option<i64>,
    pub last_error: Option<String>,
    pub engine_json: Option<String>,
    pub result_json: Option<String>,
    /// The task whose result it took instead of running (`None`: it ran, or has not finished).
    pub reused_from: Option<String>,
}

/// An artifact as recorded: content hash, where it lives and which task made it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ArtifactRecord {
    pub task_id: String,
    pub task_key: String,
    pub name: String,
    pub sha256: String,
    pub size: u64,
    pub media_type: String,
    pub object_key: String,
}

/// An output a worker reports; its content is already in object storage under `object_key`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct NewArtifact {
    pub name: String,
    pub sha256: String,
    pub size: u64,
    pub media_type: String,
    pub object_key: String,
}

/// A task handed to a worker, with the outputs of its dependencies as inputs.
#[derive(Clone, Debug, PartialEq)]
pub struct LeasedTask {
    pub id: String,
    pub job_id: String,
    pub key: String,
    pub stage: Stage,
    pub attempt: u32,
    pub params_json: String,
    pub inputs: Vec<ArtifactRecord>,
    pub lease_deadline_ms: i64,
}

/// Who may finish a task: the worker holding the lease of this attempt.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Fence {
    pub task_id: String,
    pub worker_id: String,
    pub attempt: u32,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Completion {
    pub fence: Fence,
    pub outputs: Vec<NewArtifact>,
    pub engine_json: String,
    pub timings_json: String,
    pub result_json: String,
    /// Samples this (package) task made; their files are its outputs named `<sample>/<file>`.
    pub samples: Vec<String>,
    /// The task whose result and outputs these are (task reuse): no attempt ran, none is recorded.
    pub reused_from: Option<String>,
}

/// Counts of a job's tasks by stage and state.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Progress {
    pub by_stage: BTreeMap<Stage, BTreeMap<TaskState, u64>>,
    /// Succeeded tasks by stage that took a finished task's result instead of running.
    pub reused: BTreeMap<Stage, u64>,
    pub samples: u64,
}

impl Progress {
    pub fn count(&self, state: TaskState) -> u64 {
        self.by_stage.values().filter_map(|m| m.get(&state)).sum()
    }

    pub fn stage_count(&self, stage: Stage, state: TaskState) -> u64 {
        self.by_stage.get(&stage).and_then(|m| m.get(&state)).copied().unwrap_or(0)
    }

    pub fn total(&self) -> u64 {
        self.by_stage.values().flat_map(|m| m.values()).sum()
    }
}

/// One task in a lineage chain, with what it consumed and produced.
#[derive(Clone, Debug, PartialEq)]
pub struct LineageEntry {
    pub task: TaskRecord,
    pub depends_on: Vec<String>,
    pub inputs: Vec<ArtifactRecord>,
    pub outputs: Vec<ArtifactRecord>,
}

/// One attempt at a task.
#[derive(Clone, Debug, PartialEq)]
pub struct AttemptRecord {
    pub task_id: String,
    pub attempt: u32,
    pub worker_id: String,
    pub started_ms: i64,
    pub ended_ms: Option<i64>,
    /// `None` while the attempt runs.
    pub outcome: Option<AttemptOutcome>,
    pub error: Option<String>,
}
