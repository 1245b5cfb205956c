//! The web dashboard on the coordinator's HTTP listener (`--http-listen`): one page
//! (`/dashboard`) that reads the store's dashboard views (`vint_store::DashboardView`, the same
//! tables `vintctl dashboard` prints) through a small JSON API and refreshes them every few
//! seconds, with charts drawn here as SVG by plotters. It only reads.
//!
//! ```text
//!  GET /dashboard                     the page (page.html + app.js, compiled in)
//!  GET /dashboard/api/jobs            recent jobs: id, name, state, created_ms, finished_ms
//!  GET /dashboard/api/view/VIEW?job=  a view's columns and rows (of one job, if given)
//!  GET /dashboard/chart/CHART.svg?job= throughput | acceptance | taxels | occlusion
//! ```
//!
//! With a tokens file every route needs a `read` token (a `submit` one will do): `Authorization:
//! Bearer TOKEN`, or HTTP Basic with the token as the password, which is what a browser prompts
//! for on the 401 answer.
//!
//! A view's table is kept for `VIEW_TTL` and shared by every tab and chart that asks for it, so
//! the database answers each (view, job) at most once per period however many pages are open
//! (the page itself refreshes every 2 s, and at most every second whatever `?refresh=` says).

use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use axum::Router;
use axum::extract::{Path, Query, Request, State};
use axum::http::{HeaderValue, StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use base64::Engine;
use plotters::prelude::*;
use serde::Deserialize;
use serde_json::{Value, json};
use vint_store::{DashboardTable, DashboardView, Store};

use crate::auth::{Denied, Role, Tokens};

const PAGE: &str = include_str!("dashboard/page.html");
const SCRIPT: &str = include_str!("dashboard/app.js");
/// Jobs listed on the page, newest first: those the per-job views show when no job is chosen.
const JOBS_LISTED: u32 = vint_store::DASHBOARD_JOBS_SHOWN;
const CHART_SIZE: (u32, u32) = (560, 260);
/// Series colours, by stage for throughput (grasp, render, noise, package) and for bars.
const PALETTE: [RGBColor; 4] =
    [RGBColor(31, 95, 191), RGBColor(47, 125, 79), RGBColor(196, 120, 24), RGBColor(130, 70, 160)];

/// How long a view's table is served from memory before the database is asked again.
const VIEW_TTL: Duration = Duration::from_secs(2);
/// Most (view, job) tables kept; past it the cache starts over.
const VIEW_CACHE_ENTRIES: usize = 512;

/// Tables by view name and the job each was read for (`None`: all jobs), with when.
type ViewCache = HashMap<(&'static str, Option<String>), (Instant, Arc<DashboardTable>)>;

/// The store and the tables recently read from it.
#[derive(Clone)]
struct Views {
    store: Store,
    cache: Arc<Mutex<ViewCache>>,
}

impl Views {
    /// `view` of `job` (all jobs when `None`), from memory when read within `VIEW_TTL`.
    async fn table(&self, view: DashboardView, job: Option<&str>) -> vint_store::Result<Arc<DashboardTable>> {
        let key = (view.name(), job.map(str::to_string));
        if let Some((at, table)) = self.cache.lock().unwrap_or_else(|p| p.into_inner()).get(&key)
            && at.elapsed() < VIEW_TTL
        {
            return Ok(table.clone());
        }
        let table = Arc::new(self.store.dashboard(view, job, 0).await?);
        let mut cache = self.cache.lock().unwrap_or_else(|p| p.into_inner());
        if cache.len() >= VIEW_CACHE_ENTRIES {
            cache.clear();
        }
        cache.insert(key, (Instant::now(), table.clone()));
        Ok(table)
    }
}

/// The dashboard's routes over `store`, each behind a `read` token when there are `tokens`.
pub fn router(store: Store, tokens: Option<Arc<Tokens>>) -> Router {
    Router::new()
        .route("/dashboard", get(page))
        .route("/dashboard/app.js", get(script))
        .route("/dashboard/api/jobs", get(jobs))
        .route("/dashboard/api/view/{view}", get(view))
        .route("/dashboard/chart/{file}", get(chart))
        .with_state(Views { store, cache: Arc::default() })
        .layer(middleware::from_fn_with_state(tokens, require_read))
}

/// Lets a request through if there are no tokens or it carries a token with the `read` role.
async fn require_read(State(tokens): State<Option<Arc<Tokens>>>, request: Request, next: Next) -> Response {
    let Some(tokens) = tokens else { return next.run(request).await };
    let header = request.headers().get(header::AUTHORIZATION).map(as_bearer);
    match tokens.authorize_bearer(header.as_ref(), Role::Read) {
        Ok(_) => next.run(request).await,
        Err(Denied::Unauthenticated(message)) => (
            StatusCode::UNAUTHORIZED,
            [(
                header::WWW_AUTHENTICATE,
                "Basic realm=\"vint dashboard: a read token as the password\", charset=\"UTF-8\"",
            )],
            message,
        )
            .into_response(),
        Err(Denied::PermissionDenied(message)) => (StatusCode::FORBIDDEN, message).into_response(),
    }
}

/// An `Authorization` header as `Bearer TOKEN`: HTTP Basic (any user name, the token as the
/// password) is what a browser sends; anything else is passed on as it is.
fn as_bearer(value: &HeaderValue) -> HeaderValue {
    let basic = value.to_str().ok().and_then(|v| v.split_once(' ')).filter(|(s, _)| s.eq_ignore_ascii_case("basic"));
    let token = basic
        .and_then(|(_, b64)| base64::engine::general_purpose::STANDARD.decode(b64.trim()).ok())
        .and_then(|raw| String::from_utf8(raw).ok())
        .and_then(|pair| pair.split_once(':').map(|(_, token)| token.to_string()));
    match token.and_then(|t| HeaderValue::from_str(&format!("Bearer {t}")).ok()) {
        Some(bearer) => bearer,
        None => value.clone(),
    }
}

#[derive(Deserialize)]
struct JobQuery {
    job: Option<String>,
}

async fn page() -> Response {
    ([(header::CONTENT_TYPE, "text/html; charset=utf-8"), (header::CACHE_CONTROL, "no-store")], PAGE).into_response()
}

async fn script() -> Response {
    ([(header::CONTENT_TYPE, "text/javascript; charset=utf-8"), (header::CACHE_CONTROL, "no-store")], SCRIPT)
        .into_response()
}

async fn jobs(State(views): State<Views>) -> Response {
    match views.store.list_jobs(JOBS_LISTED).await {
        Ok(jobs) => {
            let jobs: Vec<Value> = jobs
                .iter()
                .map(|j| {
                    json!({"id": j.id, "name": j.name, "state": j.state.as_str(),
                           "created_ms": j.created_ms, "finished_ms": j.finished_ms})
                })
                .collect();
            axum::Json(jobs).into_response()
        }
        Err(e) => store_error(&e),
    }
}

async fn view(State(views): State<Views>, Path(name): Path<String>, Query(q): Query<JobQuery>) -> Response {
    let view = match name.parse::<DashboardView>() {
        Ok(v) => v,
        Err(e) => return (StatusCode::NOT_FOUND, e.to_string()).into_response(),
    };
    match views.table(view, q.job.as_deref()).await {
        Ok(table) => axum::Json(table_json(&table)).into_response(),
        Err(e) => store_error(&e),
    }
}

/// A view's table as the page reads it: `{view, columns, rows}`.
fn table_json(table: &DashboardTable) -> Value {
    json!({"view": table.view.name(), "columns": table.columns, "rows": table.rows})
}

fn store_error(e: &vint_store::StoreError) -> Response {
    // The database's own words (hosts, roles, databases) go to the log, not to the page.
    tracing::error!(error = %e, "dashboard query failed");
    (StatusCode::SERVICE_UNAVAILABLE, "the database did not answer; see the coordinator's log").into_response()
}

/// The charts the page draws, each from one view.
#[derive(Clone, Copy, Debug)]
enum Chart {
    Throughput,
    Acceptance,
    Taxels,
    Occlusion,
}

impl Chart {
    fn parse(file: &str) -> Option<Chart> {
        match file.strip_suffix(".svg")? {
            "throughput" => Some(Chart::Throughput),
            "acceptance" => Some(Chart::Acceptance),
            "taxels" => Some(Chart::Taxels),
            "occlusion" => Some(Chart::Occlusion),
            _ => None,
        }
    }

    fn view(self) -> DashboardView {
        match self {
            Chart::Throughput => DashboardView::Throughput,
            Chart::Acceptance => DashboardView::GraspAcceptance,
            Chart::Taxels => DashboardView::ActiveTaxels,
            Chart::Occlusion => DashboardView::Occlusion,
        }
    }
}

async fn chart(State(views): State<Views>, Path(file): Path<String>, Query(q): Query<JobQuery>) -> Response {
    let Some(chart) = Chart::parse(&file) else {
        return (
            StatusCode::NOT_FOUND,
            format!("{file:?} is not a chart (throughput|acceptance|taxels|occlusion .svg)"),
        )
            .into_response();
    };
    let table = match views.table(chart.view(), q.job.as_deref()).await {
        Ok(t) => t,
        Err(e) => return store_error(&e),
    };
    match draw(chart, &table) {
        Ok(svg) => {
            ([(header::CONTENT_TYPE, "image/svg+xml"), (header::CACHE_CONTROL, "no-store")], svg).into_response()
        }
        Err(message) => {
            tracing::error!(chart = ?chart, %message, "drawing a dashboard chart failed");
            (StatusCode::INTERNAL_SERVER_ERROR, message).into_response()
        }
    }
}

/// A column of `table` by name, as numbers (missing or null values as 0).
fn numbers(table: &DashboardTable, column: &str) -> Vec<f64> {
    let Some(i) = table.columns.iter().position(|c| c == column) else { return Vec::new() };
    table.rows.iter().map(|r| r.get(i).and_then(Value::as_f64).unwrap_or(0.0)).collect()
}

/// Columns of `table` joined with `/`, one label per row.
fn labels(table: &DashboardTable, columns: &[&str]) -> Vec<String> {
    let idx: Vec<usize> = columns.iter().filter_map(|c| table.columns.iter().position(|x| x == c)).collect();
    table
        .rows
        .iter()
        .map(|r| {
            idx.iter()
                .map(|&i| r.get(i).and_then(Value::as_str).unwrap_or("").to_string())
                .collect::<Vec<_>>()
                .join("/")
        })
        .collect()
}

fn draw(chart: Chart, table: &DashboardTable) -> Result<String, String> {
    match chart {
        Chart::Throughput => {
            let stages = labels(table, &["stage"]);
            let minutes = numbers(table, "minute_ms");
            let done = numbers(table, "succeeded");
            let first = minutes.iter().copied().fold(f64::INFINITY, f64::min);
            let mut series: BTreeMap<&str, Vec<(f64, f64)>> = BTreeMap::new();
            for ((stage, minute), n) in stages.iter().zip(&minutes).zip(&done) {
                series.entry(stage.as_str()).or_default().push(((minute - first) / 60_000.0, *n));
            }
            lines(&series, "minutes since the first", "tasks ended per minute")
        }
        Chart::Acceptance => {
            bars(&labels(table, &["object", "hand"]), &numbers(table, "acceptance"), "accepted share", Some(1.0))
        }
        Chart::Taxels => bars(
            &labels(table, &["hand", "region"]),
            &numbers(table, "mean_per_grasp"),
            "active taxels per grasp",
            None,
        ),
        Chart::Occlusion => {
            // Every tenth, empty ones too, so the histogram's axis is always 0 to 1.
            let mut views = [0.0; 10];
            for (bin, n) in numbers(table, "bin").into_iter().zip(numbers(table, "views")) {
                views[(bin.max(0.0) as usize).min(9)] += n;
            }
            let names: Vec<String> = (0..10).map(|b| format!("{:.1}", f64::from(b) / 10.0)).collect();
            bars(&names, &views, "views by occluded share (from)", None)
        }
    }
}

fn svg_error<E: std::fmt::Debug>(e: E) -> String {
    format!("drawing the chart: {e:?}")
}

/// Lines, one per series, on a shared x axis.
fn lines(series: &BTreeMap<&str, Vec<(f64, f64)>>, x_desc: &str, y_desc: &str) -> Result<String, String> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, CHART_SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(svg_error)?;
        let points = series.values().flatten();
        let x_max = points.clone().map(|p| p.0).fold(0.0, f64::max).max(1.0);
        let y_max = points.map(|p| p.1).fold(0.0, f64::max).max(1.0) * 1.1;
        let mut chart = ChartBuilder::on(&root)
            .margin(10)
            .x_label_area_size(34)
            .y_label_area_size(46)
            .build_cartesian_2d(0.0..x_max, 0.0..y_max)
            .map_err(svg_error)?;
        chart.configure_mesh().x_desc(x_desc).y_desc(y_desc).draw().map_err(svg_error)?;
        for (i, (stage, points)) in series.iter().enumerate() {
            let color = PALETTE[i % PALETTE.len()];
            chart
                .draw_series(LineSeries::new(points.iter().copied(), color.stroke_width(2)))
                .map_err(svg_error)?
                .label(*stage)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], color.stroke_width(2)));
            chart.draw_series(points.iter().map(|&p| Circle::new(p, 3, color.filled()))).map_err(svg_error)?;
        }
        if !series.is_empty() {
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK.mix(0.3))
                .draw()
                .map_err(svg_error)?;
        }
        root.present().map_err(svg_error)?;
    }
    Ok(svg)
}

/// One bar per label.
fn bars(names: &[String], values: &[f64], y_desc: &str, y_top: Option<f64>) -> Result<String, String> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, CHART_SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(svg_error)?;
        let n = names.len().max(1) as u32;
        let y_max = y_top.unwrap_or_else(|| values.iter().copied().fold(0.0, f64::max).max(1.0) * 1.1);
        let mut chart = ChartBuilder::on(&root)
            .margin(10)
            .x_label_area_size(60)
            .y_label_area_size(46)
            .build_cartesian_2d((0..n).into_segmented(), 0.0..y_max)
            .map_err(svg_error)?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(names.len().max(1))
            .x_label_formatter(&|v| match v {
                SegmentValue::CenterOf(i) => names.get(*i as usize).cloned().unwrap_or_default(),
                _ => String::new(),
            })
            .y_desc(y_desc)
            .draw()
            .map_err(svg_error)?;
        chart
            .draw_series(
                Histogram::vertical(&chart)
                    .style(PALETTE[0].filled())
                    .margin(6)
                    .data(values.iter().enumerate().map(|(i, v)| (i as u32, *v))),
            )
            .map_err(svg_error)?;
        root.present().map_err(svg_error)?;
    }
    Ok(svg)
}
