//! `ListSamples` in pages: a real coordinator, in process, over a real (SQLite) store whose
//! package tasks completed with the files of their samples.

use serde_json::json;
use vint_core::Stage;
use vint_core::plan::NewTask;
use vint_proto::v1 as pb;
use vint_proto::v1::job_service_client::JobServiceClient;
use vint_store::{Completion, Fence, NewArtifact, Store};

mod common;

fn artifact(name: &str) -> NewArtifact {
    let sha256 = vint_artifacts::sha256_hex(name.as_bytes());
    NewArtifact {
        name: name.into(),
        object_key: vint_artifacts::key_for(&sha256).unwrap(),
        sha256,
        size: name.len() as u64,
        media_type: "application/json".into(),
    }
}

/// Five package tasks of job `j`, each with two samples (a grasp's two views) and its grasp
/// record, completed.
async fn packaged_job() -> (Store, tempfile::TempDir) {
    let dir = tempfile::tempdir().unwrap();
    let store = common::sqlite_store(dir.path()).await;
    let job = common::job("j");
    let tasks: Vec<NewTask> = (0..5)
        .map(|i| NewTask {
            key: format!("package/mug/trx3/c{i:05}"),
            stage: Stage::Package,
            params: json!({}),
            deps: vec![],
        })
        .collect();
    store.submit_job(&job, &tasks, 0).await.unwrap();
    for task in store.lease("w", &[Stage::Package], 5, 60_000, 1).await.unwrap() {
        let i: u32 = task.key[task.key.len() - 5..].parse().unwrap();
        let grasp = format!("mug.trx3.g{:06}", 10 + i);
        let samples = vec![format!("{grasp}.v00"), format!("{grasp}.v01")];
        let mut outputs: Vec<NewArtifact> = samples.iter().map(|s| artifact(&format!("{s}/meta.json"))).collect();
        outputs.push(artifact(&format!("{grasp}/grasp.json")));
        let done = Completion {
            fence: Fence { task_id: task.id.clone(), worker_id: "w".into(), attempt: task.attempt },
            outputs,
            engine_json: "{}".into(),
            timings_json: "null".into(),
            result_json: "{}".into(),
            samples,
            reused_from: None,
        };
        store.complete(&done, &[], 2).await.unwrap();
    }
    (store, dir)
}

#[tokio::test(flavor = "multi_thread")]
async fn samples_come_in_pages_of_whole_package_tasks_that_add_up_to_the_job() {
    let (store, _dir) = packaged_job().await;
    let (listener, addr) = vint_coordinator::bind(([127, 0, 0, 1], 0).into()).await.unwrap();
    let config = vint_coordinator::CoordinatorConfig::default();
    tokio::spawn(vint_coordinator::serve(store, config, listener, std::future::pending()));
    let mut client = JobServiceClient::connect(format!("http://{addr}")).await.unwrap();
    let list =
        |page_token: String, page_size: u32| pb::ListSamplesRequest { job_id: "j".into(), page_token, page_size };

    let whole = client.list_samples(list(String::new(), 0)).await.unwrap().into_inner();
    assert_eq!((whole.samples.len(), whole.grasps.len()), (10, 5));
    assert!(whole.next_page_token.is_empty(), "five tasks fit one default page");

    let (mut token, mut pages, mut samples, mut grasps) = (String::new(), Vec::new(), Vec::new(), Vec::new());
    loop {
        let page = client.list_samples(list(token.clone(), 2)).await.unwrap().into_inner();
        pages.push(page.samples.len());
        samples.extend(page.samples.into_iter().map(|s| s.sample_id));
        grasps.extend(page.grasps.into_iter().map(|g| g.grasp_id));
        if page.next_page_token.is_empty() {
            break;
        }
        assert!(page.next_page_token > token, "pages move forward");
        token = page.next_page_token;
    }
    assert_eq!(pages, [4, 4, 2], "two package tasks of two samples a page");
    let all: Vec<String> = whole.samples.iter().map(|s| s.sample_id.clone()).collect();
    assert_eq!(samples, all, "the pages add up to the whole, in order, nothing twice");
    assert_eq!(grasps, whole.grasps.iter().map(|g| g.grasp_id.clone()).collect::<Vec<_>>());
    let unknown = client.list_samples(pb::ListSamplesRequest { job_id: "nope".into(), ..Default::default() }).await;
    assert_eq!(unknown.unwrap_err().code(), tonic::Code::NotFound);
}
