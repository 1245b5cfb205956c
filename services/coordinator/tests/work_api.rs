//! The worker API as a worker speaks it: a real coordinator, in process, over a real (SQLite)
//! store, reached through the generated gRPC client.

use serde_json::json;
use vint_core::plan::NewTask;
use vint_core::{Stage, TaskState};
use vint_proto::v1 as pb;
use vint_proto::v1::work_service_client::WorkServiceClient;
use vint_store::Store;

mod common;

/// A coordinator serving `store` on a free local port until the returned sender is dropped.
async fn start_coordinator(store: Store) -> (String, tokio::sync::oneshot::Sender<()>) {
    let (listener, addr) = vint_coordinator::bind(([127, 0, 0, 1], 0).into()).await.unwrap();
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let config = vint_coordinator::CoordinatorConfig::default();
    tokio::spawn(vint_coordinator::serve(store, config, listener, async {
        let _ = stopped.await;
    }));
    (format!("http://{addr}"), stop)
}

#[tokio::test(flavor = "multi_thread")]
async fn an_output_whose_key_is_not_its_content_key_is_refused_and_changes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let store = common::sqlite_store(dir.path()).await;
    let job = common::job("j");
    // A noise task unlocks nothing, so its completion depends on nothing but its outputs.
    let noise = NewTask { key: "noise/a".into(), stage: Stage::Noise, params: json!({}), deps: vec![] };
    store.submit_job(&job, &[noise], vint_coordinator::now_ms()).await.unwrap();
    let (url, _stop) = start_coordinator(store.clone()).await;
    let mut client = WorkServiceClient::connect(url).await.unwrap();
    let lease = pb::LeaseTasksRequest {
        worker_id: "w".into(),
        stages: vec!["noise".into()],
        capacity: 1,
        lease_ms: 60_000,
        ..Default::default()
    };
    let task = client.lease_tasks(lease).await.unwrap().into_inner().tasks.remove(0);

    let content = b"depth noise";
    let sha256 = vint_artifacts::sha256_hex(content);
    let content_key = vint_artifacts::key_for(&sha256).unwrap();
    let complete = |key: &str| pb::CompleteTaskRequest {
        worker_id: "w".into(),
        task_id: task.task_id.clone(),
        attempt: task.attempt,
        outputs: vec![pb::ArtifactRef {
            name: "v00_depth_noisy.npy".into(),
            sha256: sha256.clone(),
            size: content.len() as u64,
            media_type: "application/x-npy".into(),
            key: key.into(),
            task_key: String::new(),
        }],
        engine_json: "{}".into(),
        timings: None,
        result_json: r#"{"views": 1}"#.into(), // what a noise engine answers
    };
    let other_content_key = vint_artifacts::key_for(&vint_artifacts::sha256_hex(b"other bytes")).unwrap();
    // A well-formed key of other content, then keys of shapes the store never makes (paths that
    // would leave the store among them): each names what is wrong with it.
    let wrong_content = (other_content_key, format!("key must be the content key {content_key}"));
    let bad_shapes = [
        format!("uploads/{sha256}"),
        format!("{content_key}.tmp"),
        String::new(),
        format!("/{content_key}"),
        format!("sha256/../../{sha256}"),
        format!("sha256\\{}\\{sha256}", &sha256[..2]),
    ]
    .map(|key| (key, "artifact key".to_string()));
    for (wrong_key, expected) in std::iter::once(wrong_content).chain(bad_shapes) {
        let refused = client.complete_task(complete(&wrong_key)).await.unwrap_err();
        assert_eq!(refused.code(), tonic::Code::InvalidArgument, "key {wrong_key:?}: {refused}");
        assert!(refused.message().contains(&expected), "key {wrong_key:?}: {refused}");
        // Nothing was recorded: the task is still the worker's, running, with no outputs.
        let after = store.task(&task.task_id).await.unwrap().unwrap();
        assert_eq!((after.state, after.lease_owner.as_deref()), (TaskState::Running, Some("w")));
        assert!(store.artifacts_of_task(&task.task_id).await.unwrap().is_empty());
        assert_eq!(store.attempts(&task.task_id).await.unwrap()[0].outcome, None, "the attempt still runs");
    }

    // An output named twice is refused too, and records nothing.
    let mut twice = complete(&content_key);
    twice.outputs.push(twice.outputs[0].clone());
    let refused = client.complete_task(twice).await.unwrap_err();
    assert_eq!(refused.code(), tonic::Code::InvalidArgument, "{refused}");
    assert!(refused.message().contains("\"v00_depth_noisy.npy\": named twice"), "{refused}");
    assert!(store.artifacts_of_task(&task.task_id).await.unwrap().is_empty());

    // The same completion naming the content key is accepted: the key alone was refused.
    client.complete_task(complete(&content_key)).await.unwrap();
    assert_eq!(store.task(&task.task_id).await.unwrap().unwrap().state, TaskState::Succeeded);
    let recorded = store.artifacts_of_task(&task.task_id).await.unwrap();
    assert_eq!(recorded.iter().map(|a| a.object_key.as_str()).collect::<Vec<_>>(), [content_key.as_str()]);
}
