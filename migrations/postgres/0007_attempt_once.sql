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

-- The rows written per task and per sample reference their task without a foreign key: the store
-- writes an attempt, an artifact or a sample only from the task row it has fenced in the same
-- statement, and nothing deletes tasks. Each check cost a row lock on the task (FOR KEY SHARE)
-- per row written: 10–19 % of a lease + complete cycle in raw SQL, and one per artifact, 14 per
-- sample. Dependencies (task_deps) and tasks' jobs keep theirs: they are written with the tasks.
ALTER TABLE attempts DROP CONSTRAINT attempts_task_id_fkey;
ALTER TABLE artifacts DROP CONSTRAINT artifacts_task_id_fkey;
ALTER TABLE samples DROP CONSTRAINT samples_job_id_fkey;
ALTER TABLE samples DROP CONSTRAINT samples_package_task_id_fkey;
