-- A task's outputs packed in one row (issue 21): `artifacts` held a row per file (~300 bytes with
-- its index entry, 14 files a sample: most of a sample's database bytes on the 2 M run,
-- docs/benchmarks.md). `files` is vint_store's packed format (services/store/src/outputs.rs:
-- names front-coded, hashes as 32 bytes, object keys and times derived, not stored); `count` and
-- `bytes` let SQL (the dashboard) total a job's files without reading them.
--
-- The table `samples` goes too (318 bytes a sample on the 2 M run, with its two indexes): a
-- package task's files are named `<sample id>/<file>`, so its row lists its samples already, and a
-- sample's package task is found from its id (object, hand) among the few of its pair.
--
-- Existing rows are packed by the store when it migrates (`Store::migrate`, in Rust: the format is
-- not SQL's to write), which then drops `artifacts`. Stop coordinators older than this migration
-- before applying it: they write `artifacts`.
CREATE TABLE outputs (
    task_id  TEXT PRIMARY KEY,  -- no foreign key, as attempts (migration 0007)
    files    BYTEA NOT NULL,
    count    BIGINT NOT NULL,
    bytes    BIGINT NOT NULL,
    samples  BIGINT NOT NULL   -- the samples a package task made (its files' first path segments)
);

-- Stored out of line when large, never compressed: a row is mostly SHA-256 digests, which pglz
-- cannot shrink (Postgres then stores the row as it is, after trying), and the timing-only
-- worker's constant payloads share one digest per file kind, which it would shrink ~5× and so
-- make benches/dispatch.sh under-report what real rows take (docs/benchmarks.md).
ALTER TABLE outputs ALTER COLUMN files SET STORAGE EXTERNAL;

-- The dashboard's files and bytes per job and stage, now from the packed rows.
CREATE OR REPLACE VIEW dashboard.bytes_written AS
SELECT t.job_id, t.stage, CAST(SUM(o.count) AS BIGINT) AS files, CAST(SUM(o.bytes) AS BIGINT) AS bytes
FROM outputs o JOIN tasks t ON t.id = o.task_id
GROUP BY t.job_id, t.stage;

DROP TABLE samples;
