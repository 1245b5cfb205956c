//! What every store test shares: a real database of each backend per test, the macros that run one
//! contract test against both, and small builders for jobs, tasks and completions.
//!
//! Postgres comes from `VINT_TEST_POSTGRES_URL` (default `postgres://postgres@127.0.0.1:5432/postgres`);
//! each test gets a database of its own. A missing Postgres fails these tests: it never skips them.

// Each test file uses the part of this module it needs.
#![allow(dead_code, unused_macros)]

use serde_json::json;
use vint_core::Stage;
use vint_core::plan::NewTask;
use vint_store::{Completion, Fence, LeasedTask, NewArtifact, NewJob, RetryPolicy, Store};

pub const RETRY: RetryPolicy = RetryPolicy { max_attempts: 3, backoff_base_ms: 100, backoff_cap_ms: 1_000 };

/// A store over a fresh database, and the URL to reach that database directly.
pub struct TestDb {
    pub store: Store,
    pub url: String,
    /// Holds the SQLite file's directory for the test's lifetime.
    _dir: Option<tempfile::TempDir>,
}

pub async fn sqlite_db() -> TestDb {
    let dir = tempfile::tempdir().unwrap();
    let url = format!("sqlite://{}", dir.path().join("vint.db").display());
    TestDb { store: Store::open(&url, RETRY).await.unwrap(), url, _dir: Some(dir) }
}

pub async fn postgres_db() -> TestDb {
    let url = empty_postgres_database().await;
    TestDb { store: Store::open(&url, RETRY).await.unwrap(), url, _dir: None }
}

/// The admin URL of the test server: `VINT_TEST_POSTGRES_URL`, or the local default.
pub fn postgres_admin_url() -> String {
    std::env::var("VINT_TEST_POSTGRES_URL")
        .unwrap_or_else(|_| "postgres://postgres@127.0.0.1:5432/postgres".to_string())
}

/// A new, empty Postgres database (no migrations applied); returns its URL.
pub async fn empty_postgres_database() -> String {
    let admin = postgres_admin_url();
    // vint_test_<pid>_<tag>_<nanos>_<n>, as vint_tests::postgres_database names them: scripts/test.sh
    // reads the pid to drop the databases of test processes that no longer run.
    let db = format!("vint_test_{}_store_{}", std::process::id(), uuid_like());
    sqlx::any::install_default_drivers();
    let mut conn = <sqlx::AnyConnection as sqlx::Connection>::connect(&admin).await.unwrap_or_else(|e| {
        panic!("Postgres is required for the store tests ({}): {e}", vint_telemetry::redact_url(&admin))
    });
    sqlx::Executor::execute(&mut conn, sqlx::AssertSqlSafe(format!("CREATE DATABASE {db}"))).await.unwrap();
    let base = admin.rsplit_once('/').map(|(b, _)| b.to_string()).unwrap();
    format!("{base}/{db}")
}

fn uuid_like() -> String {
    use std::sync::atomic::{AtomicU64, Ordering};
    static N: AtomicU64 = AtomicU64::new(0);
    let t = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap().as_nanos();
    format!("{}_{}", t % 1_000_000_000, N.fetch_add(1, Ordering::Relaxed))
}

/// Runs one contract test, given a `Store`, against both backends.
macro_rules! store_test {
    ($name:ident, $body:expr) => {
        mod $name {
            use super::*;
            #[tokio::test(flavor = "multi_thread", worker_threads = 4)]
            async fn sqlite() {
                let db = common::sqlite_db().await;
                ($body)(db.store.clone()).await;
            }
            #[tokio::test(flavor = "multi_thread", worker_threads = 4)]
            async fn postgres() {
                let db = common::postgres_db().await;
                ($body)(db.store.clone()).await;
            }
        }
    };
}

/// Runs one test that also speaks to the database directly, given a `Store` and its database's
/// URL, against both backends.
macro_rules! database_test {
    ($name:ident, $body:expr) => {
        mod $name {
            use super::*;
            #[tokio::test(flavor = "multi_thread", worker_threads = 4)]
            async fn sqlite() {
                let db = common::sqlite_db().await;
                ($body)(db.store.clone(), db.url.clone()).await;
            }
            #[tokio::test(flavor = "multi_thread", worker_threads = 4)]
            async fn postgres() {
                let db = common::postgres_db().await;
                ($body)(db.store.clone(), db.url.clone()).await;
            }
        }
    };
}

pub fn task(key: &str, stage: Stage, deps: &[&str]) -> NewTask {
    NewTask { key: key.into(), stage, params: json!({"k": key}), deps: deps.iter().map(|d| d.to_string()).collect() }
}

pub fn job(id: &str) -> NewJob {
    NewJob {
        id: id.into(),
        name: "t".into(),
        seed: 1,
        spec_toml: "".into(),
        plan_json: "{}".into(),
        idempotency_key: format!("key-{id}"),
        assets: vec![],
        timing_only: false,
        submitted_by: None,
    }
}

pub fn artifact(name: &str) -> NewArtifact {
    let sha256 = format!("{:0>64}", name.len());
    NewArtifact {
        name: name.into(),
        object_key: vint_artifacts::key_for(&sha256).unwrap(),
        sha256,
        size: 3,
        media_type: "application/octet-stream".into(),
    }
}

pub fn completion(fence: Fence, outputs: &[&str]) -> Completion {
    Completion {
        fence,
        outputs: outputs.iter().map(|n| artifact(n)).collect(),
        engine_json: r#"{"name":"test-double"}"#.into(),
        timings_json: "{}".into(),
        result_json: "{}".into(),
        samples: vec![],
        reused_from: None,
    }
}

pub fn fence(t: &LeasedTask, worker: &str) -> Fence {
    Fence { task_id: t.id.clone(), worker_id: worker.into(), attempt: t.attempt }
}
