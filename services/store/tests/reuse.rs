//! Task reuse in the store (`vint_store::reuse`, the `reused_from` completion), against a real
//! Postgres and a real SQLite.

#[macro_use]
mod common;

use common::*;
use vint_core::{Stage, TaskState};
use vint_store::Store;

const ALL: [Stage; 4] = [Stage::Grasp, Stage::Render, Stage::Noise, Stage::Package];

store_test!(a_finished_tasks_result_is_found_by_its_key_from_any_job, |store: Store| async move {
    store.submit_job(&job("a"), &[task("grasp/x", Stage::Grasp, &[])], 0).await.unwrap();
    let leased = store.lease("w", &ALL, 1, 1_000, 1).await.unwrap();
    store.set_content_keys(&[(leased[0].id.clone(), leased[0].attempt, "k1".into())]).await.unwrap();
    assert!(store.stored_results(&["k1".into()]).await.unwrap().is_empty(), "a running task is no result");
    let mut done = completion(fence(&leased[0], "w"), &["grasps.json", "touch.json"]);
    done.result_json = r#"{"accepted":[0]}"#.into();
    store.complete(&done, &[], 2).await.unwrap();
    let found = store.stored_results(&["k1".into(), "k2".into()]).await.unwrap();
    assert_eq!(found.len(), 1);
    let stored = &found["k1"];
    assert_eq!(stored.task_id, "a/grasp/x");
    assert_eq!(stored.result_json, r#"{"accepted":[0]}"#);
    assert_eq!(stored.outputs.iter().map(|o| o.name.as_str()).collect::<Vec<_>>(), ["grasps.json", "touch.json"]);
});

store_test!(a_key_is_written_only_on_the_lease_it_names, |store: Store| async move {
    store.submit_job(&job("a"), &[task("grasp/x", Stage::Grasp, &[])], 0).await.unwrap();
    let leased = store.lease("w", &ALL, 1, 1_000, 1).await.unwrap();
    store.set_content_keys(&[(leased[0].id.clone(), leased[0].attempt + 1, "stale".into())]).await.unwrap();
    assert_eq!(store.content_key("a/grasp/x").await.unwrap(), None);
    store.set_content_keys(&[(leased[0].id.clone(), leased[0].attempt, "k".into())]).await.unwrap();
    assert_eq!(store.content_key("a/grasp/x").await.unwrap().as_deref(), Some("k"));
    // Written again (as a later attempt's lease, by another engine, would), the key is replaced.
    store.set_content_keys(&[(leased[0].id.clone(), leased[0].attempt, "k2".into())]).await.unwrap();
    assert_eq!(store.content_key("a/grasp/x").await.unwrap().as_deref(), Some("k2"));
});

store_test!(a_reused_completion_records_its_source_and_no_attempt, |store: Store| async move {
    let chain = [task("grasp/x", Stage::Grasp, &[]), task("render/x", Stage::Render, &["grasp/x"])];
    store.submit_job(&job("a"), &chain, 0).await.unwrap();
    let leased = store.lease("w", &ALL, 1, 1_000, 1).await.unwrap();
    assert_eq!(leased[0].attempt, 1);
    let mut reused = completion(fence(&leased[0], "w"), &["grasps.json"]);
    reused.reused_from = Some("old/grasp/x".into());
    store.complete(&reused, &[], 2).await.unwrap();
    let t = store.task("a/grasp/x").await.unwrap().unwrap();
    assert_eq!(t.state, TaskState::Succeeded);
    assert_eq!(t.reused_from.as_deref(), Some("old/grasp/x"));
    assert_eq!(t.attempt, 0, "no attempt ran");
    assert_eq!(store.attempt_count("a/grasp/x").await.unwrap(), 0);
    // Its dependents are unblocked as by any completion, and see the reused outputs as inputs.
    let next = store.lease("w", &ALL, 1, 1_000, 3).await.unwrap();
    assert_eq!(next[0].key, "render/x");
    assert_eq!(next[0].inputs.iter().map(|i| i.name.as_str()).collect::<Vec<_>>(), ["grasps.json"]);
    store.complete(&completion(fence(&next[0], "w"), &["v00_rgb.png"]), &[], 4).await.unwrap();
    assert_eq!(store.attempt_count("a/render/x").await.unwrap(), 1);
    let progress = store.progress("a").await.unwrap();
    assert_eq!(progress.reused.get(&Stage::Grasp), Some(&1));
    assert_eq!(progress.reused.get(&Stage::Render), None);
    assert_eq!(store.job("a").await.unwrap().unwrap().state, vint_core::JobState::Succeeded);
});
