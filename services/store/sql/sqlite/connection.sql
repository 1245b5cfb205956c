-- Connections and the schema: what `lib.rs` runs when it connects, migrates and answers health.

-- name: on_connect
-- Run on the one connection: write-ahead logging (readers do not wait for the writer), commits
-- that survive a process crash (NORMAL: not a power loss, which the embedded default accepts),
-- foreign keys enforced, and a wait of up to 10 s for a lock instead of SQLITE_BUSY.
PRAGMA journal_mode = WAL;
PRAGMA synchronous = NORMAL;
PRAGMA foreign_keys = ON;
PRAGMA busy_timeout = 10000;

-- name: migrations_table_exists
-- Whether sqlx's migration table exists (`n` is 0 or 1).
SELECT COUNT(*) AS n FROM sqlite_master WHERE type = 'table' AND name = '_sqlx_migrations';

-- name: applied_migrations
-- The versions of the migrations applied to the database.
SELECT version FROM _sqlx_migrations WHERE success ORDER BY version;

-- name: connection_encrypted
-- None: a SQLite database is a local file, with no connection to encrypt (`Store::encrypted`
-- answers `None`).

-- name: ping
-- A trivial query: the embedded store's health.
SELECT 1;
