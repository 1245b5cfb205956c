-- An attempt is written once, when it ends (issue 11): the running attempt lives in its task's
-- row (state 'running', lease_owner, attempt, and leased_ms, when it was leased), so a lease and
-- its completion write one attempts row instead of inserting one and updating it.
ALTER TABLE tasks ADD COLUMN leased_ms BIGINT;

-- Attempts running at the upgrade move into their tasks' rows; their rows are written again
-- when they end.
UPDATE tasks SET leased_ms = (
    SELECT a.started_ms FROM attempts a WHERE a.task_id = tasks.id AND a.attempt = tasks.attempt
) WHERE state = 'running';
DELETE FROM attempts WHERE ended_ms IS NULL;

-- (Postgres also drops the foreign keys of attempts, artifacts and samples here, whose checks
-- cost a row lock per row written; SQLite cannot drop a constraint without rebuilding the table,
-- and the embedded store is small.)
