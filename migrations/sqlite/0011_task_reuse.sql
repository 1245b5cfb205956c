-- Task reuse by content: each task's reuse key and the task whose result it took instead of
-- running; the same as migrations/postgres/0011_task_reuse.sql.
ALTER TABLE tasks ADD COLUMN content_key TEXT;
ALTER TABLE tasks ADD COLUMN reused_from TEXT;
CREATE INDEX tasks_by_content_key ON tasks (content_key) WHERE content_key IS NOT NULL;
