-- A task's outputs packed in one row: the same as migrations/postgres/0013_packed_outputs.sql
-- (existing rows are packed by `Store::migrate`, which then drops `artifacts`); `samples` goes.
CREATE TABLE outputs (
    task_id  TEXT PRIMARY KEY,
    files    BLOB NOT NULL,
    count    BIGINT NOT NULL,
    bytes    BIGINT NOT NULL,
    samples  BIGINT NOT NULL   -- the samples a package task made (its files' first path segments)
);

DROP VIEW dashboard_bytes_written;
CREATE VIEW dashboard_bytes_written AS
SELECT t.job_id, t.stage, SUM(o.count) AS files, SUM(o.bytes) AS bytes
FROM outputs o JOIN tasks t ON t.id = o.task_id
GROUP BY t.job_id, t.stage;

DROP TABLE samples;
