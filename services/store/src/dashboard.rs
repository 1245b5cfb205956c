//! The dashboard: what an operator and a dataset owner ask of a job, read from the views of
//! migration 0008 (`dashboard.<name>` on Postgres, `dashboard_<name>` on SQLite).
//!
//! Callers name a view from a fixed list (`DashboardView`), never SQL; each view's columns and
//! their types are declared here, so every reader — the coordinator's QueryDashboard, `vintctl
//! dashboard`, a web page — gets the same typed table. docs/dashboard.md describes the views.

use std::fmt;
use std::str::FromStr;

use serde_json::Value;
use sqlx::Row;
use sqlx::any::AnyRow;

use crate::sql::sql;
use crate::{Result, Store};

/// The most rows one query returns (and what a limit of 0 means).
pub const MAX_ROWS: u32 = 10_000;

/// The jobs a per-job view shows when asked for no job: the newest, those the dashboard lists.
pub const JOBS_SHOWN: u32 = 50;

/// A column's type, as every backend returns it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ColumnType {
    Text,
    Integer,
    Real,
}

/// One of the dashboard views.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DashboardView {
    /// Tasks per job and stage in each state.
    JobProgress,
    /// Attempts ended per job, stage and minute, succeeded or not, with their engine time.
    Throughput,
    /// Attempts that did not succeed, by stage, outcome and reason, with example task keys.
    Failures,
    /// Workers, their stages, when they were last heard from, and the tasks they hold. Not per job.
    Workers,
    /// Grasp trials per (object, hand): ran, accepted, rejected.
    GraspAcceptance,
    /// Rejected grasp trials per (object, hand) by reason.
    GraspRejections,
    /// Active taxels per accepted grasp, by hand and region.
    ActiveTaxels,
    /// Render engine seconds per view by resolution, samples per pixel and device.
    RenderSeconds,
    /// Files and bytes recorded per job and stage.
    BytesWritten,
    /// Rendered views per job and object by occlusion, in tenths (migration 0010).
    Occlusion,
}

use ColumnType::{Integer, Real, Text};

impl DashboardView {
    pub const ALL: [DashboardView; 10] = [
        DashboardView::JobProgress,
        DashboardView::Throughput,
        DashboardView::Failures,
        DashboardView::Workers,
        DashboardView::GraspAcceptance,
        DashboardView::GraspRejections,
        DashboardView::ActiveTaxels,
        DashboardView::RenderSeconds,
        DashboardView::BytesWritten,
        DashboardView::Occlusion,
    ];

    /// The view's name, as `vintctl dashboard` and the RPC take it.
    pub fn name(self) -> &'static str {
        match self {
            DashboardView::JobProgress => "job_progress",
            DashboardView::Throughput => "throughput",
            DashboardView::Failures => "failures",
            DashboardView::Workers => "workers",
            DashboardView::GraspAcceptance => "grasp_acceptance",
            DashboardView::GraspRejections => "grasp_rejections",
            DashboardView::ActiveTaxels => "active_taxels",
            DashboardView::RenderSeconds => "render_seconds",
            DashboardView::BytesWritten => "bytes_written",
            DashboardView::Occlusion => "occlusion",
        }
    }

    /// Whether its rows belong to a job (a `job_id` column a query can filter on).
    pub fn per_job(self) -> bool {
        self != DashboardView::Workers
    }

    /// Its columns, in order, with their types.
    pub fn columns(self) -> &'static [(&'static str, ColumnType)] {
        match self {
            DashboardView::JobProgress => &[
                ("job_id", Text),
                ("stage", Text),
                ("tasks", Integer),
                ("waiting", Integer),
                ("queued", Integer),
                ("running", Integer),
                ("succeeded", Integer),
                ("failed", Integer),
                ("cancelled", Integer),
            ],
            DashboardView::Throughput => &[
                ("job_id", Text),
                ("stage", Text),
                ("minute_ms", Integer),
                ("succeeded", Integer),
                ("failed", Integer),
                ("engine_s", Real),
            ],
            DashboardView::Failures => &[
                ("job_id", Text),
                ("stage", Text),
                ("outcome", Text),
                ("reason", Text),
                ("attempts", Integer),
                ("tasks", Integer),
                ("first_task_key", Text),
                ("last_task_key", Text),
            ],
            DashboardView::Workers => &[
                ("worker_id", Text),
                ("stages", Text),
                ("first_seen_ms", Integer),
                ("last_seen_ms", Integer),
                ("last_heartbeat_ms", Integer),
                ("running_tasks", Integer),
            ],
            DashboardView::GraspAcceptance => &[
                ("job_id", Text),
                ("object", Text),
                ("hand", Text),
                ("tasks", Integer),
                ("trials", Integer),
                ("accepted", Integer),
                ("rejected", Integer),
                ("acceptance", Real),
            ],
            DashboardView::GraspRejections => {
                &[("job_id", Text), ("object", Text), ("hand", Text), ("reason", Text), ("trials", Integer)]
            }
            DashboardView::ActiveTaxels => &[
                ("job_id", Text),
                ("hand", Text),
                ("region", Text),
                ("grasps", Integer),
                ("active_taxels", Integer),
                ("mean_per_grasp", Real),
                ("min_per_grasp", Integer),
                ("max_per_grasp", Integer),
            ],
            DashboardView::RenderSeconds => &[
                ("job_id", Text),
                ("width", Integer),
                ("height", Integer),
                ("samples", Integer),
                ("device", Text),
                ("renders", Integer),
                ("views", Integer),
                ("engine_s", Real),
                ("seconds_per_view", Real),
            ],
            DashboardView::BytesWritten => &[("job_id", Text), ("stage", Text), ("files", Integer), ("bytes", Integer)],
            DashboardView::Occlusion => &[("job_id", Text), ("object", Text), ("bin", Integer), ("views", Integer)],
        }
    }

    /// The statement that reads it (`sql/<dialect>/dashboard.sql`): its columns in the order of
    /// its grouping columns, of one job or of all.
    fn statement(self) -> &'static str {
        match self {
            DashboardView::JobProgress => "dashboard_job_progress",
            DashboardView::Throughput => "dashboard_throughput",
            DashboardView::Failures => "dashboard_failures",
            DashboardView::Workers => "dashboard_workers",
            DashboardView::GraspAcceptance => "dashboard_grasp_acceptance",
            DashboardView::GraspRejections => "dashboard_grasp_rejections",
            DashboardView::ActiveTaxels => "dashboard_active_taxels",
            DashboardView::RenderSeconds => "dashboard_render_seconds",
            DashboardView::BytesWritten => "dashboard_bytes_written",
            DashboardView::Occlusion => "dashboard_occlusion",
        }
    }
}

impl fmt::Display for DashboardView {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A name that is no dashboard view.
#[derive(Debug, thiserror::Error)]
#[error("{0:?} is not a dashboard view (one of: {names})", names = view_names())]
pub struct UnknownView(pub String);

fn view_names() -> String {
    DashboardView::ALL.iter().map(|v| v.name()).collect::<Vec<_>>().join(", ")
}

impl FromStr for DashboardView {
    type Err = UnknownView;
    fn from_str(s: &str) -> std::result::Result<Self, Self::Err> {
        DashboardView::ALL.into_iter().find(|v| v.name() == s).ok_or_else(|| UnknownView(s.to_string()))
    }
}

/// A view's rows: each a value per column (`null`, a string, an integer or a number).
#[derive(Clone, Debug, PartialEq)]
pub struct DashboardTable {
    pub view: DashboardView,
    pub columns: Vec<String>,
    pub rows: Vec<Vec<Value>>,
}

impl DashboardTable {
    /// The rows as JSON objects keyed by column name.
    pub fn objects(&self) -> Vec<serde_json::Map<String, Value>> {
        self.rows.iter().map(|row| self.columns.iter().cloned().zip(row.iter().cloned()).collect()).collect()
    }
}

impl Store {
    /// Up to `limit` rows of `view` (`MAX_ROWS` when 0 or more), of one job when `job_id` is given,
    /// else of the `JOBS_SHOWN` newest jobs (a view that is not per job ignores both,
    /// `DashboardView::per_job`).
    pub async fn dashboard(&self, view: DashboardView, job_id: Option<&str>, limit: u32) -> Result<DashboardTable> {
        let columns = view.columns();
        let limit = if limit == 0 { MAX_ROWS } else { limit.min(MAX_ROWS) };
        let mut query = sqlx::query(sql(self.backend, view.statement())?).bind(i64::from(limit));
        if view.per_job() {
            query = query.bind(job_id.unwrap_or("")).bind(i64::from(JOBS_SHOWN));
        }
        let rows = query.fetch_all(&self.pool).await?;
        let rows = rows.iter().map(|row| row_values(row, columns)).collect::<Result<_>>()?;
        Ok(DashboardTable { view, columns: columns.iter().map(|(name, _)| name.to_string()).collect(), rows })
    }
}

fn row_values(row: &AnyRow, columns: &[(&str, ColumnType)]) -> Result<Vec<Value>> {
    columns
        .iter()
        .map(|(name, ty)| {
            Ok(match ty {
                Text => row.try_get::<Option<String>, _>(*name)?.map(Value::from),
                Integer => row.try_get::<Option<i64>, _>(*name)?.map(Value::from),
                Real => row.try_get::<Option<f64>, _>(*name)?.map(Value::from),
            }
            .unwrap_or(Value::Null))
        })
        .collect()
}
