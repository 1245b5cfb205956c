//! Who may call what, as an operator deploys it: `vint-coordinator --auth-tokens FILE` (over
//! SQLite), every RPC of both services called with no token, an unknown token and a token of each
//! role; `vintctl` and `vint-worker` with their tokens; the loopback rule; TLS with a private CA.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use tonic::Code;
use tonic::metadata::AsciiMetadataValue;
use tonic::transport::Channel;
use vint_proto::v1 as pb;
use vint_proto::v1::job_service_client::JobServiceClient;
use vint_proto::v1::work_service_client::WorkServiceClient;
use vint_tests::*;

const SUBMIT: &str = "submit-7f3c9a2e5b1d4c68";
const WORKER: &str = "worker-2b8e6d1f9a3c5e70";
const READ: &str = "read-5d1a7c3e9b2f4a86";
const UNKNOWN: &str = "nobody-0a1b2c3d4e5f6a7b";

/// The specification this test holds the coordinator to: each RPC and the roles that may call it.
/// `submit` may do what `read` may (a submitter watches its jobs); nothing else implies anything.
const ALLOWED: &[(&str, &[&str])] = &[
    ("/vint.v1.JobService/SubmitJob", &["submit"]),
    ("/vint.v1.JobService/CancelJob", &["submit"]),
    ("/vint.v1.JobService/GetJob", &["submit", "read"]),
    ("/vint.v1.JobService/ListJobs", &["submit", "read"]),
    ("/vint.v1.JobService/WatchJob", &["submit", "read"]),
    ("/vint.v1.JobService/GetLineage", &["submit", "read"]),
    ("/vint.v1.JobService/ListSamples", &["submit", "read"]),
    ("/vint.v1.JobService/GetServerInfo", &["submit", "read"]),
    ("/vint.v1.JobService/QueryDashboard", &["submit", "read"]),
    ("/vint.v1.WorkService/LeaseTasks", &["worker"]),
    ("/vint.v1.WorkService/Heartbeat", &["worker"]),
    ("/vint.v1.WorkService/CompleteTask", &["worker"]),
    ("/vint.v1.WorkService/CompleteTasks", &["worker"]),
    ("/vint.v1.WorkService/ReleaseTasks", &["worker"]),
    ("/vint.v1.WorkService/FailTask", &["worker"]),
];

fn write_tokens(dir: &Path) -> PathBuf {
    let path = dir.join("tokens");
    std::fs::write(&path, format!("# vint tokens\nsubmit {SUBMIT}\nworker {WORKER}\n\nread {READ}\n")).unwrap();
    path
}

/// `vint-coordinator` over a fresh SQLite database with `extra` flags, listening on `port` (on
/// `host`, which the readiness check dials as 127.0.0.1).
fn coordinator(dir: &Path, port: u16, host: &str, extra: &[&str]) -> Proc {
    let database = format!("sqlite://{}?mode=rwc", dir.join(format!("vint-{port}.db")).display());
    let log = std::fs::File::create(dir.join(format!("coordinator-{port}.log"))).unwrap();
    let child = Command::new(bin("vint-coordinator"))
        .args(["--database", &database, "--listen", &format!("{host}:{port}")])
        .args(extra)
        .stdout(Stdio::null())
        .stderr(Stdio::from(log))
        .spawn()
        .expect("start vint-coordinator");
    let mut proc = Proc { child, name: format!("coordinator-{port}") };
    let deadline = Instant::now() + Duration::from_secs(30);
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        if let Ok(Some(status)) = proc.child.try_wait() {
            let log = std::fs::read_to_string(dir.join(format!("coordinator-{port}.log"))).unwrap_or_default();
            panic!("vint-coordinator exited ({status}) instead of listening:\n{log}");
        }
        assert!(Instant::now() < deadline, "vint-coordinator did not start listening on {port}");
        std::thread::sleep(Duration::from_millis(50));
    }
    proc.name = format!("coordinator on {host}:{port}");
    proc
}

/// Runs `vint-coordinator` with `args` expecting it to refuse to start; its exit code and stderr.
fn coordinator_refusal(args: &[&str]) -> (Option<i32>, String) {
    let mut child = Command::new(bin("vint-coordinator"))
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start vint-coordinator");
    let deadline = Instant::now() + Duration::from_secs(20);
    while child.try_wait().unwrap().is_none() {
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!("vint-coordinator {args:?} kept running; it should have refused to start");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let output = child.wait_with_output().unwrap();
    (output.status.code(), stderr(&output))
}

/// Calls `rpc` (a gRPC path) with an empty request and `token`; the status code it got (`Ok` if
/// it succeeded). Past authorization an empty request may fail for its own reasons.
async fn call(channel: Channel, token: Option<&str>, rpc: &str) -> Code {
    let header: Option<AsciiMetadataValue> = token.map(|t| format!("Bearer {t}").parse().unwrap());
    let with_token = move |mut request: tonic::Request<()>| {
        if let Some(h) = &header {
            request.metadata_mut().insert("authorization", h.clone());
        }
        Ok(request)
    };
    let mut jobs = JobServiceClient::with_interceptor(channel.clone(), with_token.clone());
    let mut work = WorkServiceClient::with_interceptor(channel, with_token);
    let method = rpc.rsplit('/').next().unwrap();
    let result = match method {
        "SubmitJob" => jobs.submit_job(pb::SubmitJobRequest::default()).await.map(drop),
        "CancelJob" => jobs.cancel_job(pb::CancelJobRequest::default()).await.map(drop),
        "GetJob" => jobs.get_job(pb::GetJobRequest::default()).await.map(drop),
        "ListJobs" => jobs.list_jobs(pb::ListJobsRequest::default()).await.map(drop),
        "WatchJob" => match jobs.watch_job(pb::WatchJobRequest::default()).await {
            // Refused or not, the answer comes with the stream's first message.
            Ok(mut stream) => match tokio::time::timeout(Duration::from_secs(5), stream.get_mut().message()).await {
                Ok(message) => message.map(drop),
                Err(_) => Ok(()),
            },
            Err(status) => Err(status),
        },
        "GetLineage" => jobs.get_lineage(pb::GetLineageRequest::default()).await.map(drop),
        "ListSamples" => jobs.list_samples(pb::ListSamplesRequest::default()).await.map(drop),
        "GetServerInfo" => jobs.get_server_info(pb::GetServerInfoRequest::default()).await.map(drop),
        "QueryDashboard" => jobs.query_dashboard(pb::QueryDashboardRequest::default()).await.map(drop),
        "LeaseTasks" => work.lease_tasks(pb::LeaseTasksRequest::default()).await.map(drop),
        "Heartbeat" => work.heartbeat(pb::HeartbeatRequest::default()).await.map(drop),
        "CompleteTask" => work.complete_task(pb::CompleteTaskRequest::default()).await.map(drop),
        "CompleteTasks" => work.complete_tasks(pb::CompleteTasksRequest::default()).await.map(drop),
        "ReleaseTasks" => work.release_tasks(pb::ReleaseTasksRequest::default()).await.map(drop),
        "FailTask" => work.fail_task(pb::FailTaskRequest::default()).await.map(drop),
        other => panic!("this test does not know how to call {other}: add it"),
    };
    result.err().map_or(Code::Ok, |s| s.code())
}

#[tokio::test(flavor = "multi_thread")]
async fn every_rpc_refuses_no_token_and_unknown_tokens_and_admits_exactly_its_roles() {
    let dir = tempfile::tempdir().unwrap();
    let tokens = write_tokens(dir.path());
    let port = free_port();
    let _coordinator = coordinator(dir.path(), port, "127.0.0.1", &["--auth-tokens", tokens.to_str().unwrap()]);
    let channel = Channel::from_shared(format!("http://127.0.0.1:{port}")).unwrap().connect().await.unwrap();

    let table: Vec<&str> = vint_coordinator::auth::RPC_ROLES.iter().map(|(path, _)| *path).collect();
    let specified: Vec<&str> = ALLOWED.iter().map(|(path, _)| *path).collect();
    assert_eq!(
        {
            let mut t = table.clone();
            t.sort();
            t
        },
        {
            let mut s = specified.clone();
            s.sort();
            s
        },
        "the coordinator's role table and this test's specification list different RPCs"
    );

    let mut wrong = Vec::new();
    for &(rpc, allowed) in ALLOWED {
        let cases = [
            (None, "no token"),
            (Some(UNKNOWN), "unknown"),
            (Some(SUBMIT), "submit"),
            (Some(WORKER), "worker"),
            (Some(READ), "read"),
        ];
        for (token, who) in cases {
            let code = call(channel.clone(), token, rpc).await;
            let ok = match who {
                "no token" | "unknown" => code == Code::Unauthenticated,
                role if allowed.contains(&role) => !matches!(code, Code::Unauthenticated | Code::PermissionDenied),
                _ => code == Code::PermissionDenied,
            };
            if !ok {
                wrong.push(format!("{rpc} with {who}: {code:?}"));
            }
        }
    }
    assert!(wrong.is_empty(), "calls answered against the role table:\n{}", wrong.join("\n"));
}

#[tokio::test(flavor = "multi_thread")]
async fn a_submitter_submits_with_its_token_and_nobody_else_can() {
    let dir = tempfile::tempdir().unwrap();
    let tokens = write_tokens(dir.path());
    let port = free_port();
    let _coordinator = coordinator(dir.path(), port, "127.0.0.1", &["--auth-tokens", tokens.to_str().unwrap()]);
    let url = format!("http://127.0.0.1:{port}");
    let spec = tiny_spec();
    let spec = spec.to_str().unwrap();

    let o = vintctl(&["submit", spec, "--coordinator", &url, "--token", SUBMIT]);
    assert!(o.status.success(), "submit with --token: {}", stderr(&o));
    let job = stdout(&o).trim().to_string();
    let env = [("VINT_TOKEN".to_string(), SUBMIT.to_string())];
    let o = vintctl_with_env(&["submit", spec, "--coordinator", &url, "--idempotency-key", "again"], &env);
    assert!(o.status.success(), "submit with VINT_TOKEN: {}", stderr(&o));

    for (token, why) in
        [(Some(WORKER), "needs a submit token"), (Some(READ), "needs a submit token"), (None, "--token")]
    {
        let mut args = vec!["submit", spec, "--coordinator", &url, "--idempotency-key", "refused"];
        args.extend(token.iter().flat_map(|t| ["--token", *t]));
        let o = vintctl(&args);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "submit with {token:?} must fail: {err}");
        assert!(err.contains("refused") && err.contains(why), "submit with {token:?}: {err}");
        assert!(token.is_none_or(|t| !err.contains(t)), "the token is never printed: {err}");
    }

    // A read token follows the job; it cannot cancel it, the submit token can.
    let o = vintctl(&["status", &job, "--coordinator", &url, "--token", READ, "--json"]);
    assert!(o.status.success(), "status with a read token: {}", stderr(&o));
    let o = vintctl(&["cancel", &job, "--coordinator", &url, "--token", READ]);
    assert_eq!(o.status.code(), Some(1), "cancel with a read token: {}", stderr(&o));
    let o = vintctl(&["jobs", "--coordinator", &url, "--token", WORKER]);
    assert_eq!(o.status.code(), Some(1), "jobs with a worker token: {}", stderr(&o));
}

#[tokio::test(flavor = "multi_thread")]
async fn a_worker_with_a_worker_token_leases_and_one_with_a_read_token_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let tokens = write_tokens(dir.path());
    let port = free_port();
    let _coordinator = coordinator(dir.path(), port, "127.0.0.1", &["--auth-tokens", tokens.to_str().unwrap()]);
    let url = format!("http://127.0.0.1:{port}");
    let o =
        vintctl(&["submit", tiny_spec().to_str().unwrap(), "--timing-only", "--coordinator", &url, "--token", SUBMIT]);
    assert!(o.status.success(), "submit: {}", stderr(&o));
    let job = stdout(&o).trim().to_string();
    let store = format!("file://{}", dir.path().join("objects").display());

    let worker = |id: &str, token: &str| {
        let log = std::fs::File::create(dir.path().join(format!("{id}.log"))).unwrap();
        let child = Command::new(bin("vint-worker"))
            .args(["--coordinator", &url, "--store", &store, "--worker-id", id, "--engine-mode", "timing-only"])
            .env("VINT_TOKEN", token)
            .stdout(Stdio::null())
            .stderr(Stdio::from(log))
            .spawn()
            .expect("start vint-worker");
        Proc { child, name: id.to_string() }
    };
    // The refused worker first: had it leased anything, the job would show it.
    let refused = worker("reader", READ);
    let log = dir.path().join("reader.log");
    let deadline = Instant::now() + Duration::from_secs(20);
    while !std::fs::read_to_string(&log).unwrap_or_default().contains("refuses this worker") {
        assert!(Instant::now() < deadline, "no refusal logged: {}", std::fs::read_to_string(&log).unwrap_or_default());
        std::thread::sleep(Duration::from_millis(100));
    }
    drop(refused);
    let o = vintctl(&["status", &job, "--coordinator", &url, "--token", READ, "--json"]);
    let status: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let progress = &status["progress"];
    assert_eq!(
        (progress["tasks_running"].as_u64(), progress["tasks_succeeded"].as_u64()),
        (Some(0), Some(0)),
        "a worker with a read token leased nothing: {status:#}"
    );

    let _worker = worker("leaser", WORKER);
    let o = vintctl(&["watch", &job, "--coordinator", &url, "--token", READ, "--json"]);
    assert!(o.status.success(), "a worker with a worker token runs the job: {}\n{}", stdout(&o), stderr(&o));
}

#[test]
fn without_tokens_the_coordinator_listens_on_loopback_only_unless_told_otherwise() {
    let dir = tempfile::tempdir().unwrap();
    let database = format!("sqlite://{}?mode=rwc", dir.path().join("refused.db").display());
    let port = free_port();
    let any = format!("0.0.0.0:{port}");
    let (code, err) = coordinator_refusal(&["--database", &database, "--listen", &any]);
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("--listen 0.0.0.0") && err.contains("--auth-tokens") && err.contains("--insecure-listen-any"),
        "{err}"
    );

    let _open = coordinator(dir.path(), port, "0.0.0.0", &["--insecure-listen-any"]);
    drop(_open);
    let tokens = write_tokens(dir.path());
    let port = free_port();
    let _guarded = coordinator(dir.path(), port, "0.0.0.0", &["--auth-tokens", tokens.to_str().unwrap()]);
}

#[test]
fn a_bad_tokens_file_stops_the_coordinator_naming_the_line_and_never_the_token() {
    let dir = tempfile::tempdir().unwrap();
    let tokens = dir.path().join("tokens");
    std::fs::write(&tokens, format!("submit {SUBMIT}\n# worker next\nworkers {WORKER}\n")).unwrap();
    let database = format!("sqlite://{}?mode=rwc", dir.path().join("vint.db").display());
    let listen = format!("127.0.0.1:{}", free_port());
    let args = ["--database", &database, "--listen", &listen, "--auth-tokens", tokens.to_str().unwrap()];
    let (code, err) = coordinator_refusal(&args);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains(&format!("{}, line 3", tokens.display())) && err.contains("submit, worker or read"), "{err}");
    assert!(!err.contains(WORKER) && !err.contains(SUBMIT), "a token was printed: {err}");
    std::fs::write(&tokens, "# nobody\n").unwrap();
    let (code, err) = coordinator_refusal(&args);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("no tokens"), "{err}");
}

#[test]
fn over_tls_a_client_trusting_the_private_ca_makes_an_authenticated_call() {
    let dir = tempfile::tempdir().unwrap();
    let certified = rcgen::generate_simple_self_signed(vec!["localhost".to_string(), "127.0.0.1".to_string()]).unwrap();
    let cert = dir.path().join("cert.pem");
    let key = dir.path().join("key.pem");
    std::fs::write(&cert, certified.cert.pem()).unwrap();
    std::fs::write(&key, certified.signing_key.serialize_pem()).unwrap();
    let tokens = write_tokens(dir.path());
    let (port, http) = (free_port(), free_port());
    let http_listen = format!("127.0.0.1:{http}");
    let flags = [
        "--auth-tokens",
        tokens.to_str().unwrap(),
        "--tls-cert",
        cert.to_str().unwrap(),
        "--tls-key",
        key.to_str().unwrap(),
        "--http-listen",
        &http_listen,
    ];
    let _coordinator = coordinator(dir.path(), port, "127.0.0.1", &flags);
    let https = format!("https://127.0.0.1:{port}");

    let o = vintctl(&["jobs", "--coordinator", &https, "--tls-ca", cert.to_str().unwrap(), "--token", READ, "--json"]);
    assert!(o.status.success(), "an authenticated call over TLS: {}", stderr(&o));
    assert_eq!(serde_json::from_str::<serde_json::Value>(&stdout(&o)).unwrap(), serde_json::json!([]));
    let env = [("VINT_TLS_CA".to_string(), cert.display().to_string())];
    let o = vintctl_with_env(&["jobs", "--coordinator", &https, "--json"], &env);
    assert_eq!(o.status.code(), Some(1), "over TLS, still no call without a token: {}", stderr(&o));

    // Not trusting the CA, or speaking plain HTTP/2 to it, gets nowhere.
    let o = vintctl(&["jobs", "--coordinator", &https, "--token", READ]);
    assert!(!o.status.success(), "the system's roots do not trust a private CA: {}", stdout(&o));
    let o = vintctl(&["jobs", "--coordinator", &format!("http://127.0.0.1:{port}"), "--token", READ]);
    assert!(!o.status.success(), "plain HTTP/2 to a TLS coordinator: {}", stdout(&o));

    // The HTTP listener speaks HTTPS with the same certificate, and still wants its token.
    let ca = certified.cert.der().to_vec();
    assert_eq!(https_get(http, "/dashboard/api/jobs", &ca, &format!("Bearer {READ}")), (200, "[]".to_string()));
    assert_eq!(https_get(http, "/dashboard/api/jobs", &ca, &format!("Bearer {WORKER}")).0, 403);
    assert_eq!(https_get(http, "/healthz", &ca, "Bearer -").0, 200);
    assert!(http_get(http, "/healthz").is_none(), "plain HTTP to the HTTPS listener got an answer");
}

/// `GET path` over HTTPS on 127.0.0.1:`port`, trusting only the certificate `ca` (DER), with an
/// `Authorization` header: (status, body).
fn https_get(port: u16, path: &str, ca: &[u8], authorization: &str) -> (u16, String) {
    use std::io::{Read, Write};
    use std::sync::Arc;
    let mut roots = rustls::RootCertStore::empty();
    roots.add(rustls::pki_types::CertificateDer::from(ca.to_vec())).unwrap();
    let provider = Arc::new(rustls::crypto::aws_lc_rs::default_provider());
    let config = rustls::ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .unwrap()
        .with_root_certificates(roots)
        .with_no_client_auth();
    let name = rustls::pki_types::ServerName::try_from("localhost").unwrap();
    let connection = rustls::ClientConnection::new(Arc::new(config), name).unwrap();
    let tcp = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
    tcp.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    let mut tls = rustls::StreamOwned::new(connection, tcp);
    let request = format!(
        "GET {path} HTTP/1.1\r\nHost: localhost\r\nAuthorization: {authorization}\r\nConnection: close\r\n\r\n"
    );
    tls.write_all(request.as_bytes()).unwrap();
    let mut raw = Vec::new();
    // The server may close without a TLS close_notify: what was read before that is the answer.
    let _ = tls.read_to_end(&mut raw);
    let raw = String::from_utf8_lossy(&raw);
    let (head, body) = raw.split_once("\r\n\r\n").unwrap_or_else(|| panic!("no HTTP answer: {raw:?}"));
    (head.split(' ').nth(1).unwrap().parse().unwrap(), body.to_string())
}

/// The HTTP side: `/healthz` and `/metrics` are open (the kubelet and Prometheus); the dashboard
/// and its API need a `read` token (a `submit` one will do), as a bearer or as HTTP Basic's
/// password (what a browser sends); without tokens the HTTP listener is loopback-only too.
#[test]
fn the_dashboard_needs_a_read_token_and_health_and_metrics_stay_open() {
    let dir = tempfile::tempdir().unwrap();
    let tokens = write_tokens(dir.path());
    let (port, http) = (free_port(), free_port());
    let listen = format!("127.0.0.1:{http}");
    let _coordinator = coordinator(
        dir.path(),
        port,
        "127.0.0.1",
        &["--auth-tokens", tokens.to_str().unwrap(), "--http-listen", &listen],
    );
    let deadline = Instant::now() + Duration::from_secs(20);
    while http_get(http, "/healthz").is_none_or(|(status, _, _)| status != 200) {
        assert!(Instant::now() < deadline, "/healthz never answered 200");
        std::thread::sleep(Duration::from_millis(100));
    }
    let (status, _, metrics) = http_get(http, "/metrics").unwrap();
    assert!(status == 200 && metrics.contains("vint_queue_tasks"), "{status}: {metrics}");

    for path in
        ["/dashboard", "/dashboard/api/jobs", "/dashboard/api/view/job_progress", "/dashboard/chart/throughput.svg"]
    {
        let (status, _, body) = http_get(http, path).unwrap();
        assert_eq!(status, 401, "{path} without a token: {body}");
        for (authorization, expected) in [
            (format!("Bearer {UNKNOWN}"), 401),
            (format!("Bearer {WORKER}"), 403),
            (format!("Bearer {READ}"), 200),
            (format!("Bearer {SUBMIT}"), 200),
            (format!("Basic {}", base64_encode(&format!("anyone:{READ}"))), 200),
            (format!("Basic {}", base64_encode(&format!("anyone:{WORKER}"))), 403),
        ] {
            let (status, body) = http_get_authorized(http, path, &authorization).unwrap();
            let shown = authorization.split(' ').next().unwrap();
            assert_eq!(status, expected, "{path} with a {shown} header: {body}");
            assert!(!body.contains(READ) && !body.contains(WORKER), "a token was echoed: {body}");
        }
    }

    let database = format!("sqlite://{}?mode=rwc", dir.path().join("refused.db").display());
    let (listen, http_any) = (format!("127.0.0.1:{}", free_port()), format!("0.0.0.0:{}", free_port()));
    let (code, err) = coordinator_refusal(&["--database", &database, "--listen", &listen, "--http-listen", &http_any]);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("--http-listen 0.0.0.0") && err.contains("--auth-tokens"), "{err}");
}

/// Standard base64 with padding (RFC 4648), written out so the test does not lean on the crate the
/// coordinator decodes with.
fn base64_encode(text: &str) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for chunk in text.as_bytes().chunks(3) {
        let b = [chunk[0], *chunk.get(1).unwrap_or(&0), *chunk.get(2).unwrap_or(&0)];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for i in 0..4 {
            if i <= chunk.len() {
                out.push(ALPHABET[((n >> (18 - 6 * i)) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// Workers act under their token's name: the holder of one worker token cannot heartbeat,
/// complete, fail or release a lease another token's worker holds, even claiming its worker id;
/// and one token's workers hold at most `--max-leases-per-token` leases.
#[tokio::test(flavor = "multi_thread")]
async fn a_worker_token_acts_only_on_its_own_leases_and_holds_at_most_its_cap() {
    const POOL_A: &str = "worker-a-1c4e7a9d2f5b8e03";
    const POOL_B: &str = "worker-b-6d9f2c5a8e1b4d70";
    let dir = tempfile::tempdir().unwrap();
    let tokens = dir.path().join("tokens");
    std::fs::write(&tokens, format!("submit {SUBMIT}\nworker {POOL_A} pool-a\nworker {POOL_B} pool-b\n")).unwrap();
    let port = free_port();
    let _coordinator = coordinator(
        dir.path(),
        port,
        "127.0.0.1",
        &["--auth-tokens", tokens.to_str().unwrap(), "--max-leases-per-token", "2"],
    );
    let url = format!("http://127.0.0.1:{port}");
    let o = vintctl(&["submit", tiny_spec().to_str().unwrap(), "--coordinator", &url, "--token", SUBMIT]);
    assert!(o.status.success(), "submit: {}", stderr(&o));
    let channel = Channel::from_shared(url.clone()).unwrap().connect().await.unwrap();
    let client = |token: &'static str| {
        let header: AsciiMetadataValue = format!("Bearer {token}").parse().unwrap();
        WorkServiceClient::with_interceptor(channel.clone(), move |mut request: tonic::Request<()>| {
            request.metadata_mut().insert("authorization", header.clone());
            Ok(request)
        })
    };
    let (mut a, mut b) = (client(POOL_A), client(POOL_B));
    let lease = |capacity: u32| pb::LeaseTasksRequest {
        worker_id: "w1".into(),
        stages: vec!["grasp".into()],
        capacity,
        lease_ms: 60_000,
        engines: Default::default(),
        timing_only: false,
    };
    let task = a.lease_tasks(lease(1)).await.unwrap().into_inner().tasks.remove(0);
    let held = vec![pb::TaskAttempt { task_id: task.task_id.clone(), attempt: task.attempt }];

    // Pool b's worker claiming the same id is another worker: pool-b/w1, not pool-a/w1.
    let beat = |held: Vec<pb::TaskAttempt>| pb::HeartbeatRequest { worker_id: "w1".into(), held, lease_ms: 60_000 };
    let lost = b.heartbeat(beat(held.clone())).await.unwrap().into_inner().lost;
    assert_eq!(lost.len(), 1, "another token's worker renewed pool a's lease");
    let complete = pb::CompleteTaskRequest {
        worker_id: "w1".into(),
        task_id: task.task_id.clone(),
        attempt: task.attempt,
        outputs: vec![],
        engine_json: "{}".into(),
        timings: None,
        result_json: r#"{"accepted": []}"#.into(),
    };
    assert_eq!(b.complete_task(complete).await.unwrap_err().code(), Code::FailedPrecondition);
    let fail = pb::FailTaskRequest {
        worker_id: "w1".into(),
        task_id: task.task_id.clone(),
        attempt: task.attempt,
        retryable: false,
        message: "sabotage".into(),
    };
    assert_eq!(b.fail_task(fail).await.unwrap_err().code(), Code::FailedPrecondition);
    let release = pb::ReleaseTasksRequest { worker_id: "w1".into(), tasks: held.clone() };
    assert!(b.release_tasks(release).await.unwrap().into_inner().released.is_empty());
    assert!(a.heartbeat(beat(held)).await.unwrap().into_inner().lost.is_empty(), "pool a still holds it");
    let bad_id = pb::LeaseTasksRequest { worker_id: "../w1".into(), ..lease(1) };
    assert_eq!(a.lease_tasks(bad_id).await.unwrap_err().code(), Code::InvalidArgument);

    // The cap: pool a holds 1 of 2, gets 1 more of the 5 it asks for, then none.
    assert_eq!(a.lease_tasks(lease(5)).await.unwrap().into_inner().tasks.len(), 1);
    let refused = a.lease_tasks(lease(5)).await.unwrap_err();
    assert_eq!(refused.code(), Code::ResourceExhausted, "{refused}");
    assert!(
        refused.message().contains("pool-a") && refused.message().contains("--max-leases-per-token 2"),
        "{refused}"
    );
    assert_eq!(b.lease_tasks(lease(1)).await.unwrap().into_inner().tasks.len(), 1, "pool b has its own cap");

    // The attempt records the token's name.
    let database = format!("sqlite://{}?mode=rwc", dir.path().join(format!("vint-{port}.db")).display());
    let store = vint_store::Store::open(&database, vint_store::RetryPolicy::default()).await.unwrap();
    let record = store.task(&task.task_id).await.unwrap().unwrap();
    assert_eq!(record.lease_owner.as_deref(), Some("pool-a/w1"));
}

/// A token has at most `--max-jobs-per-token` jobs running; resubmitting one it has is answered.
#[test]
fn a_token_has_at_most_its_cap_of_jobs_running() {
    let dir = tempfile::tempdir().unwrap();
    let tokens = write_tokens(dir.path());
    let port = free_port();
    let _coordinator = coordinator(
        dir.path(),
        port,
        "127.0.0.1",
        &["--auth-tokens", tokens.to_str().unwrap(), "--max-jobs-per-token", "1"],
    );
    let url = format!("http://127.0.0.1:{port}");
    let spec = tiny_spec();
    let submit = |extra: &[&str]| {
        let mut args = vec!["submit", spec.to_str().unwrap(), "--coordinator", &url, "--token", SUBMIT];
        args.extend_from_slice(extra);
        vintctl(&args)
    };
    let first = submit(&[]);
    assert!(first.status.success(), "submit: {}", stderr(&first));
    let refused = submit(&["--timing-only"]);
    assert_eq!(refused.status.code(), Some(1), "a second running job: {}", stdout(&refused));
    let message = stderr(&refused);
    assert!(message.contains("has 1 jobs running") && message.contains("--max-jobs-per-token 1"), "{message}");
    let again = submit(&[]);
    assert!(again.status.success(), "a resubmission is answered: {}", stderr(&again));
    assert_eq!(stdout(&again).trim(), stdout(&first).trim());
}
