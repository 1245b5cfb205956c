-- Task reuse by content (vint_core::reuse): each task's reuse key, written when a worker that
-- declares its engine's identity leases it, and the task whose finished result a task took instead
-- of running.
--
-- A task whose key matches a succeeded task's (of any job) is completed from that task's result
-- and outputs without running: `reused_from` names it, and no attempt row is written. The keys live
-- in a table of their own, not in a column of `tasks`: a partial index on `tasks` cost every task
-- update ~17 % of the batch-256 completion rate even with no key set (docs/benchmarks.md), while
-- tasks leased by a worker that declares no identity (the timing-only worker) write no row here.
ALTER TABLE tasks ADD COLUMN reused_from TEXT;

CREATE TABLE task_keys (
    task_id      TEXT PRIMARY KEY,  -- no foreign key, as attempts and artifacts (migration 0007)
    content_key  TEXT NOT NULL
);
CREATE INDEX task_keys_by_key ON task_keys (content_key);
