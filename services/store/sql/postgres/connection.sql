-- Connections and the schema: what `lib.rs` runs when it connects, migrates and answers health.

-- name: on_connect
-- Run on every new connection. Plan each execution with its values: task states are skewed (a
-- job's few failed or running tasks among millions succeeded), and a generic plan estimates every
-- state alike (measured on a 2 M-sample job: with cached generic plans, the per-batch check whether
-- a job finished and the progress counts grew to 0.5 s each and samples/s fell from 2,400 to 1,300;
-- with custom plans it held ~2,800 to the end, docs/benchmarks.md). Every statement of the store
-- is a few index lookups per row of a batch: no JIT either.
SET plan_cache_mode = force_custom_plan;
SET jit = off;

-- name: migrations_table_exists
-- Whether sqlx's migration table exists (`n` is 0 or 1).
SELECT COUNT(*) AS n FROM pg_tables WHERE tablename = '_sqlx_migrations' AND schemaname = current_schema();

-- name: applied_migrations
-- The versions of the migrations applied to the database.
SELECT version FROM _sqlx_migrations WHERE success ORDER BY version;

-- name: connection_encrypted
-- Whether this connection is encrypted (TLS), as the server sees it.
SELECT ssl FROM pg_stat_ssl WHERE pid = pg_backend_pid();

-- name: ping
-- A trivial query: the coordinator's health.
SELECT 1;
