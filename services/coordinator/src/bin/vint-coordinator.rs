//! `vint-coordinator`: the gRPC coordinator as a standalone server (cluster mode).

use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

use anyhow::{Context, anyhow};
use clap::Parser;
use vint_coordinator::CoordinatorConfig;
use vint_coordinator::auth::Tokens;
use vint_coordinator::tls::TlsIdentity;
use vint_store::{RetryPolicy, Store, StoreError};

#[derive(Parser)]
#[command(
    name = "vint-coordinator",
    version,
    about = "vint coordinator: schedules grasp, render, noise and package tasks over gRPC"
)]
struct Args {
    /// Database URL: postgres://… (cluster) or sqlite://… (single machine).
    #[arg(long, env = "VINT_DATABASE_URL", hide_env_values = true)]
    database: String,
    /// Address to listen on. Without --auth-tokens only a loopback address is accepted (see
    /// --insecure-listen-any).
    #[arg(long, env = "VINT_LISTEN", default_value = "127.0.0.1:7700")]
    listen: SocketAddr,
    /// Address to serve HTTP on: Prometheus metrics at /metrics, a health check at /healthz
    /// (200 while the database answers). Off when not given.
    #[arg(long, env = "VINT_HTTP_LISTEN")]
    http_listen: Option<SocketAddr>,
    /// Tokens file: one `ROLE TOKEN [NAME]` per line, ROLE one of submit, worker, read
    /// (docs/security.md). Every call must then carry a token whose role allows it; a worker
    /// token's workers act under its NAME.
    #[arg(long, env = "VINT_AUTH_TOKENS", hide_env_values = true)]
    auth_tokens: Option<PathBuf>,
    /// Listen on a non-loopback address without --auth-tokens: anyone who reaches the port may
    /// submit, cancel and report tasks.
    #[arg(long, env = "VINT_INSECURE_LISTEN_ANY")]
    insecure_listen_any: bool,
    /// TLS certificate chain (PEM) for gRPC and the --http-listen listener (HTTPS); needs --tls-key.
    #[arg(long, env = "VINT_TLS_CERT", requires = "tls_key")]
    tls_cert: Option<PathBuf>,
    /// TLS private key (PEM) of --tls-cert.
    #[arg(long, env = "VINT_TLS_KEY", requires = "tls_cert")]
    tls_key: Option<PathBuf>,
    /// Artifact store the workers use (file:///… or s3://…): where the user files of submitted
    /// specs are stored. Without it, specs that name files of their own are refused.
    #[arg(long, env = "VINT_STORE", hide_env_values = true)]
    store: Option<String>,
    /// What one job may ask for (a submission over a limit is refused, naming the flag).
    #[command(flatten)]
    limits: vint_coordinator::LimitFlags,
    /// Most leases the workers of one token may hold at once (with --auth-tokens): a leaked
    /// worker token cannot sit on more of the queue than this.
    #[arg(long, env = "VINT_MAX_LEASES_PER_TOKEN", default_value_t = 10_000)]
    max_leases_per_token: u64,
    /// Most running jobs one token may have submitted (with --auth-tokens): a submission past it
    /// is refused until one ends (a resubmission of a job it has is always answered).
    #[arg(long, env = "VINT_MAX_JOBS_PER_TOKEN", default_value_t = 100)]
    max_jobs_per_token: u64,
    /// Most gRPC connections open at once; one past it is closed at once, and one silent for 10 s
    /// after connecting is closed then (each worker or client process holds one connection).
    #[arg(long, env = "VINT_MAX_CONNECTIONS", default_value_t = 4_096)]
    max_connections: usize,
    /// Most connections this coordinator opens to Postgres (SQLite: one). Size the server's
    /// `max_connections` for every replica's pool plus the migration job and administration.
    #[arg(long, env = "VINT_DATABASE_POOL", default_value_t = vint_store::DEFAULT_POSTGRES_POOL,
          value_parser = clap::value_parser!(u32).range(1..=1_024))]
    database_pool: u32,
    /// Default lease length in milliseconds.
    #[arg(long, env = "VINT_LEASE_MS", default_value_t = 30_000)]
    lease_ms: i64,
    /// Attempts per task before it fails permanently.
    #[arg(long, env = "VINT_MAX_ATTEMPTS", default_value_t = 4)]
    max_attempts: u32,
    /// Base of the exponential retry backoff, in milliseconds.
    #[arg(long, env = "VINT_BACKOFF_MS", default_value_t = 1_000)]
    backoff_ms: i64,
    /// Log as JSON lines.
    #[arg(long, env = "VINT_LOG_JSON")]
    log_json: bool,
    /// Apply the database migrations and exit (a Kubernetes Job or init container whose role may
    /// change the schema). Without it or --no-migrate, the coordinator migrates at start.
    /// (Not clap's `conflicts_with`: it counts a variable set to false as given.)
    #[arg(long, env = "VINT_MIGRATE_ONLY")]
    migrate_only: bool,
    /// Never change the schema (replicas whose role has no DDL rights): refuse to start, exit
    /// code 2, while the database lacks any of this binary's migrations.
    #[arg(long, env = "VINT_NO_MIGRATE")]
    no_migrate: bool,
}

/// Bad input (flags, tokens file, TLS files): the message and exit code 2.
struct BadInput(anyhow::Error);

fn main() -> ExitCode {
    let args = Args::parse();
    vint_telemetry::init_tracing(args.log_json);
    let security = match Security::from_args(&args) {
        Ok(security) => security,
        Err(BadInput(e)) => {
            eprintln!("error: {e:#}");
            return ExitCode::from(2);
        }
    };
    let runtime = match tokio::runtime::Builder::new_multi_thread().enable_all().build() {
        Ok(runtime) => runtime,
        Err(e) => {
            eprintln!("error: cannot start the async runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    match runtime.block_on(run(args, security)) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// Who may call and how the wire is protected, checked before anything is opened.
struct Security {
    tokens: Option<Arc<Tokens>>,
    tls: Option<TlsIdentity>,
    /// The same certificate and key for the HTTP listener (HTTPS).
    http_tls: Option<Arc<vint_telemetry::TlsServerConfig>>,
}

impl Security {
    fn from_args(args: &Args) -> Result<Security, BadInput> {
        if args.migrate_only && args.no_migrate {
            return Err(BadInput(anyhow!(
                "--migrate-only and --no-migrate (or VINT_MIGRATE_ONLY and VINT_NO_MIGRATE) are both true: \
                 migrate and exit, or never migrate, not both"
            )));
        }
        let tokens = match &args.auth_tokens {
            Some(path) => Some(Arc::new(Tokens::load(path).map_err(|e| BadInput(e.into()))?)),
            None => None,
        };
        if tokens.is_none() && !args.listen.ip().is_loopback() && !args.insecure_listen_any {
            return Err(BadInput(anyhow!(
                "--listen {}: without --auth-tokens the coordinator listens on loopback only (127.0.0.1 or ::1), \
                 as anyone who reaches the port could submit, cancel and report tasks. Pass --auth-tokens FILE \
                 (docs/security.md), or --insecure-listen-any on a network you trust",
                args.listen
            )));
        }
        if let Some(http) = args.http_listen.filter(|a| !a.ip().is_loopback())
            && tokens.is_none()
            && !args.insecure_listen_any
        {
            return Err(BadInput(anyhow!(
                "--http-listen {http}: without --auth-tokens the dashboard (every job's progress, failures and \
                 workers) is served on loopback only. Pass --auth-tokens FILE, or --insecure-listen-any on a network \
                 you trust"
            )));
        }
        let (tls, http_tls) = match (&args.tls_cert, &args.tls_key) {
            (Some(cert), Some(key)) => (
                Some(TlsIdentity::load(cert, key).map_err(|e| BadInput(e.into()))?),
                Some(
                    vint_telemetry::tls_server_config(cert, key)
                        .map_err(|e| BadInput(anyhow!("--tls-cert/--tls-key: {e}")))?,
                ),
            ),
            _ => (None, None),
        };
        Ok(Security { tokens, tls, http_tls })
    }
}

async fn run(args: Args, security: Security) -> anyhow::Result<()> {
    let retry =
        RetryPolicy { max_attempts: args.max_attempts, backoff_base_ms: args.backoff_ms, ..RetryPolicy::default() };
    let database = vint_telemetry::redact_url(&args.database);
    let store = Store::connect_with_pool(&args.database, retry, args.database_pool)
        .await
        .with_context(|| format!("opening database {database}"))?;
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
    tracing::info!(%addr, backend = ?store.backend(), auth = security.tokens.is_some(), tls = security.tls.is_some(),
        "coordinator listening");
    if !addr.ip().is_loopback() {
        if security.tokens.is_none() {
            tracing::warn!(%addr, "listening beyond loopback with no tokens (--insecure-listen-any): every call is allowed");
        } else if security.tls.is_none() {
            tracing::warn!(%addr, "listening beyond loopback without TLS: tokens cross the network in clear text");
        }
    }
    println!("listening on {addr}");
    let artifacts = match &args.store {
        Some(url) => Some(
            vint_artifacts::ArtifactStore::open(url)
                .with_context(|| format!("opening store {}", vint_telemetry::redact_url(url)))?,
        ),
        None => None,
    };
    let config = CoordinatorConfig {
        default_lease_ms: args.lease_ms,
        limits: args.limits.limits(),
        max_leases_per_token: args.max_leases_per_token,
        max_jobs_per_token: args.max_jobs_per_token,
        max_connections: args.max_connections,
        artifacts,
        tokens: security.tokens,
        tls: security.tls,
        ..CoordinatorConfig::default()
    };
    // One signal stops both listeners.
    let (stop_tx, stop) = tokio::sync::watch::channel(false);
    tokio::spawn(async move {
        shutdown_signal().await;
        let _ = stop_tx.send(true);
    });
    let stopped = |mut stop: tokio::sync::watch::Receiver<bool>| async move {
        let _ = stop.wait_for(|s| *s).await;
    };
    let http = match args.http_listen {
        Some(addr) => {
            let (listener, addr) =
                vint_coordinator::bind(addr).await.with_context(|| format!("binding --http-listen {addr}"))?;
            let router = vint_coordinator::http_router(store.clone(), &config);
            Some(match security.http_tls {
                Some(tls) => {
                    tracing::info!(%addr, "serving /metrics, /healthz and /dashboard over HTTPS");
                    tokio::spawn(vint_telemetry::serve_https(listener, router, tls, stopped(stop.clone())))
                }
                None => {
                    tracing::info!(%addr, "serving /metrics, /healthz and /dashboard");
                    tokio::spawn(vint_telemetry::serve_http(listener, router, stopped(stop.clone())))
                }
            })
        }
        None => None,
    };
    vint_coordinator::serve(store.clone(), config, listener, stopped(stop)).await?;
    if let Some(http) = http {
        http.abort();
    }
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

#[cfg(test)]
mod tests {
    use clap::{CommandFactory, Parser};

    use super::Args;

    #[test]
    fn a_switch_set_false_in_the_environment_is_off_and_conflicts_with_nothing() {
        let parsed = temp_env(&[("VINT_MIGRATE_ONLY", "false"), ("VINT_NO_MIGRATE", "true")], || {
            Args::try_parse_from(["vint-coordinator", "--database", "sqlite://x.db"])
        });
        let args = parsed.expect("parses");
        assert!(!args.migrate_only && args.no_migrate);
        let both = temp_env(&[("VINT_MIGRATE_ONLY", "true"), ("VINT_NO_MIGRATE", "true")], || {
            Args::try_parse_from(["vint-coordinator", "--database", "sqlite://x.db"])
        });
        let err = super::Security::from_args(&both.expect("parses")).err().expect("refused");
        assert!(err.0.to_string().contains("both true"), "{}", err.0);
    }

    /// Runs `f` with the variables set, then removes them.
    fn temp_env<T>(vars: &[(&str, &str)], f: impl FnOnce() -> T) -> T {
        for (k, v) in vars {
            // SAFETY: tests of this binary that read the environment run in this one function.
            unsafe { std::env::set_var(k, v) };
        }
        let out = f();
        for (k, _) in vars {
            // SAFETY: as above.
            unsafe { std::env::remove_var(k) };
        }
        out
    }

    /// A deployment configures a process through its environment (a ConfigMap, a Secret): every
    /// flag has a `VINT_*` variable.
    #[test]
    fn every_flag_has_an_environment_variable() {
        let command = Args::command();
        let missing: Vec<String> = command
            .get_arguments()
            .filter(|a| a.get_long().is_some_and(|l| l != "help" && l != "version"))
            .filter(|a| !a.get_env().is_some_and(|e| e.to_string_lossy().starts_with("VINT_")))
            .map(|a| format!("--{}", a.get_long().unwrap_or_default()))
            .collect();
        assert!(missing.is_empty(), "flags without a VINT_* environment variable: {missing:?}");
    }
}
