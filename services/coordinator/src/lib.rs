//! The coordinator: vint's gRPC front over the store. It plans jobs, hands tasks to workers,
//! fences their completions, reaps expired leases and answers progress and lineage queries.
//!
//! It holds no state that is not in the database: kill it at any moment, start it again (or run
//! several behind a load balancer on Postgres) and nothing is lost. It never runs an engine and
//! never reads artifact contents; workers move the bytes, the coordinator records their hashes.
//! The one set of bytes it writes is a submission's user files (a spec's own hands and objects),
//! which it stores content-addressed where the workers read artifacts.
//!
//! What it does is counted in `Metrics` (`metrics.rs`); `http_router` serves them at `/metrics`,
//! with `/healthz`, when the binary is given `--http-listen`.
//!
//! With a tokens file every call is checked against the role table in `auth`; with a certificate
//! and key both services speak TLS (`tls`).

pub mod auth;
mod convert;
mod dashboard;
pub mod forecast;
mod health;
mod http;
mod jobs_api;
mod limit_flags;
mod metrics;
mod planner;
mod reuse;
mod shared_progress;
pub mod tls;

pub use limit_flags::LimitFlags;
mod listener;
mod work_api;

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use tokio::net::TcpListener;
use tonic::transport::server::TcpIncoming;
use vint_proto::v1::job_service_server::JobServiceServer;
use vint_proto::v1::work_service_server::WorkServiceServer;
use vint_store::Store;

pub use http::router as http_router;
pub use jobs_api::JobApi;
pub use metrics::Metrics;
pub use work_api::WorkApi;

/// Tunables of one coordinator process.
#[derive(Clone, Debug)]
pub struct CoordinatorConfig {
    /// Lease length when a worker does not ask for one.
    pub default_lease_ms: i64,
    /// How often expired leases are reaped and finished jobs finalized.
    pub reap_interval: Duration,
    /// How often WatchJob polls the store.
    pub watch_interval: Duration,
    /// Where submitted user files go (the workers' artifact store); `None` refuses specs that
    /// name any.
    pub artifacts: Option<vint_artifacts::ArtifactStore>,
    /// Where the services record what they do (`http_router` exports it).
    pub metrics: Metrics,
    /// Bearer tokens and their roles; `None` checks nothing (a loopback-only coordinator).
    pub tokens: Option<Arc<auth::Tokens>>,
    /// Certificate and key to serve TLS with; `None` serves plain HTTP/2.
    pub tls: Option<tls::TlsIdentity>,
    /// After shutdown is asked for, how long RPCs in flight may take to finish (a `WatchJob`
    /// stream never does) before the server closes anyway.
    pub shutdown_grace: Duration,
    /// How often the gRPC health service asks the database whether it answers.
    pub health_interval: Duration,
    /// What one job may ask for; a submission over any limit is refused before it is planned.
    pub limits: vint_core::limits::Limits,
    /// Most leases the workers of one token may hold at once (with a tokens file).
    pub max_leases_per_token: u64,
    /// Most running jobs one token may have submitted (with a tokens file).
    pub max_jobs_per_token: u64,
    /// Most gRPC connections open at once (`listener.rs`): one worker or client process holds one.
    pub max_connections: usize,
}

impl Default for CoordinatorConfig {
    fn default() -> Self {
        CoordinatorConfig {
            default_lease_ms: 30_000,
            reap_interval: Duration::from_millis(500),
            watch_interval: Duration::from_millis(250),
            artifacts: None,
            metrics: Metrics::default(),
            tokens: None,
            tls: None,
            shutdown_grace: Duration::from_secs(10),
            health_interval: Duration::from_secs(5),
            limits: vint_core::limits::Limits::default(),
            max_leases_per_token: 10_000,
            max_jobs_per_token: 100,
            max_connections: 4_096,
        }
    }
}

/// Milliseconds since the Unix epoch: the only clock the coordinator reads.
pub fn now_ms() -> i64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map(|d| d.as_millis() as i64).unwrap_or(0)
}

/// Most calls one gRPC connection carries at once (a worker process runs a few loops, each with
/// a lease, a completion and a heartbeat in flight).
const GRPC_STREAMS_PER_CONNECTION: u32 = 256;

/// Largest gRPC message accepted (a spec is at most 1 MiB; completions list a few hundred files).
const MAX_MESSAGE_BYTES: usize = 8 << 20;
/// Largest job submission: a spec and its user files.
const MAX_SUBMIT_BYTES: usize = vint_core::asset::MAX_ASSETS_TOTAL_BYTES as usize + (2 << 20);

/// Serves both APIs and `grpc.health.v1.Health` on `listener` until `shutdown` resolves, with the
/// lease reaper running. Then it stops accepting connections, lets the RPCs in flight finish
/// for at most `config.shutdown_grace`, and stops the reaper and the health checks.
pub async fn serve(
    store: Store,
    config: CoordinatorConfig,
    listener: TcpListener,
    shutdown: impl std::future::Future<Output = ()> + Send + 'static,
) -> Result<(), tonic::transport::Error> {
    // Pings find connections whose peer went away; a connection carries at most
    // GRPC_STREAMS_PER_CONNECTION calls at once.
    let mut server = tonic::transport::Server::builder()
        .http2_keepalive_interval(Some(Duration::from_secs(30)))
        .http2_keepalive_timeout(Some(Duration::from_secs(10)))
        .max_concurrent_streams(GRPC_STREAMS_PER_CONNECTION);
    if let Some(identity) = &config.tls {
        server = server.tls_config(identity.server_config())?;
    }
    let auth = auth::AuthLayer::new(config.tokens.clone());
    let reaper = tokio::spawn(reap_forever(store.clone(), config.reap_interval, config.metrics.clone()));
    let (health_reporter, health) = tonic_health::server::health_reporter();
    let health_checks = tokio::spawn(health::report_forever(store.clone(), health_reporter, config.health_interval));
    let (asked_tx, asked) = tokio::sync::oneshot::channel::<()>();
    let shutdown = async move {
        shutdown.await;
        let _ = asked_tx.send(());
    };
    let grace = config.shutdown_grace;
    let max_connections = config.max_connections;
    let jobs =
        JobServiceServer::new(JobApi::new(store.clone(), config.clone())).max_decoding_message_size(MAX_SUBMIT_BYTES);
    let work = WorkServiceServer::new(WorkApi::new(store, config)).max_decoding_message_size(MAX_MESSAGE_BYTES);
    // Small request/response pairs: without TCP_NODELAY each reply waits ~40 ms for a delayed ACK
    // (tonic applies its nodelay default only to listeners it binds itself).
    let incoming = listener::capped(
        TcpIncoming::from(listener).with_nodelay(Some(true)),
        max_connections,
        listener::FIRST_BYTES_TIMEOUT,
    );
    let server = server
        .layer(auth)
        .add_service(health)
        .add_service(jobs)
        .add_service(work)
        .serve_with_incoming_shutdown(incoming, shutdown);
    let result = tokio::select! {
        result = server => result,
        () = async {
            if asked.await.is_ok() {
                tokio::time::sleep(grace).await;
            } else {
                std::future::pending::<()>().await;
            }
        } => {
            tracing::warn!(grace_ms = grace.as_millis() as u64, "RPCs still in flight after the shutdown grace; closing");
            Ok(())
        }
    };
    reaper.abort();
    health_checks.abort();
    result
}

/// Binds `addr` (port 0 picks a free one) and returns the listener with its real address.
pub async fn bind(addr: SocketAddr) -> std::io::Result<(TcpListener, SocketAddr)> {
    let listener = TcpListener::bind(addr).await?;
    let local = listener.local_addr()?;
    Ok((listener, local))
}

/// How often the queue and job gauges are counted again (`Store::queue_depth`).
const QUEUE_DEPTH_EVERY: Duration = Duration::from_secs(5);

/// Since when this coordinator has been able to hear workers' heartbeats: since it started,
/// and again since its database last came back, or last answered only after `DEAF_AFTER` (a
/// database that takes seconds to hand out a connection after a restart holds the workers'
/// heartbeats in the same queue). The reaper passes it to `Store::reap_expired`, which leaves
/// every lease its worker has not yet had a whole lease to renew since then, and does not count
/// the attempts of those that ran out before it.
#[derive(Clone, Copy, Debug)]
struct Hearing {
    since_ms: i64,
    database_down: bool,
}

impl Hearing {
    fn started(now_ms: i64) -> Hearing {
        Hearing { since_ms: now_ms, database_down: false }
    }

    /// Whether the reaper may expire leases now: not while the database is down.
    fn may_reap(&self) -> bool {
        !self.database_down
    }

    /// Records how a store call of the reaper ended at `now_ms` (when it returned) after taking
    /// `took`: a transient failure means the database is down; an answer after it was down, or
    /// one that took `DEAF_AFTER` or more, that it answers again from now.
    fn heard(&mut self, transient_failure: bool, took: Duration, now_ms: i64) {
        if transient_failure {
            self.database_down = true;
        } else if self.database_down || took >= DEAF_AFTER {
            self.database_down = false;
            self.since_ms = now_ms;
            tracing::warn!(
                took_ms = took.as_millis() as u64,
                "the database answers again; leases are reaped again once their workers could renew them"
            );
        }
    }
}

/// A reaper's store call that takes this long means the database was not answering: the workers'
/// heartbeats waited as long.
const DEAF_AFTER: Duration = Duration::from_secs(2);

fn transient<T>(result: &vint_store::Result<T>) -> bool {
    result.as_ref().is_err_and(|e| e.is_transient())
}

async fn reap_forever(store: Store, every: Duration, metrics: Metrics) {
    let mut tick = tokio::time::interval(every);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut depth_counted: Option<Instant> = None;
    let mut hearing = Hearing::started(now_ms());
    loop {
        tick.tick().await;
        let now = now_ms();
        if hearing.may_reap() {
            let called = Instant::now();
            let reaped = store.reap_expired(now, hearing.since_ms).await;
            // When the call ended, not when the tick began: after an outage the pool may take
            // seconds to connect again, and the workers' heartbeats wait in the same queue.
            hearing.heard(transient(&reaped), called.elapsed(), now_ms());
            metrics.set_database_up(hearing.may_reap());
            match reaped {
                Ok(0) => {}
                Ok(n) => {
                    metrics.leases_expired(n);
                    tracing::warn!(tasks = n, "requeued tasks whose lease expired");
                }
                Err(e) => tracing::error!(error = %e, "lease reaper failed"),
            }
        }
        let called = Instant::now();
        let finalized = store.finalize_jobs(now).await;
        hearing.heard(transient(&finalized), called.elapsed(), now_ms());
        metrics.set_database_up(hearing.may_reap());
        if let Err(e) = finalized {
            tracing::error!(error = %e, "finalizing jobs failed");
        }
        match store.refresh_statistics().await {
            Ok(tables) if !tables.is_empty() => tracing::debug!(?tables, "analyzed"),
            Ok(_) => {}
            Err(e) => tracing::error!(error = %e, "refreshing the planner's statistics failed"),
        }
        if depth_counted.is_none_or(|at| at.elapsed() >= QUEUE_DEPTH_EVERY) {
            depth_counted = Some(Instant::now());
            match store.queue_depth().await {
                Ok(depth) => metrics.set_queue_depth(&depth),
                Err(e) => tracing::error!(error = %e, "counting the queue failed"),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::Hearing;

    #[test]
    fn hearing_starts_at_start_and_again_when_the_database_returns_or_answers_late() {
        let prompt = Duration::from_millis(5);
        let mut h = Hearing::started(1_000);
        assert!(h.may_reap());
        h.heard(false, prompt, 2_000);
        assert_eq!(h.since_ms, 1_000, "a prompt answer while up changes nothing");
        h.heard(true, prompt, 3_000);
        assert!(!h.may_reap(), "no reaping while the database is down");
        h.heard(true, prompt, 4_000);
        assert_eq!(h.since_ms, 1_000);
        h.heard(false, prompt, 5_000);
        assert!(h.may_reap());
        assert_eq!(h.since_ms, 5_000, "heard again from the database's return");
        // A call that waited 10 s for a connection, with no error: the heartbeats waited too.
        h.heard(false, Duration::from_secs(10), 16_000);
        assert_eq!(h.since_ms, 16_000, "heard again from the late answer");
    }
}
