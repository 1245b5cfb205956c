//! `vint-coordinator`: the gRPC coordinator as a standalone server (cluster mode).

use std::net::SocketAddr;

use anyhow::Context;
use clap::Parser;
use vint_coordinator::CoordinatorConfig;
use vint_store::{RetryPolicy, Store, StoreError};

#[derive(Parser)]
#[command(version, about = "vint coordinator: schedules grasp, render, noise and package tasks over gRPC")]
struct Args {
    /// Database URL: postgres://… (cluster) or sqlite://… (single machine).
    #[arg(long, env = "VINT_DATABASE_URL")]
    database: String,
    /// Address to listen on.
    #[arg(long, env = "VINT_LISTEN", default_value = "127.0.0.1:7700")]
    listen: SocketAddr,
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
    /// Apply the database migrations and exit (a Kubernetes Job or init container whose role may
    /// change the schema). Without it or --no-migrate, the coordinator migrates at start.
    #[arg(long, conflicts_with = "no_migrate")]
    migrate_only: bool,
    /// Never change the schema (replicas whose role has no DDL rights): refuse to start, exit
    /// code 2, while the database lacks any of this binary's migrations.
    #[arg(long)]
    no_migrate: bool,
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    vint_telemetry::init_tracing(args.log_json);
    let retry =
        RetryPolicy { max_attempts: args.max_attempts, backoff_base_ms: args.backoff_ms, ..RetryPolicy::default() };
    let database = vint_telemetry::redact_url(&args.database);
    let store = Store::connect(&args.database, retry).await.with_context(|| format!("opening database {database}"))?;
    if args.no_migrate {
        match store.require_current_schema().await {
            Err(e @ StoreError::SchemaBehind { .. }) => {
                eprintln!("error: database {database}: {e}");
                std::process::exit(2);
            }
            checked => checked.with_context(|| format!("reading the schema version of {database}"))?,
        }
    } else {
        store.migrate().await.with_context(|| format!("migrating database {database}"))?;
    }
    if args.migrate_only {
        tracing::info!(database = %database, "migrations applied");
        println!("migrated {database}");
        store.close().await;
        return Ok(());
    }
    let (listener, addr) =
        vint_coordinator::bind(args.listen).await.with_context(|| format!("binding {}", args.listen))?;
    tracing::info!(%addr, backend = ?store.backend(), "coordinator listening");
    println!("listening on {addr}");
    let artifacts = match &args.store {
        Some(url) => Some(
            vint_artifacts::ArtifactStore::open(url)
                .with_context(|| format!("opening store {}", vint_telemetry::redact_url(url)))?,
        ),
        None => None,
    };
    let config = CoordinatorConfig { default_lease_ms: args.lease_ms, artifacts, ..CoordinatorConfig::default() };
    vint_coordinator::serve(store.clone(), config, listener, shutdown_signal()).await?;
    store.close().await;
    tracing::info!("coordinator stopped");
    Ok(())
}

/// Resolves on SIGINT or SIGTERM (what Kubernetes sends before SIGKILL).
async fn shutdown_signal() {
    use tokio::signal::unix::{SignalKind, signal};
    match signal(SignalKind::terminate()) {
        Ok(mut term) => tokio::select! {
            _ = tokio::signal::ctrl_c() => {}
            _ = term.recv() => {}
        },
        Err(e) => {
            tracing::warn!(error = %e, "cannot listen for SIGTERM; stopping on Ctrl-C only");
            let _ = tokio::signal::ctrl_c().await;
        }
    }
    tracing::info!("shutting down");
}
