//! The coordinator counts what its worker API does: a real coordinator, in process, over a real
//! (SQLite) store, driven through the generated gRPC client, its metrics read at `/metrics`.

use serde_json::json;
use vint_core::Stage;
use vint_core::plan::NewTask;
use vint_proto::v1 as pb;
use vint_proto::v1::work_service_client::WorkServiceClient;

mod common;

/// A plain HTTP/1.0 GET: the status and the body.
async fn get(addr: std::net::SocketAddr, path: &str) -> (u16, String) {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let mut stream = tokio::net::TcpStream::connect(addr).await.unwrap();
    stream.write_all(format!("GET {path} HTTP/1.0\r\nHost: test\r\n\r\n").as_bytes()).await.unwrap();
    let mut raw = String::new();
    stream.read_to_string(&mut raw).await.unwrap();
    let (head, body) = raw.split_once("\r\n\r\n").unwrap();
    (head.split(' ').nth(1).unwrap().parse().unwrap(), body.to_string())
}

#[tokio::test(flavor = "multi_thread")]
async fn leases_completions_failures_and_refusals_are_counted_by_stage() {
    let dir = tempfile::tempdir().unwrap();
    let store = common::sqlite_store(dir.path()).await;
    let job = common::job("j");
    // Noise tasks unlock nothing: their completions depend on nothing but their outputs.
    let noise = |key: &str| NewTask { key: key.into(), stage: Stage::Noise, params: json!({}), deps: vec![] };
    store.submit_job(&job, &[noise("noise/a"), noise("noise/b")], vint_coordinator::now_ms()).await.unwrap();

    let config = vint_coordinator::CoordinatorConfig::default();
    let router = vint_coordinator::http_router(store.clone(), &config);
    let (listener, addr) = vint_coordinator::bind(([127, 0, 0, 1], 0).into()).await.unwrap();
    let (_stop, stopped) = tokio::sync::oneshot::channel::<()>();
    tokio::spawn(vint_coordinator::serve(store.clone(), config, listener, async {
        let _ = stopped.await;
    }));
    let (http_listener, http) = vint_coordinator::bind(([127, 0, 0, 1], 0).into()).await.unwrap();
    tokio::spawn(vint_telemetry::serve_http(http_listener, router, std::future::pending()));

    let mut client = WorkServiceClient::connect(format!("http://{addr}")).await.unwrap();
    let lease = pb::LeaseTasksRequest {
        worker_id: "w".into(),
        stages: vec!["noise".into()],
        capacity: 2,
        lease_ms: 60_000,
        ..Default::default()
    };
    let tasks = client.lease_tasks(lease).await.unwrap().into_inner().tasks;
    assert_eq!(tasks.len(), 2);

    let content = b"depth noise";
    let sha256 = vint_artifacts::sha256_hex(content);
    let complete = |task: &pb::LeasedTask, key: String| pb::CompleteTaskRequest {
        worker_id: "w".into(),
        task_id: task.task_id.clone(),
        attempt: task.attempt,
        outputs: vec![pb::ArtifactRef {
            name: "v00_depth_noisy.npy".into(),
            sha256: sha256.clone(),
            size: content.len() as u64,
            media_type: "application/x-npy".into(),
            key,
            task_key: String::new(),
        }],
        engine_json: "{}".into(),
        timings: None,
        result_json: r#"{"views": 1}"#.into(),
    };
    // A report with a key that is not the content key is refused; the right one is recorded.
    assert!(client.complete_task(complete(&tasks[0], "sha256/not-it".into())).await.is_err());
    let key = vint_artifacts::key_for(&sha256).unwrap();
    client.complete_task(complete(&tasks[0], key)).await.unwrap();
    let fail = pb::FailTaskRequest {
        worker_id: "w".into(),
        task_id: tasks[1].task_id.clone(),
        attempt: tasks[1].attempt,
        retryable: true,
        message: "engine crashed".into(),
    };
    assert!(client.fail_task(fail).await.unwrap().into_inner().will_retry);

    let (status, body) = get(http, "/metrics").await;
    assert_eq!(status, 200);
    let build = format!("vint_build_info{{component=\"coordinator\",version=\"{}\"}} 1", env!("CARGO_PKG_VERSION"));
    for line in [
        build.as_str(),
        "vint_database_up 1",
        "vint_tasks_leased_total{stage=\"noise\"} 2",
        "vint_tasks_leased_total{stage=\"render\"} 0",
        "vint_tasks_completed_total{stage=\"noise\"} 1",
        "vint_completions_refused_total{reason=\"invalid\"} 1",
        "vint_completions_refused_total{reason=\"lease_lost\"} 0",
        "vint_tasks_failed_total{stage=\"noise\",outcome=\"retry\"} 1",
        "vint_tasks_failed_total{stage=\"noise\",outcome=\"failed\"} 0",
        "vint_rpc_duration_seconds_count{rpc=\"lease_tasks\"} 1",
        "vint_rpc_duration_seconds_count{rpc=\"complete_task\"} 2",
        "vint_rpc_duration_seconds_count{rpc=\"fail_task\"} 1",
        "vint_rpc_duration_seconds_count{rpc=\"heartbeat\"} 0",
    ] {
        assert!(body.lines().any(|l| l == line), "missing {line:?} in\n{body}");
    }
    assert_eq!(get(http, "/healthz").await, (200, "ok\n".to_string()));
}

/// A watch on a job that never changes ends when its client leaves: the poller does not wait for
/// a send that never comes (`vint_watch_streams` goes back to 0).
#[tokio::test(flavor = "multi_thread")]
async fn a_watch_ends_when_its_client_leaves_a_job_that_never_changes() {
    let dir = tempfile::tempdir().unwrap();
    let store = common::sqlite_store(dir.path()).await;
    let job = common::job("stuck");
    let noise = NewTask { key: "noise/a".into(), stage: Stage::Noise, params: json!({}), deps: vec![] };
    store.submit_job(&job, &[noise], vint_coordinator::now_ms()).await.unwrap();
    let config = vint_coordinator::CoordinatorConfig::default();
    let router = vint_coordinator::http_router(store.clone(), &config);
    let (listener, addr) = vint_coordinator::bind(([127, 0, 0, 1], 0).into()).await.unwrap();
    tokio::spawn(vint_coordinator::serve(store.clone(), config, listener, std::future::pending()));
    let (http_listener, http) = vint_coordinator::bind(([127, 0, 0, 1], 0).into()).await.unwrap();
    tokio::spawn(vint_telemetry::serve_http(http_listener, router, std::future::pending()));
    let open = || async move {
        let (_, body) = get(http, "/metrics").await;
        body.lines().find_map(|l| l.strip_prefix("vint_watch_streams ")).unwrap().trim().to_string()
    };

    let mut client =
        vint_proto::v1::job_service_client::JobServiceClient::connect(format!("http://{addr}")).await.unwrap();
    let mut stream = client.watch_job(pb::WatchJobRequest { job_id: "stuck".into() }).await.unwrap().into_inner();
    assert!(stream.message().await.unwrap().is_some(), "the first progress comes at once");
    assert_eq!(open().await, "1");
    drop(stream);
    drop(client);
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
    while open().await != "0" {
        assert!(std::time::Instant::now() < deadline, "the watch of a stuck job outlived its client");
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
}
