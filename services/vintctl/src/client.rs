//! Talking to a coordinator over gRPC: the URL a user gives, the connection (TLS and the bearer
//! token through `vint_connect`), each call's failure as an exit code, and following a job's
//! progress stream. It prints nothing (`report` does).

use std::time::Duration;

use anyhow::anyhow;
use futures::StreamExt;
use tonic::Code;
use vint_connect::{AuthChannel, Remote};
use vint_proto::v1 as pb;
use vint_proto::v1::job_service_client::JobServiceClient;

use crate::report::ProgressView;
use crate::{Failure, bad_input};

/// A connected coordinator.
pub struct Coordinator {
    pub url: String,
    client: JobServiceClient<AuthChannel>,
}

/// The coordinator URL for `raw` as a user wrote it (`--coordinator` or `VINT_COORDINATOR`):
/// `HOST:PORT` gets `http://`; `https://` means TLS (trusting `--tls-ca` or the system's roots);
/// any other scheme is bad input.
pub fn coordinator_url(raw: &str) -> Result<String, Failure> {
    let raw = raw.trim();
    let bad = |rule: &str| bad_input(anyhow!("--coordinator (or VINT_COORDINATOR): {rule}, got {raw:?}"));
    if raw.is_empty() {
        return Err(bad("must be a URL like http://HOST:PORT"));
    }
    let url = match raw.split_once("://") {
        Some((scheme, _)) if scheme.eq_ignore_ascii_case("http") || scheme.eq_ignore_ascii_case("https") => {
            raw.to_string()
        }
        Some(_) => return Err(bad("must be an http:// or https:// URL")),
        None => format!("http://{raw}"),
    };
    match url.parse::<tonic::transport::Uri>() {
        Ok(uri) if uri.host().is_some_and(|h| !h.is_empty()) => Ok(url),
        _ => Err(bad("must be a URL like http://HOST:PORT")),
    }
}

impl Coordinator {
    /// Connects to the coordinator `remote` names (its URL as `coordinator_url` reads it), with
    /// its TLS trust and token. An unreachable one is a failure (exit 1) that says how to get one.
    pub async fn connect(remote: &Remote) -> Result<Coordinator, Failure> {
        let url = coordinator_url(&remote.url)?;
        let remote = Remote { url: url.clone(), ..remote.clone() };
        let endpoint = remote.endpoint().map_err(|e| bad_input(e.into()))?.connect_timeout(Duration::from_secs(5));
        let bearer = remote.bearer().map_err(|e| bad_input(e.into()))?;
        let channel = endpoint.connect().await.map_err(|e| unreachable(&url, &e))?;
        let client = JobServiceClient::with_interceptor(channel, bearer).max_decoding_message_size(64 << 20);
        Ok(Coordinator { url, client })
    }

    pub async fn submit(&mut self, request: pb::SubmitJobRequest) -> Result<pb::SubmitJobResponse, Failure> {
        Ok(self.client.submit_job(request).await.map_err(|s| rpc_failure("submit", s))?.into_inner())
    }

    pub async fn job(&mut self, job_id: &str) -> Result<pb::Job, Failure> {
        let request = pb::GetJobRequest { job_id: job_id.into() };
        Ok(self.client.get_job(request).await.map_err(|s| rpc_failure("job", s))?.into_inner())
    }

    pub async fn dashboard(
        &mut self,
        view: &str,
        job_id: Option<&str>,
        limit: u32,
    ) -> Result<pb::DashboardTable, Failure> {
        let request = pb::QueryDashboardRequest { view: view.into(), job_id: job_id.unwrap_or_default().into(), limit };
        Ok(self.client.query_dashboard(request).await.map_err(|s| rpc_failure("dashboard", s))?.into_inner())
    }

    pub async fn jobs(&mut self, limit: u32) -> Result<Vec<pb::Job>, Failure> {
        let request = pb::ListJobsRequest { limit };
        Ok(self.client.list_jobs(request).await.map_err(|s| rpc_failure("jobs", s))?.into_inner().jobs)
    }

    pub async fn cancel(&mut self, job_id: &str) -> Result<pb::Job, Failure> {
        let request = pb::CancelJobRequest { job_id: job_id.into() };
        Ok(self.client.cancel_job(request).await.map_err(|s| rpc_failure("cancel", s))?.into_inner())
    }

    pub async fn lineage(&mut self, request: pb::GetLineageRequest) -> Result<pb::Lineage, Failure> {
        Ok(self.client.get_lineage(request).await.map_err(|s| rpc_failure("lineage", s))?.into_inner())
    }

    /// A job's packaged samples with their files: every page of `ListSamples`, in one answer.
    pub async fn samples(&mut self, job_id: &str) -> Result<pb::ListSamplesResponse, Failure> {
        let mut all = pb::ListSamplesResponse::default();
        let mut token = String::new();
        loop {
            let request = pb::ListSamplesRequest { job_id: job_id.into(), page_token: token.clone(), page_size: 0 };
            let page =
                self.client.list_samples(request).await.map_err(|s| rpc_failure("listing samples", s))?.into_inner();
            if token.is_empty() {
                all.models = page.models;
                all.pairs = page.pairs;
            }
            all.samples.extend(page.samples);
            all.grasps.extend(page.grasps);
            if page.next_page_token.is_empty() {
                return Ok(all);
            }
            if page.next_page_token <= token {
                return Err(Failure {
                    code: 1,
                    error: anyhow!(
                        "listing samples: the coordinator's pages went backwards ({:?} after {token:?})",
                        page.next_page_token
                    ),
                });
            }
            token = page.next_page_token;
        }
    }

    pub async fn server_info(&mut self) -> Result<pb::ServerInfo, Failure> {
        let request = pb::GetServerInfoRequest {};
        Ok(self.client.get_server_info(request).await.map_err(|s| rpc_failure("server info", s))?.into_inner())
    }

    /// Follows a job's progress until it reaches a final state, showing each update on `view`;
    /// returns the last one.
    pub async fn follow(&mut self, job_id: &str, view: &ProgressView) -> Result<pb::JobProgress, Failure> {
        let request = pb::WatchJobRequest { job_id: job_id.into() };
        let mut stream = self.client.watch_job(request).await.map_err(|s| rpc_failure("watch", s))?.into_inner();
        let mut last = None;
        while let Some(update) = stream.next().await {
            let p = update.map_err(|s| rpc_failure("watch", s))?;
            view.show(&p);
            last = Some(p);
        }
        let last = last.ok_or_else(|| anyhow!("the coordinator closed the watch without any progress"))?;
        view.finish(&last);
        Ok(last)
    }
}

/// A call's failure: "not found" and "invalid argument" are the user's (exit 2), the rest exit 1.
/// A refused token says which flag carries one.
pub fn rpc_failure(what: &str, s: tonic::Status) -> Failure {
    let error = match s.code() {
        Code::Unauthenticated => {
            anyhow!(
                "{what}: the coordinator refused the call ({}); pass a token with --token or VINT_TOKEN",
                s.message()
            )
        }
        Code::PermissionDenied => anyhow!("{what}: the coordinator refused the call: {}", s.message()),
        _ => anyhow!("{what}: {}", s.message()),
    };
    match s.code() {
        Code::NotFound | Code::InvalidArgument => bad_input(error),
        _ => Failure { code: 1, error },
    }
}

/// No coordinator answered at `url`: say what was tried, why it failed (once) and what to do.
fn unreachable(url: &str, e: &tonic::transport::Error) -> Failure {
    let mut cause: &dyn std::error::Error = e;
    while let Some(source) = cause.source() {
        cause = source;
    }
    let why = match cause.downcast_ref::<std::io::Error>().map(std::io::Error::kind) {
        Some(std::io::ErrorKind::ConnectionRefused) => "connection refused".to_string(),
        Some(std::io::ErrorKind::TimedOut) => "timed out".to_string(),
        _ => cause.to_string(),
    };
    Failure {
        code: 1,
        error: anyhow!(
            "no coordinator answers at {url} ({why}). This command needs a running coordinator:\n  \
             - start one: vint-coordinator --database sqlite:///ABS/PATH/vint.db --store file:///ABS/PATH/objects, \
             and workers (docs/guide.md, \"On a cluster\");\n  \
             - or point vintctl at yours: --coordinator http://HOST:PORT, or VINT_COORDINATOR=http://HOST:PORT;\n  \
             - or make a dataset on this machine with no server: vintctl run SPEC --out DIR"
        ),
    }
}
