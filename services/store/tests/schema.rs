//! Connecting to the database as a cluster does: migrations as a step of their own (a replica
//! without DDL rights checks the schema and refuses one that is behind), and TLS to Postgres.

#[macro_use]
mod common;

use common::*;
use vint_store::{Store, StoreError};

/// A database with nothing applied, of each backend: its URL (and the SQLite file's directory).
async fn empty_sqlite() -> (String, tempfile::TempDir) {
    let dir = tempfile::tempdir().unwrap();
    (format!("sqlite://{}", dir.path().join("vint.db").display()), dir)
}

/// The versions of the migrations this build carries, from the migrations directory.
fn shipped_versions(backend: &str) -> Vec<i64> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("migrations").join(backend);
    let mut versions: Vec<i64> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().split('_').next().unwrap().parse().unwrap())
        .collect();
    versions.sort();
    versions
}

async fn a_replica_refuses_a_schema_behind_its_binary_and_changes_nothing(url: &str, backend: &str) {
    let replica = Store::connect(url, RETRY).await.unwrap();
    let err = replica.require_current_schema().await.unwrap_err();
    let StoreError::SchemaBehind { missing } = &err else { panic!("{err}") };
    assert_eq!(*missing, shipped_versions(backend), "nothing is applied to an empty database");
    assert!(err.to_string().contains("--migrate-only"), "the error says what to do: {err}");
    // The check ran no DDL: the database is still empty.
    assert!(matches!(replica.require_current_schema().await, Err(StoreError::SchemaBehind { .. })));
    assert!(replica.list_jobs(1).await.is_err(), "no tables were created");

    // The migration step (`--migrate-only`), then the replica starts.
    Store::connect(url, RETRY).await.unwrap().migrate().await.unwrap();
    replica.require_current_schema().await.unwrap();
    assert!(replica.list_jobs(1).await.unwrap().is_empty());

    // A database one migration behind (as after deploying a binary with a new migration, before
    // its migration Job ran) is refused, naming that migration.
    let mut conn = <sqlx::AnyConnection as sqlx::Connection>::connect(url).await.unwrap();
    let newest = *shipped_versions(backend).last().unwrap();
    sqlx::query("DELETE FROM _sqlx_migrations WHERE version = $1").bind(newest).execute(&mut conn).await.unwrap();
    let err = replica.require_current_schema().await.unwrap_err();
    assert!(matches!(&err, StoreError::SchemaBehind { missing } if *missing == [newest]), "{err}");
}

#[tokio::test]
async fn sqlite_a_replica_refuses_a_schema_behind_its_binary_and_changes_nothing() {
    let (url, _dir) = empty_sqlite().await;
    a_replica_refuses_a_schema_behind_its_binary_and_changes_nothing(&url, "sqlite").await;
}

#[tokio::test]
async fn postgres_a_replica_refuses_a_schema_behind_its_binary_and_changes_nothing() {
    let url = empty_postgres_database().await;
    a_replica_refuses_a_schema_behind_its_binary_and_changes_nothing(&url, "postgres").await;
}

fn with_sslmode(url: &str, mode: &str) -> String {
    let sep = if url.contains('?') { '&' } else { '?' };
    format!("{url}{sep}sslmode={mode}")
}

/// Whether the test server offers TLS (`SHOW ssl`), asked over a connection in clear.
async fn server_offers_tls(url: &str) -> bool {
    let mut conn = <sqlx::AnyConnection as sqlx::Connection>::connect(&with_sslmode(url, "disable")).await.unwrap();
    let row = sqlx::query("SHOW ssl").fetch_one(&mut conn).await.unwrap();
    sqlx::Row::try_get::<String, _>(&row, "ssl").unwrap() == "on"
}

#[tokio::test]
async fn postgres_connections_use_tls_when_asked_and_never_fall_back_to_clear_text() {
    let url = empty_postgres_database().await;
    let offers_tls = server_offers_tls(&url).await;
    // In clear only when asked.
    let clear = Store::connect(&with_sslmode(&url, "disable"), RETRY).await.unwrap();
    assert_eq!(clear.encrypted().await.unwrap(), Some(false));
    // The test server is on loopback: a URL that says nothing of TLS connects in clear there
    // (`postgres_url`: TLS over loopback protects nothing and halved batch-256 completion).
    let default = Store::connect(&url, RETRY).await.unwrap();
    let says_tls = url.contains("sslmode") || std::env::var_os("PGSSLMODE").is_some();
    if !says_tls {
        assert_eq!(default.encrypted().await.unwrap(), Some(false));
    }
    // `prefer`, the default elsewhere: TLS whenever the server offers it.
    let prefer = Store::connect(&with_sslmode(&url, "prefer"), RETRY).await.unwrap();
    assert_eq!(prefer.encrypted().await.unwrap(), Some(offers_tls));
    // `require`: TLS or nothing. A build without a TLS backend would refuse every such URL with
    // "SQLx was built without TLS support"; this one negotiates.
    match Store::connect(&with_sslmode(&url, "require"), RETRY).await {
        Ok(store) => {
            assert!(offers_tls, "connected with sslmode=require to a server without TLS");
            assert_eq!(store.encrypted().await.unwrap(), Some(true));
        }
        Err(e) => {
            assert!(!offers_tls, "sslmode=require failed against a server with TLS: {e}");
            assert!(e.to_string().contains("server does not support TLS"), "{e}");
        }
    }
    // `verify-full` checks the certificate against the roots it trusts: the test server's is
    // self-signed (Debian's snakeoil), so it is refused with a certificate error, never in clear.
    let err = Store::connect(&with_sslmode(&url, "verify-full"), RETRY).await.unwrap_err().to_string();
    let expected = if offers_tls { "certificate" } else { "server does not support TLS" };
    assert!(err.to_lowercase().contains(expected), "{err}");
    assert!(!err.contains("built without TLS"), "{err}");
}

#[tokio::test]
async fn an_unsupported_url_is_refused_without_its_password() {
    let err = Store::connect("mysql://vint:hunter2@db/vint", RETRY).await.unwrap_err().to_string();
    assert!(err.contains("mysql://vint:***@db/vint") && !err.contains("hunter2"), "{err}");
}
