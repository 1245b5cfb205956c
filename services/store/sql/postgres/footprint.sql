-- The database's rows (`footprint.rs`): what the footprint model predicts, counted.

-- name: table_rows
-- Rows in each table over every job, in `TableRows::TABLES` order (`outputs_files`: the files the
-- packed `outputs` rows hold).
SELECT (SELECT COUNT(*) FROM jobs) AS jobs,
       (SELECT COUNT(*) FROM job_assets) AS job_assets,
       (SELECT COUNT(*) FROM tasks) AS tasks,
       (SELECT COUNT(*) FROM task_deps) AS task_deps,
       (SELECT COUNT(*) FROM attempts) AS attempts,
       (SELECT COUNT(*) FROM outputs) AS outputs,
       (SELECT CAST(COALESCE(SUM(count), 0) AS BIGINT) FROM outputs) AS outputs_files,
       (SELECT COUNT(*) FROM task_keys) AS task_keys;
