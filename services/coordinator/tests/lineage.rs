//! `GetLineage` stays one bounded message however many tasks share what it asks about: a real
//! coordinator, in process, over a real (SQLite) store.

use serde_json::json;
use vint_core::Stage;
use vint_core::plan::NewTask;
use vint_proto::v1 as pb;
use vint_proto::v1::get_lineage_request::Subject;
use vint_proto::v1::job_service_client::JobServiceClient;
use vint_store::JobAsset;

mod common;

/// The coordinator's `LINEAGE_TASKS_NAMING_A_FILE`.
const LISTED: usize = 100;

#[tokio::test(flavor = "multi_thread")]
async fn a_file_every_task_reads_lists_the_first_tasks_and_says_there_are_more() {
    let dir = tempfile::tempdir().unwrap();
    let store = common::sqlite_store(dir.path()).await;
    let (mesh, other) = ("ab".repeat(32), "cd".repeat(32));
    let mut job = common::job("j");
    job.assets = [(&mesh, "assets/bowl.obj"), (&other, "assets/cup.obj")]
        .map(|(sha, path)| JobAsset {
            path: path.into(),
            sha256: sha.clone(),
            size: 42,
            media_type: "model/obj".into(),
            object_key: format!("sha256/{}/{sha}", &sha[..2]),
        })
        .to_vec();
    // 150 tasks read the bowl, 3 the cup.
    let named = |i: usize, sha: &str| NewTask {
        key: format!("grasp/{i:04}"),
        stage: Stage::Grasp,
        params: json!({"object": {"shape": {"type": "mesh", "asset": sha}}}),
        deps: vec![],
    };
    let tasks: Vec<NewTask> = (0..153).map(|i| named(i, if i < 150 { &mesh } else { &other })).collect();
    store.submit_job(&job, &tasks, 0).await.unwrap();

    let (listener, addr) = vint_coordinator::bind(([127, 0, 0, 1], 0).into()).await.unwrap();
    let config = vint_coordinator::CoordinatorConfig::default();
    tokio::spawn(vint_coordinator::serve(store, config, listener, std::future::pending()));
    let mut client = JobServiceClient::connect(format!("http://{addr}")).await.unwrap();
    let lineage = |sha: &str| pb::GetLineageRequest {
        job_id: "j".into(),
        subject: Some(Subject::ArtifactSha256(sha.to_string())),
    };

    let bowl = client.get_lineage(lineage(&mesh)).await.unwrap().into_inner();
    assert_eq!(bowl.user_files.iter().map(|f| f.path.as_str()).collect::<Vec<_>>(), ["assets/bowl.obj"]);
    assert_eq!(bowl.tasks.len(), LISTED);
    assert!(bowl.more_tasks, "150 tasks read it");
    let keys: Vec<String> = bowl.tasks.iter().map(|t| t.key.clone()).collect();
    assert_eq!(keys, (0..LISTED).map(|i| format!("grasp/{i:04}")).collect::<Vec<_>>(), "the first by key");

    let cup = client.get_lineage(lineage(&other)).await.unwrap().into_inner();
    assert_eq!(
        cup.tasks.iter().map(|t| t.key.as_str()).collect::<Vec<_>>(),
        ["grasp/0150", "grasp/0151", "grasp/0152"]
    );
    assert!(!cup.more_tasks);
}
