//! The coordinator's HTTP side (`--http-listen`): `/metrics` and `/healthz`, on the telemetry
//! crate's router. Healthy means the database answers: the coordinator holds nothing else.

use std::time::Duration;

use vint_store::Store;

use crate::Metrics;

/// Longest `/healthz` waits for the database before it answers 503.
const DATABASE_CHECK_TIMEOUT: Duration = Duration::from_secs(2);

/// The coordinator's HTTP routes.
pub fn router(store: Store, metrics: &Metrics) -> vint_telemetry::Router {
    vint_telemetry::router(metrics.registry(), DatabaseHealth(store))
}

/// Healthy while the database answers a trivial query within `DATABASE_CHECK_TIMEOUT`.
#[derive(Clone)]
struct DatabaseHealth(Store);

impl vint_telemetry::HealthCheck for DatabaseHealth {
    async fn check(&self) -> vint_telemetry::Health {
        match tokio::time::timeout(DATABASE_CHECK_TIMEOUT, self.0.ping()).await {
            Ok(Ok(())) => Ok(()),
            Ok(Err(e)) => Err(format!("the database does not answer: {e}")),
            Err(_) => Err(format!("the database did not answer within {DATABASE_CHECK_TIMEOUT:?}")),
        }
    }
}
