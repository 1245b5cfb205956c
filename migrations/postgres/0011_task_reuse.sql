-- Task reuse by content (vint_core::reuse): a task's reuse key, set when a worker that declares its
-- engine's identity leases it, and the task whose finished result it took instead of running.
--
-- A task whose key matches a succeeded task's (of any job) is completed from that task's result
-- and outputs without running: `reused_from` names it, and no attempt row is written. Tasks leased
-- by a worker that declares no identity (the timing-only worker) get no key and are never reused
-- nor reusable: they write no index entry.
ALTER TABLE tasks ADD COLUMN content_key TEXT;
ALTER TABLE tasks ADD COLUMN reused_from TEXT;
CREATE INDEX tasks_by_content_key ON tasks (content_key) WHERE content_key IS NOT NULL;
