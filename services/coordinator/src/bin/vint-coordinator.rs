//! `vint-coordinator`: the gRPC coordinator as a standalone server (cluster mode).

use std::net::SocketAddr;

use anyhow::Context;
use clap::Parser;
use vint_coordinator::CoordinatorConfig;
use vint_store::{RetryPolicy, Store};

#[derive(Parser)]
#[command(version, about = "vint coordinator: schedules grasp, render, noise and package tasks over gRPC")]
struct Args {
    /// Database URL: postgres://… (cluster) or sqlite://… (single machine).
    #[arg(long, env = "VINT_DATABASE_URL")]
    database: String,
    /// Address to listen on.
    #[arg(long, env = "VINT_LISTEN", default_value = "127.0.0.1:7700")]
    listen: SocketAddr,
    /// Address to serve HTTP on: Prometheus metrics at /metrics, a health check at /healthz
    /// (200 while the database answers). Off when not given.
    #[arg(long, env = "VINT_HTTP_LISTEN")]
    http_listen: Option<SocketAddr>,
    /// Artifact store the workers use (file:///… or s3://…): where the user files of submitted
    /// specs are stored. Without it, specs that name files of their own are refused.
    #[arg(long, env = "VINT_STORE")]
    store: Option<String>,
    /// Default lease length in milliseconds.
    #[arg(long, default_value_t = 30_000)]
    lease_ms: i64,
    /// Attempts per task before it fails permanently.
    #[arg(long, default_value_t = 4)]
    max_attempts: u32,
    /// Base of the exponential retry backoff, in milliseconds.
    #[arg(long, default_value_t = 1_000)]
    backoff_ms: i64,
    /// Log as JSON lines.
    #[arg(long)]
    log_json: bool,
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    vint_telemetry::init_tracing(args.log_json);
    let retry =
        RetryPolicy { max_attempts: args.max_attempts, backoff_base_ms: args.backoff_ms, ..RetryPolicy::default() };
    let store =
        Store::open(&args.database, retry).await.with_context(|| format!("opening database {}", args.database))?;
    let (listener, addr) =
        vint_coordinator::bind(args.listen).await.with_context(|| format!("binding {}", args.listen))?;
    tracing::info!(%addr, backend = ?store.backend(), "coordinator listening");
    println!("listening on {addr}");
    let artifacts = match &args.store {
        Some(url) => Some(vint_artifacts::ArtifactStore::open(url).with_context(|| format!("opening store {url}"))?),
        None => None,
    };
    let config = CoordinatorConfig { default_lease_ms: args.lease_ms, artifacts, ..CoordinatorConfig::default() };
    let http = match args.http_listen {
        Some(addr) => {
            let (listener, addr) =
                vint_coordinator::bind(addr).await.with_context(|| format!("binding --http-listen {addr}"))?;
            tracing::info!(%addr, "serving /metrics and /healthz");
            let router = vint_coordinator::http_router(store.clone(), &config.metrics);
            Some(tokio::spawn(vint_telemetry::serve_http(listener, router, std::future::pending())))
        }
        None => None,
    };
    let shutdown = async {
        let _ = tokio::signal::ctrl_c().await;
        tracing::info!("shutting down");
    };
    vint_coordinator::serve(store, config, listener, shutdown).await?;
    if let Some(http) = http {
        http.abort();
    }
    Ok(())
}
