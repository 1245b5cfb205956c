-- Task reuse by content: each task's reuse key, and the task whose result a task took instead of
-- running; the same as migrations/postgres/0011_task_reuse.sql.
ALTER TABLE tasks ADD COLUMN reused_from TEXT;

CREATE TABLE task_keys (
    task_id      TEXT PRIMARY KEY,
    content_key  TEXT NOT NULL
);
CREATE INDEX task_keys_by_key ON task_keys (content_key);
