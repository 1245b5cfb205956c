//! The lineage store: jobs, tasks, dependencies, attempts, artifacts and samples.
//!
//! Lineage is the graph of tasks (`task_deps`) with the artifacts each made: a task's inputs are
//! exactly its dependencies' outputs, because a task is queued only once every dependency has
//! succeeded and a succeeded task's outputs never change (completion is fenced and happens once).
//! So the edges are derived (`task_deps ⋈ artifacts`), never stored twice.
//!
//! This crate is the only place in vint that speaks SQL. One `Store` type serves both backends
//! through sqlx's `Any` driver: **Postgres** for clusters (many coordinators and workers, leasing
//! with `FOR UPDATE SKIP LOCKED`) and **SQLite** for the embedded default (one process, one
//! connection, so every transaction is serialized). Every statement is a named block of a file in
//! `sql/postgres/` or `sql/sqlite/` (`sql.rs`): the two directories hold the same files and names,
//! each statement spelled in its dialect (row locks, reading a JSON array as rows, one statement
//! of data-modifying CTEs where SQLite takes several), and code asks for one by name. Both run
//! the same test suite.
//!
//! Every transition follows `vint_core::state`; completion and failure are fenced on the lease
//! holder and attempt, so a worker whose lease expired can change nothing. States, stages and
//! attempt outcomes travel as the `vint_core` enums, bound as parameters, and the database refuses
//! any name the enums do not define (migration 0004); `tests/states.rs` checks every transition the
//! store makes against `TaskState::can_transition`. Times are passed in (`now_ms`) rather than read
//! from a clock, which keeps the queue logic testable.
//!
//! At the scale of millions of samples (issue 11, `benches/dispatch.sh`): a batch of leases or
//! completions is a fixed number of set-based statements; an attempt is written once, when it
//! ends (the running attempt is its task's row); the rows written per artifact and per sample
//! carry no foreign key on Postgres (the store writes them only from the task row it has just
//! fenced); no two batch statements wait on each other's task rows in opposite orders (a
//! heartbeat skips rows locked by a completion of the same leases; completions lock the
//! dependents they unblock in id order); and the coordinator keeps the planner's statistics
//! current as a job grows its tables (`Store::refresh_statistics`).

mod dashboard;
mod depth;
mod failures;
pub mod footprint;
mod jobs;
mod lineage;
mod outputs;
mod queue;
mod records;
mod reuse;
mod sql;

use std::str::FromStr;
use std::time::Duration;

use sqlx::any::{AnyPoolOptions, install_default_drivers};
use sqlx::{AnyPool, Executor, Row};

use crate::sql::sql;

pub use dashboard::{
    ColumnType, DashboardTable, DashboardView, JOBS_SHOWN as DASHBOARD_JOBS_SHOWN, MAX_ROWS as DASHBOARD_MAX_ROWS,
    UnknownView,
};
pub use depth::{LIVE_TASK_STATES, QueueDepth};
pub use failures::FailedTask;
pub use jobs::DeletedJob;
pub use lineage::{ASSET_TASK_KEY, grasp_records_of, samples_of};
pub use queue::{Clock, Heartbeat};
pub use records::*;
pub use reuse::StoredResult;

/// Which database a `Store` talks to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Backend {
    Postgres,
    Sqlite,
}

/// The URL the pool connects with: `url`, plus `sslmode=disable` when it names a loopback host
/// (127.0.0.0/8, ::1, localhost) and says nothing of TLS itself (no `sslmode` in it, no
/// `PGSSLMODE` in the environment: `pgsslmode`). libpq's and sqlx's default, `prefer`, encrypts
/// whenever the server offers TLS — Debian's Postgres does, with its snakeoil certificate — and
/// on loopback that protects nothing but costs: measured with `benches/coordinator.rs`, TLS to a
/// local Postgres took batch-256 completion from 39 to 60 ms p50 and 19,200 to 14,100 tasks/s
/// (docs/benchmarks.md). Any other host keeps `prefer`, and an explicit `sslmode` always wins.
fn postgres_url(url: &str, pgsslmode: Option<&str>) -> String {
    let Ok(parsed) = url::Url::parse(url) else { return url.to_string() };
    let loopback = match parsed.host() {
        Some(url::Host::Ipv4(ip)) => ip.is_loopback(),
        Some(url::Host::Ipv6(ip)) => ip.is_loopback(),
        // A postgres:// URL's host is opaque to the url crate: an address arrives as a name.
        Some(url::Host::Domain(name)) => {
            name.eq_ignore_ascii_case("localhost") || name.parse::<std::net::IpAddr>().is_ok_and(|ip| ip.is_loopback())
        }
        None => false,
    };
    let says_tls = pgsslmode.is_some() || parsed.query_pairs().any(|(key, _)| key == "sslmode");
    if !loopback || says_tls {
        return url.to_string();
    }
    let separator = if parsed.query().is_some() { '&' } else { '?' };
    format!("{url}{separator}sslmode=disable")
}

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("database error: {0}")]
    Database(#[from] sqlx::Error),
    #[error("migration failed: {0}")]
    Migrate(#[from] sqlx::migrate::MigrateError),
    /// The URL, with any password redacted.
    #[error("unsupported database URL {0:?}: expected postgres://… or sqlite://…")]
    UnsupportedUrl(String),
    #[error(
        "the database's schema is behind this binary: migrations {missing:?} are not applied \
         (run `vint-coordinator --migrate-only` with a role that may change the schema)"
    )]
    SchemaBehind { missing: Vec<i64> },
    #[error(
        "task {task_id} attempt {attempt}: lease not held by worker {worker_id} (expired, cancelled or taken over)"
    )]
    LeaseLost { task_id: String, attempt: u32, worker_id: String },
    #[error("{0} not found")]
    NotFound(String),
    #[error("corrupt row: {0}")]
    Corrupt(String),
    /// A write the store refuses: what, and the rule it breaks.
    #[error("{0}")]
    Invalid(String),
    /// A statement this build's SQL files lack (`sql.rs`; its tests make this unreachable).
    #[error("SQL statement: {0}")]
    Statement(String),
}

impl StoreError {
    /// Whether the error is the database's passing state rather than the request's fault: a lost
    /// or refused connection, a pool with no connection free in time, a transaction the database
    /// chose to abort (serialization failure, deadlock), a server shutting down or full, a SQLite
    /// database locked by another process. The same request may succeed when tried again.
    pub fn is_transient(&self) -> bool {
        let StoreError::Database(e) = self else { return false };
        match e {
            sqlx::Error::Io(_)
            | sqlx::Error::Tls(_)
            | sqlx::Error::PoolTimedOut
            | sqlx::Error::PoolClosed
            | sqlx::Error::WorkerCrashed
            | sqlx::Error::Protocol(_) => true,
            sqlx::Error::Database(db) => db.code().is_some_and(|code| transient_code(&code)),
            _ => false,
        }
    }
}

/// SQLSTATEs (Postgres) and result codes (SQLite) of a transient failure: connection exceptions
/// (class 08), serialization failure and deadlock (40001, 40P01), too many connections (53300),
/// operator intervention (class 57: admin or crash shutdown, cannot connect now); SQLITE_BUSY (5)
/// and SQLITE_LOCKED (6).
fn transient_code(code: &str) -> bool {
    code.starts_with("08") || code.starts_with("57") || matches!(code, "40001" | "40P01" | "53300" | "5" | "6")
}

pub type Result<T, E = StoreError> = std::result::Result<T, E>;

/// Connections a store opens to Postgres unless told otherwise (`Store::connect_with_pool`).
pub const DEFAULT_POSTGRES_POOL: u32 = 16;

/// Retry policy applied when a task fails retryably or its lease expires.
#[derive(Clone, Copy, Debug)]
pub struct RetryPolicy {
    pub max_attempts: u32,
    pub backoff_base_ms: i64,
    pub backoff_cap_ms: i64,
}

impl Default for RetryPolicy {
    fn default() -> Self {
        RetryPolicy { max_attempts: 4, backoff_base_ms: 1_000, backoff_cap_ms: 60_000 }
    }
}

#[derive(Clone, Debug)]
pub struct Store {
    pool: AnyPool,
    backend: Backend,
    retry: RetryPolicy,
}

impl Store {
    /// Connects to `postgres://…` or `sqlite://…` (created if missing) and applies migrations.
    pub async fn open(url: &str, retry: RetryPolicy) -> Result<Store> {
        let store = Store::connect(url, retry).await?;
        store.migrate().await?;
        Ok(store)
    }

    /// Connects without touching the schema (no DDL): for coordinator replicas whose role may
    /// not change it, which check it with `require_current_schema` instead.
    pub async fn connect(url: &str, retry: RetryPolicy) -> Result<Store> {
        Store::connect_with_pool(url, retry, DEFAULT_POSTGRES_POOL).await
    }

    /// `connect` with at most `postgres_pool` connections to Postgres (SQLite always has one).
    pub async fn connect_with_pool(url: &str, retry: RetryPolicy, postgres_pool: u32) -> Result<Store> {
        install_default_drivers();
        let backend = if url.starts_with("postgres://") || url.starts_with("postgresql://") {
            Backend::Postgres
        } else if url.starts_with("sqlite:") {
            Backend::Sqlite
        } else {
            return Err(StoreError::UnsupportedUrl(vint_telemetry::redact_url(url)));
        };
        let pool = match backend {
            Backend::Postgres => {
                AnyPoolOptions::new()
                    .max_connections(postgres_pool.max(1))
                    .after_connect(|conn, _| Box::pin(on_connect(conn, Backend::Postgres)))
                    .connect(&postgres_url(url, std::env::var("PGSSLMODE").ok().as_deref()))
                    .await?
            }
            Backend::Sqlite => {
                let url = if url.contains('?') { url.to_string() } else { format!("{url}?mode=rwc") };
                // One connection: SQLite serializes writers anyway, and one connection means no
                // SQLITE_BUSY between our own transactions.
                AnyPoolOptions::new()
                    .max_connections(1)
                    .acquire_timeout(Duration::from_secs(60))
                    .after_connect(|conn, _| Box::pin(on_connect(conn, Backend::Sqlite)))
                    .connect(&url)
                    .await?
            }
        };
        Ok(Store { pool, backend, retry })
    }

    pub fn backend(&self) -> Backend {
        self.backend
    }

    pub fn retry_policy(&self) -> RetryPolicy {
        self.retry
    }

    /// Applies the migrations the database lacks (DDL).
    pub async fn migrate(&self) -> Result<()> {
        self.migrator().run(&self.pool).await?;
        let packed = self.pack_legacy_artifacts().await?;
        if packed > 0 {
            tracing::info!(tasks = packed, "packed the outputs of tasks recorded before migration 0013");
        }
        Ok(())
    }

    /// Refuses (`SchemaBehind`) a database that lacks any of this binary's migrations; changes
    /// nothing. A database ahead of the binary (migrated by a newer release during a rollout)
    /// passes: migrations add to the schema, but for 0013, which replaces `artifacts` and `samples`
    /// (docs/operations.md: stop older coordinators before it).
    pub async fn require_current_schema(&self) -> Result<()> {
        let applied = self.applied_migrations().await?;
        let missing: Vec<i64> = self.migrator().iter().map(|m| m.version).filter(|v| !applied.contains(v)).collect();
        if missing.is_empty() { Ok(()) } else { Err(StoreError::SchemaBehind { missing }) }
    }

    /// The versions of the migrations applied to the database (none before the first).
    async fn applied_migrations(&self) -> Result<Vec<i64>> {
        let exists = sql(self.backend, "migrations_table_exists")?;
        let n: i64 = sqlx::query(exists).fetch_one(&self.pool).await?.try_get("n")?;
        if n == 0 {
            return Ok(Vec::new());
        }
        let rows = sqlx::query(sql(self.backend, "applied_migrations")?).fetch_all(&self.pool).await?;
        rows.iter().map(|row| Ok(row.try_get::<i64, _>("version")?)).collect()
    }

    /// The migrations compiled in. The path is relative to this crate: `migrations` is a symbolic
    /// link to the repository's `migrations/`, so a packaged crate holds them too (build.rs).
    fn migrator(&self) -> sqlx::migrate::Migrator {
        match self.backend {
            Backend::Postgres => sqlx::migrate!("migrations/postgres"),
            Backend::Sqlite => sqlx::migrate!("migrations/sqlite"),
        }
    }

    /// Whether this store's connections to Postgres are encrypted (TLS), as the server sees one of
    /// them; `None` on SQLite. With the URL's default `sslmode=prefer` a connection is encrypted
    /// when the server offers TLS and in clear when it does not; `require`, `verify-ca` and
    /// `verify-full` refuse to connect in clear.
    pub async fn encrypted(&self) -> Result<Option<bool>> {
        if self.backend != Backend::Postgres {
            return Ok(None);
        }
        let row = sqlx::query(sql(self.backend, "connection_encrypted")?).fetch_one(&self.pool).await?;
        Ok(Some(row.try_get::<bool, _>("ssl")?))
    }

    /// Whether the database answers a trivial query: the coordinator's health.
    pub async fn ping(&self) -> Result<()> {
        sqlx::query(sql(self.backend, "ping")?).execute(&self.pool).await?;
        Ok(())
    }

    pub async fn close(&self) {
        self.pool.close().await;
    }
}

/// Runs the dialect's `on_connect` statements (settings) on a new connection, one by one.
async fn on_connect(conn: &mut sqlx::AnyConnection, backend: Backend) -> std::result::Result<(), sqlx::Error> {
    let text = sql(backend, "on_connect").map_err(|e| sqlx::Error::Configuration(e.to_string().into()))?;
    for statement in text.split(';').map(str::trim).filter(|s| !s.is_empty()) {
        conn.execute(statement).await?;
    }
    Ok(())
}

fn parse<T: FromStr>(what: &str, s: &str) -> Result<T> {
    s.parse().map_err(|_| StoreError::Corrupt(format!("{what} {s:?}")))
}

fn to_u32(what: &str, v: i64) -> Result<u32> {
    u32::try_from(v).map_err(|_| StoreError::Corrupt(format!("{what} {v}")))
}

#[cfg(test)]
mod transient_tests {
    use super::*;

    #[test]
    fn connection_pool_and_abort_errors_are_transient_the_request_s_own_are_not() {
        assert!(StoreError::Database(sqlx::Error::PoolTimedOut).is_transient());
        assert!(StoreError::Database(sqlx::Error::Io(std::io::ErrorKind::ConnectionReset.into())).is_transient());
        assert!(!StoreError::Database(sqlx::Error::RowNotFound).is_transient());
        assert!(!StoreError::NotFound("job x".into()).is_transient());
        for code in ["08006", "57P01", "57P03", "40001", "40P01", "53300", "5", "6"] {
            assert!(transient_code(code), "{code}");
        }
        for code in ["23505", "42P01", "22P02", "19", "1"] {
            assert!(!transient_code(code), "{code}");
        }
    }
}

#[cfg(test)]
mod url_tests {
    use super::postgres_url;

    #[test]
    fn loopback_without_a_word_on_tls_connects_in_clear() {
        let local = "postgres://postgres@127.0.0.1:5432/vint";
        assert_eq!(postgres_url(local, None), format!("{local}?sslmode=disable"));
        let with_query = "postgres://u:p@localhost/vint?application_name=x";
        assert_eq!(postgres_url(with_query, None), format!("{with_query}&sslmode=disable"));
        assert_eq!(postgres_url("postgres://[::1]:5432/vint", None), "postgres://[::1]:5432/vint?sslmode=disable");
    }

    #[test]
    fn an_explicit_choice_or_another_host_is_left_alone() {
        for url in [
            "postgres://postgres@127.0.0.1:5432/vint?sslmode=require",
            "postgres://vint@db.example.org:5432/vint",
            "postgres://vint@10.0.0.5/vint",
            "postgres:///vint?host=/var/run/postgresql",
        ] {
            assert_eq!(postgres_url(url, None), url);
        }
        assert_eq!(postgres_url("postgres://127.0.0.1/vint", Some("prefer")), "postgres://127.0.0.1/vint");
    }
}
