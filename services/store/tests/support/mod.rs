//! What a store contract test needs: a fresh Postgres database and a fresh SQLite file, a macro
//! that runs one test body against both, and small builders for jobs, tasks and fences.
//!
//! Postgres comes from `VINT_TEST_POSTGRES_URL` (default `postgres://postgres@127.0.0.1:5432/postgres`);
//! each test gets a database of its own. A missing Postgres fails these tests: it never skips them.

use serde_json::json;
use vint_core::Stage;
use vint_core::plan::NewTask;
use vint_store::{Fence, LeasedTask, NewJob, RetryPolicy, Store};

pub const RETRY: RetryPolicy = RetryPolicy { max_attempts: 3, backoff_base_ms: 100, backoff_cap_ms: 1_000 };

pub async fn sqlite_store() -> (Store, tempfile::TempDir) {
    let dir = tempfile::tempdir().unwrap();
    let url = format!("sqlite://{}", dir.path().join("vint.db").display());
    (Store::open(&url, RETRY).await.unwrap(), dir)
}

pub async fn postgres_store() -> (Store, String) {
    let admin = std::env::var("VINT_TEST_POSTGRES_URL")
        .unwrap_or_else(|_| "postgres://postgres@127.0.0.1:5432/postgres".to_string());
    // vint_test_<pid>_<tag>_<nanos>_<n>, as vint_tests::postgres_database names them: scripts/test.sh
    // reads the pid to drop the databases of test processes that no longer run.
    let db = format!("vint_test_{}_queue_{}", std::process::id(), uuid_like());
    sqlx::any::install_default_drivers();
    let mut conn = <sqlx::AnyConnection as sqlx::Connection>::connect(&admin)
        .await
        .unwrap_or_else(|e| panic!("Postgres is required for the store tests ({admin}): {e}"));
    sqlx::Executor::execute(&mut conn, sqlx::AssertSqlSafe(format!("CREATE DATABASE {db}"))).await.unwrap();
    let base = admin.rsplit_once('/').map(|(b, _)| b.to_string()).unwrap();
    (Store::open(&format!("{base}/{db}"), RETRY).await.unwrap(), db)
}

fn uuid_like() -> String {
    use std::sync::atomic::{AtomicU64, Ordering};
    static N: AtomicU64 = AtomicU64::new(0);
    let t = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap().as_nanos();
    format!("{}_{}", t % 1_000_000_000, N.fetch_add(1, Ordering::Relaxed))
}

// Builders: a task, a job and a fence as the tests write them.

pub fn task(key: &str, stage: Stage, deps: &[&str]) -> NewTask {
    NewTask { key: key.into(), stage, params: json!({"k": key}), deps: deps.iter().map(|d| d.to_string()).collect() }
}

pub fn job(id: &str) -> NewJob {
    NewJob {
        id: id.into(),
        name: "t".into(),
        seed: 1,
        spec_toml: "".into(),
        idempotency_key: format!("key-{id}"),
        assets: vec![],
    }
}

pub fn fence(t: &LeasedTask, worker: &str) -> Fence {
    Fence { task_id: t.id.clone(), worker_id: worker.into(), attempt: t.attempt }
}

/// Runs one contract test against both backends.
macro_rules! store_test {
    ($name:ident, $body:expr) => {
        mod $name {
            use super::*;
            #[tokio::test(flavor = "multi_thread", worker_threads = 4)]
            async fn sqlite() {
                let (store, _dir) = $crate::support::sqlite_store().await;
                ($body)(store).await;
            }
            #[tokio::test(flavor = "multi_thread", worker_threads = 4)]
            async fn postgres() {
                let (store, _db) = $crate::support::postgres_store().await;
                ($body)(store).await;
            }
        }
    };
}
