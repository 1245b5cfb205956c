//! Why a job failed, as the store answers it: permanently failed tasks with their last error,
//! the tasks that broke before the tasks they took down with them.

use vint_core::Stage;
use vint_store::Store;

#[macro_use]
mod common;
use common::{fence, job, task};

store_test!(failed_tasks_list_root_causes_first_with_their_last_error, |store: Store| async move {
    // Two chunks, each a grasp feeding a render feeding a package.
    let mut tasks = Vec::new();
    for c in ["a", "b"] {
        tasks.push(task(&format!("grasp/{c}"), Stage::Grasp, &[]));
        tasks.push(task(&format!("render/{c}"), Stage::Render, &[&format!("grasp/{c}")]));
        tasks.push(task(&format!("package/{c}"), Stage::Package, &[&format!("render/{c}")]));
    }
    store.submit_job(&job("j"), &tasks, 0).await.unwrap();
    assert!(store.failed_tasks("j", 20).await.unwrap().is_empty(), "nothing failed yet");

    let leased = store.lease("w", &[Stage::Grasp], 2, 60_000, 1).await.unwrap();
    let (a, b) = (&leased[0], &leased[1]);
    // grasp/b fails retryably once, then for good; grasp/a fails for good at once.
    assert!(store.fail(&fence(b, "w"), true, "engine: out of memory", 2).await.unwrap());
    assert!(
        !store
            .fail(&fence(a, "w"), false, "engine: params.physics.hold_s: 45.0 is outside [0.0, 30.0]", 3)
            .await
            .unwrap()
    );
    let retried = store.lease("w", &[Stage::Grasp], 1, 60_000, 10_000).await.unwrap();
    assert_eq!((retried[0].key.as_str(), retried[0].attempt), ("grasp/b", 2));
    assert!(
        !store.fail(&fence(&retried[0], "w"), false, "engine: object.cup: not a closed surface", 10_001).await.unwrap()
    );

    let failed = store.failed_tasks("j", 20).await.unwrap();
    let shown: Vec<(&str, Stage, u32, bool)> =
        failed.iter().map(|t| (t.key.as_str(), t.stage, t.attempts, t.failed_upstream())).collect();
    assert_eq!(
        shown,
        [
            ("grasp/a", Stage::Grasp, 1, false),
            ("grasp/b", Stage::Grasp, 2, false),
            ("package/a", Stage::Package, 0, true),
            ("package/b", Stage::Package, 0, true),
            ("render/a", Stage::Render, 0, true),
            ("render/b", Stage::Render, 0, true),
        ]
    );
    assert_eq!(failed[0].last_error, "engine: params.physics.hold_s: 45.0 is outside [0.0, 30.0]");
    assert_eq!(failed[1].last_error, "engine: object.cup: not a closed surface", "the last attempt's error");
    assert!(failed[4].last_error.contains("j/grasp/a"), "{}", failed[4].last_error);

    // A cap keeps the root causes.
    let capped: Vec<String> = store.failed_tasks("j", 3).await.unwrap().into_iter().map(|t| t.key).collect();
    assert_eq!(capped, ["grasp/a", "grasp/b", "package/a"]);
    assert!(store.failed_tasks("other", 20).await.unwrap().is_empty());
});
