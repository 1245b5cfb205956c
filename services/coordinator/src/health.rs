//! The standard gRPC health service (`grpc.health.v1.Health`), for Kubernetes' `grpc:` probes
//! and load balancers. Both APIs (`vint.v1.JobService`, `vint.v1.WorkService`) are SERVING while
//! the database answers and NOT_SERVING while it does not: a coordinator holds no state of its
//! own, so the database answering is all its readiness is. The server as a whole (`""`) is
//! SERVING while the process serves gRPC at all — a liveness probe, which a database outage must
//! not turn into restarts of every replica.

use std::time::Duration;

use tonic_health::ServingStatus;
use tonic_health::server::HealthReporter;
use vint_proto::v1::job_service_server::JobServiceServer;
use vint_proto::v1::work_service_server::WorkServiceServer;
use vint_store::Store;

use crate::{JobApi, WorkApi};

/// The services whose health follows the database's.
fn services() -> [&'static str; 2] {
    use tonic::server::NamedService;
    [<JobServiceServer<JobApi> as NamedService>::NAME, <WorkServiceServer<WorkApi> as NamedService>::NAME]
}

/// Asks the database every `every` whether it answers (within `every` itself) and reports it.
pub(crate) async fn report_forever(store: Store, reporter: HealthReporter, every: Duration) {
    let mut tick = tokio::time::interval(every);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut last = None;
    loop {
        tick.tick().await;
        let status = match tokio::time::timeout(every, store.ping()).await {
            Ok(Ok(())) => ServingStatus::Serving,
            Ok(Err(e)) => {
                tracing::error!(error = %e, "health: the database does not answer");
                ServingStatus::NotServing
            }
            Err(_) => {
                tracing::error!(timeout_ms = every.as_millis() as u64, "health: the database did not answer in time");
                ServingStatus::NotServing
            }
        };
        if last != Some(status) {
            tracing::info!(?status, "health");
            last = Some(status);
        }
        for service in services() {
            reporter.set_service_status(service, status).await;
        }
    }
}
