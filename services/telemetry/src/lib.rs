//! How vint's processes report on themselves: logging (tracing) set-up shared by the coordinator,
//! the workers and the CLI, and the HTTP side every long-running process can open — Prometheus
//! metrics at `/metrics` and a health check at `/healthz` (`http`).
//!
//! This crate owns the mechanics only: the exposition format, the routes and the server. What is
//! measured belongs to the process that measures it (`vint_coordinator::Metrics`,
//! `vint_runtime::metrics::WorkerMetrics`); every metric is named `vint_*` (docs/operations.md).

pub mod http;

pub use axum::Router;
pub use http::{
    Health, HealthCheck, ListenerLimits, Liveness, OPENMETRICS_CONTENT_TYPE, router, serve, serve_http, serve_https,
    tls_server_config,
};
/// The TLS configuration of an HTTPS listener (`tls_server_config`, `serve_https`).
pub use rustls::ServerConfig as TlsServerConfig;

/// Logs to stderr, filtered by `RUST_LOG` (default `info`), as text or JSON lines.
pub fn init_tracing(json: bool) {
    use tracing_subscriber::EnvFilter;
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("info"));
    let builder = tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr);
    let _ = if json { builder.json().try_init() } else { builder.try_init() };
}

/// Histogram buckets for a request round trip: 1 ms to 2 s, doubling (12 buckets).
pub fn rpc_seconds_buckets() -> impl Iterator<Item = f64> {
    prometheus_client::metrics::histogram::exponential_buckets(0.001, 2.0, 12)
}

/// Histogram buckets for work on a task (an engine run, a fetch, an upload): 10 ms to ~45 min,
/// doubling (19 buckets), so a 30-minute render and a 20 ms noise task both land in a bucket.
pub fn task_seconds_buckets() -> impl Iterator<Item = f64> {
    prometheus_client::metrics::histogram::exponential_buckets(0.01, 2.0, 19)
}

/// Registers `vint_build_info{component, version} 1`: which build of which process answers, so a
/// dashboard or an alert can tell a rollout's old replicas from its new ones.
pub fn register_build_info(registry: &mut prometheus_client::registry::Registry, component: &str, version: &str) {
    let labels = vec![("component".to_string(), component.to_string()), ("version".to_string(), version.to_string())];
    registry.register(
        "vint_build",
        "The build of this process: its component and version",
        prometheus_client::metrics::info::Info::new(labels),
    );
}

mod redact;
pub use redact::{REDACTED, redact_url};
