//! What the coordinator's tests share: a SQLite store in a temporary directory, and a job to
//! submit to it.

use vint_store::{NewJob, RetryPolicy, Store};

/// A fresh SQLite store in `dir`.
pub async fn sqlite_store(dir: &std::path::Path) -> Store {
    Store::open(&format!("sqlite://{}", dir.join("vint.db").display()), RetryPolicy::default()).await.unwrap()
}

/// A job `id` with no spec or plan of its consequence (its tasks are submitted by the test).
pub fn job(id: &str) -> NewJob {
    NewJob {
        id: id.into(),
        name: id.into(),
        seed: 1,
        spec_toml: String::new(),
        plan_json: "{}".into(),
        idempotency_key: id.into(),
        assets: vec![],
        timing_only: false,
        submitted_by: None,
    }
}
