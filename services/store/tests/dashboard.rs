//! The dashboard views (migration 0008) as the store reads them, on both backends: each view's
//! numbers for a small job whose every task, attempt and artifact the test made, so each expected
//! value is counted by hand here, not by the views' SQL.

use serde_json::{Value, json};
use vint_core::Stage;
use vint_core::plan::NewTask;
use vint_store::{DashboardView, Store};

#[macro_use]
mod common;
use common::{completion, fence, job};

const CAN: &str = "grasp/can/trx3/c00000";
const MUG: &str = "grasp/mug/trx3/c00000";
const RENDER_0: &str = "render/can/trx3/g000000";
const RENDER_2: &str = "render/can/trx3/g000002";

fn grasp_task(key: &str, object: &str) -> NewTask {
    NewTask {
        key: key.into(),
        stage: Stage::Grasp,
        params: json!({"object": {"name": object}, "hand": {"name": "trx3"}}),
        deps: vec![],
    }
}

fn render_task(key: &str) -> NewTask {
    NewTask {
        key: key.into(),
        stage: Stage::Render,
        params: json!({"render": {"width": 128, "height": 96, "samples": 16}}),
        deps: vec![CAN.into()],
    }
}

/// Rows of `view` for `job`, as JSON objects.
async fn rows(store: &Store, view: DashboardView, job: Option<&str>) -> Vec<Value> {
    let table = store.dashboard(view, job, 0).await.unwrap();
    let names: Vec<&str> = view.columns().iter().map(|(name, _)| *name).collect();
    assert_eq!(table.columns, names, "{view}: columns as declared");
    table.objects().into_iter().map(Value::Object).collect()
}

/// Job `j`: grasp chunks of the can (accepted 2 of 5 trials, at 61 s) and of the mug (a retryable
/// failure at 2 s, then 0 of 3 accepted at 125 s), a render of the can's grasp 0 (2 views in 3 s,
/// at 70 s) and one of its grasp 2 still running. Job `k`: one grasp task, never run.
async fn small_job(store: &Store) {
    let tasks = [grasp_task(CAN, "can"), grasp_task(MUG, "mug"), render_task(RENDER_0), render_task(RENDER_2)];
    store.submit_job(&job("j"), &tasks, 0).await.unwrap();
    store.submit_job(&job("k"), &[grasp_task(CAN, "can")], 0).await.unwrap();

    let grasps = store.lease("w1", &[Stage::Grasp], 2, 600_000, 1_000).await.unwrap();
    let (can, mug) = (grasps.iter().find(|t| t.key == CAN).unwrap(), grasps.iter().find(|t| t.key == MUG).unwrap());
    assert!(store.fail(&fence(mug, "w1"), true, "engine: out of memory", 2_000).await.unwrap());
    let mut done = completion(fence(can, "w1"), &["grasps.json", "touch.json"]);
    done.timings_json = r#"{"engine_ms": 2000.0}"#.into();
    done.result_json = json!({
        "accepted": [0, 2],
        "rejected": {"dropped": 1, "no_contact": 2},
        "active_taxels": [
            {"grasp_index": 0, "by_region": {"palm": 1, "pulp": 0, "tip": 4}},
            {"grasp_index": 2, "by_region": {"palm": 0, "pulp": 2, "tip": 3}},
        ],
    })
    .to_string();
    store.complete(&done, &[], 61_000).await.unwrap();

    let retried = store.lease("w1", &[Stage::Grasp], 1, 600_000, 10_000).await.unwrap();
    assert_eq!(retried[0].key, MUG, "the mug's retry ({retried:?})");
    let mut done = completion(fence(&retried[0], "w1"), &["grasps.json"]);
    done.result_json = json!({"accepted": [], "rejected": {"dropped": 3}, "active_taxels": []}).to_string();
    done.timings_json = r#"{"engine_ms": 500.0}"#.into();
    store.complete(&done, &[], 125_000).await.unwrap();

    let renders = store.lease("w2", &[Stage::Render, Stage::Noise], 2, 600_000, 62_000).await.unwrap();
    let held: Vec<(String, u32)> = renders.iter().map(|t| (t.id.clone(), t.attempt)).collect();
    assert!(store.heartbeat("w2", &held, 600_000, 65_000).await.map(|b| b.lost).unwrap().is_empty());
    let render = renders.iter().find(|t| t.key == RENDER_0).unwrap();
    let mut done = completion(fence(render, "w2"), &["v00/rgb.png", "v01/rgb.png", "v00/camera.json"]);
    done.timings_json = r#"{"engine_ms": 3000.0}"#.into();
    done.result_json = json!({"views": 2, "device": "CPU"}).to_string();
    store.complete(&done, &[], 70_000).await.unwrap();
}

store_test!(each_dashboard_view_counts_what_the_job_recorded, |store: Store| async move {
    small_job(&store).await;
    let j = Some("j");

    assert_eq!(
        rows(&store, DashboardView::JobProgress, j).await,
        [
            json!({"job_id": "j", "stage": "grasp", "tasks": 2, "waiting": 0, "queued": 0, "running": 0,
                   "succeeded": 2, "failed": 0, "cancelled": 0}),
            json!({"job_id": "j", "stage": "render", "tasks": 2, "waiting": 0, "queued": 0, "running": 1,
                   "succeeded": 1, "failed": 0, "cancelled": 0}),
        ]
    );
    let all = rows(&store, DashboardView::JobProgress, None).await;
    assert_eq!(all.len(), 3, "every job without a filter: {all:?}");
    assert_eq!((all[2]["job_id"].clone(), all[2]["queued"].clone()), (json!("k"), json!(1)));

    assert_eq!(
        rows(&store, DashboardView::Throughput, j).await,
        [
            json!({"job_id": "j", "stage": "grasp", "minute_ms": 0, "succeeded": 0, "failed": 1, "engine_s": 0.0}),
            json!({"job_id": "j", "stage": "grasp", "minute_ms": 60_000, "succeeded": 1, "failed": 0, "engine_s": 2.0}),
            json!({"job_id": "j", "stage": "render", "minute_ms": 60_000, "succeeded": 1, "failed": 0, "engine_s": 3.0}),
            json!({"job_id": "j", "stage": "grasp", "minute_ms": 120_000, "succeeded": 1, "failed": 0, "engine_s": 0.5}),
        ]
    );

    assert_eq!(
        rows(&store, DashboardView::Failures, j).await,
        [json!({"job_id": "j", "stage": "grasp", "outcome": "retry", "reason": "engine: out of memory",
                "attempts": 1, "tasks": 1, "first_task_key": MUG, "last_task_key": MUG})]
    );

    assert_eq!(
        rows(&store, DashboardView::Workers, None).await,
        [
            json!({"worker_id": "w1", "stages": "grasp", "first_seen_ms": 1_000, "last_seen_ms": 10_000,
                   "last_heartbeat_ms": null, "running_tasks": 0}),
            json!({"worker_id": "w2", "stages": "render,noise", "first_seen_ms": 62_000, "last_seen_ms": 65_000,
                   "last_heartbeat_ms": 65_000, "running_tasks": 1}),
        ]
    );

    assert_eq!(
        rows(&store, DashboardView::GraspAcceptance, j).await,
        [
            json!({"job_id": "j", "object": "can", "hand": "trx3", "tasks": 1, "trials": 5, "accepted": 2,
                   "rejected": 3, "acceptance": 0.4}),
            json!({"job_id": "j", "object": "mug", "hand": "trx3", "tasks": 1, "trials": 3, "accepted": 0,
                   "rejected": 3, "acceptance": 0.0}),
        ]
    );
    assert_eq!(
        rows(&store, DashboardView::GraspRejections, j).await,
        [
            json!({"job_id": "j", "object": "can", "hand": "trx3", "reason": "dropped", "trials": 1}),
            json!({"job_id": "j", "object": "can", "hand": "trx3", "reason": "no_contact", "trials": 2}),
            json!({"job_id": "j", "object": "mug", "hand": "trx3", "reason": "dropped", "trials": 3}),
        ]
    );
    assert_eq!(
        rows(&store, DashboardView::ActiveTaxels, j).await,
        [
            json!({"job_id": "j", "hand": "trx3", "region": "palm", "grasps": 2, "active_taxels": 1,
                   "mean_per_grasp": 0.5, "min_per_grasp": 0, "max_per_grasp": 1}),
            json!({"job_id": "j", "hand": "trx3", "region": "pulp", "grasps": 2, "active_taxels": 2,
                   "mean_per_grasp": 1.0, "min_per_grasp": 0, "max_per_grasp": 2}),
            json!({"job_id": "j", "hand": "trx3", "region": "tip", "grasps": 2, "active_taxels": 7,
                   "mean_per_grasp": 3.5, "min_per_grasp": 3, "max_per_grasp": 4}),
        ]
    );
    assert_eq!(
        rows(&store, DashboardView::RenderSeconds, j).await,
        [json!({"job_id": "j", "width": 128, "height": 96, "samples": 16, "device": "CPU", "renders": 1,
                "views": 2, "engine_s": 3.0, "seconds_per_view": 1.5})]
    );
    // common::artifact makes every file 3 bytes.
    assert_eq!(
        rows(&store, DashboardView::BytesWritten, j).await,
        [
            json!({"job_id": "j", "stage": "grasp", "files": 3, "bytes": 9}),
            json!({"job_id": "j", "stage": "render", "files": 3, "bytes": 9}),
        ]
    );
});

store_test!(a_dashboard_query_keeps_to_its_job_and_its_limit, |store: Store| async move {
    small_job(&store).await;
    assert!(rows(&store, DashboardView::JobProgress, Some("nope")).await.is_empty());
    let first = store.dashboard(DashboardView::JobProgress, None, 1).await.unwrap();
    assert_eq!(first.rows.len(), 1);
    assert_eq!(first.rows[0][0], json!("j"));
    // Workers are not per job: a job names none of their rows away.
    assert_eq!(rows(&store, DashboardView::Workers, Some("k")).await.len(), 2);
});

store_test!(with_no_job_chosen_a_view_shows_the_newest_jobs_only, |store: Store| async move {
    // One job more than the dashboard lists, each newer than the last: the oldest is not shown.
    let shown = vint_store::DASHBOARD_JOBS_SHOWN as usize;
    for i in 0..=shown {
        let id = format!("j{i:03}");
        store.submit_job(&job(&id), &[grasp_task(CAN, "can")], i as i64).await.unwrap();
    }
    let listed: Vec<Value> =
        rows(&store, DashboardView::JobProgress, None).await.iter().map(|r| r["job_id"].clone()).collect();
    assert_eq!(listed.len(), shown);
    assert!(!listed.contains(&json!("j000")), "the oldest job is past the list");
    assert!(listed.contains(&json!("j001")) && listed.contains(&json!(format!("j{shown:03}"))));
    assert_eq!(rows(&store, DashboardView::JobProgress, Some("j000")).await.len(), 1, "asked for by name, it is");
});

#[test]
fn view_names_parse_back_and_an_unknown_one_lists_them() {
    for view in DashboardView::ALL {
        assert_eq!(view.name().parse::<DashboardView>().unwrap(), view);
    }
    let err = "progress".parse::<DashboardView>().unwrap_err().to_string();
    assert!(err.contains("\"progress\" is not a dashboard view") && err.contains("job_progress, throughput"), "{err}");
}
