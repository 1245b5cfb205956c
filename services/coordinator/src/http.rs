//! The coordinator's HTTP side (`--http-listen`): `/metrics` and `/healthz`, on the telemetry
//! crate's router, and the web dashboard (`dashboard.rs`). Healthy means the database answers:
//! the coordinator holds nothing else.

use std::time::Duration;

use vint_store::Store;

use crate::CoordinatorConfig;

/// Longest `/healthz` waits for the database before it answers 503.
const DATABASE_CHECK_TIMEOUT: Duration = Duration::from_secs(2);

/// The coordinator's HTTP routes: `/metrics` and `/healthz` open (Prometheus and the kubelet),
/// `/dashboard` behind a `read` token when `config` has tokens.
pub fn router(store: Store, config: &CoordinatorConfig) -> vint_telemetry::Router {
    vint_telemetry::router(config.metrics.registry(), DatabaseHealth(store.clone()))
        .merge(crate::dashboard::router(store, config.tokens.clone()))
}

/// Healthy while the database answers a trivial query within `DATABASE_CHECK_TIMEOUT`.
#[derive(Clone)]
struct DatabaseHealth(Store);

impl vint_telemetry::HealthCheck for DatabaseHealth {
    async fn check(&self) -> vint_telemetry::Health {
        match tokio::time::timeout(DATABASE_CHECK_TIMEOUT, self.0.ping()).await {
            Ok(Ok(())) => Ok(()),
            // The details go to the log, not to an unauthenticated caller.
            Ok(Err(e)) => {
                tracing::warn!(error = %e, "health check: the database does not answer");
                Err("the database does not answer (the coordinator's log says why)".to_string())
            }
            Err(_) => Err(format!("the database did not answer within {DATABASE_CHECK_TIMEOUT:?}")),
        }
    }
}
