-- (Postgres replaces the artifacts' primary key on (task_id, name) with a plain index on task_id
-- here, to save its bytes: migrations/postgres/0012_artifacts_by_task.sql. SQLite cannot drop a
-- primary key without rebuilding the table, which its dashboard views depend on; the embedded
-- store is small, and keeps the key: the same rule, checked twice.)
SELECT 1;
