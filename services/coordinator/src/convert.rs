//! Conversions between store records and protobuf messages, and store errors to gRPC statuses.

use tonic::Status;
use vint_proto::v1 as pb;
use vint_store::{ArtifactRecord, DashboardTable, FailedTask, JobRecord, Progress, StoreError};

pub fn status(e: StoreError) -> Status {
    match e {
        StoreError::LeaseLost { .. } => Status::failed_precondition(e.to_string()),
        StoreError::NotFound(_) => Status::not_found(e.to_string()),
        StoreError::Invalid(_) => Status::invalid_argument(e.to_string()),
        // The database's own words stay in the log: they can name tables, roles and hosts.
        other if other.is_transient() => {
            tracing::warn!(error = %other, "store unavailable");
            Status::unavailable("the coordinator's database is unavailable; try again")
        }
        other => {
            tracing::error!(error = %other, "store error");
            Status::internal("internal error in the coordinator's store (its log has the details)")
        }
    }
}

pub fn artifact(a: &ArtifactRecord) -> pb::ArtifactRef {
    pb::ArtifactRef {
        name: a.name.clone(),
        sha256: a.sha256.clone(),
        size: a.size,
        media_type: a.media_type.clone(),
        key: a.object_key.clone(),
        task_key: a.task_key.clone(),
    }
}

pub fn progress(job: &JobRecord, p: &Progress) -> pb::JobProgress {
    use vint_core::TaskState as S;
    let stages = p
        .by_stage
        .iter()
        .map(|(stage, counts)| {
            let get = |s: S| counts.get(&s).copied().unwrap_or(0);
            (
                stage.as_str().to_string(),
                pb::StageProgress {
                    total: counts.values().sum(),
                    succeeded: get(S::Succeeded),
                    failed: get(S::Failed),
                    reused: p.reused.get(stage).copied().unwrap_or(0),
                },
            )
        })
        .collect();
    pb::JobProgress {
        job_id: job.id.clone(),
        state: job.state.as_str().to_string(),
        tasks_total: p.total(),
        tasks_succeeded: p.count(S::Succeeded),
        tasks_failed: p.count(S::Failed),
        tasks_running: p.count(S::Running),
        tasks_queued: p.count(S::Queued),
        tasks_waiting: p.count(S::Waiting),
        tasks_cancelled: p.count(S::Cancelled),
        samples_packaged: p.samples,
        stages,
        failed_tasks: Vec::new(), // a store query of its own: `JobApi` adds them when tasks failed
    }
}

pub fn job(job: &JobRecord, p: &Progress) -> pb::Job {
    pb::Job {
        job_id: job.id.clone(),
        name: job.name.clone(),
        state: job.state.as_str().to_string(),
        seed: job.seed,
        spec_toml: job.spec_toml.clone(),
        created_ms: job.created_ms,
        finished_ms: job.finished_ms.unwrap_or(0),
        progress: Some(progress(job, p)),
        timing_only: job.timing_only,
    }
}

/// Longest `last_error` a failed task carries on the wire: an engine's message is a line, a crash
/// report can be a traceback; its end says the most, so the start gives way.
const MAX_ERROR_CHARS: usize = 2000;

pub fn failed_task(t: &FailedTask) -> pb::FailedTask {
    let chars = t.last_error.chars().count();
    let last_error = if chars > MAX_ERROR_CHARS {
        let tail: String = t.last_error.chars().skip(chars - (MAX_ERROR_CHARS - 1)).collect();
        format!("…{tail}")
    } else {
        t.last_error.clone()
    };
    pb::FailedTask {
        key: t.key.clone(),
        stage: t.stage.as_str().to_string(),
        attempts: t.attempts,
        last_error,
        failed_upstream: t.failed_upstream(),
    }
}

/// A dashboard view's rows as the wire carries them: each value text, integer, real or unset (NULL).
pub fn dashboard(table: DashboardTable) -> pb::DashboardTable {
    use pb::dashboard_value::Value as V;
    let value = |v: serde_json::Value| pb::DashboardValue {
        value: match v {
            serde_json::Value::String(s) => Some(V::Text(s)),
            serde_json::Value::Number(n) => n.as_i64().map(V::Integer).or_else(|| n.as_f64().map(V::Real)),
            serde_json::Value::Null => None,
            other => Some(V::Text(other.to_string())),
        },
    };
    pb::DashboardTable {
        view: table.view.name().to_string(),
        columns: table.columns,
        rows: table
            .rows
            .into_iter()
            .map(|row| pb::DashboardRow { values: row.into_iter().map(value).collect() })
            .collect(),
    }
}
