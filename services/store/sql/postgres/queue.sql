-- The queue's shared statements (`queue/mod.rs`): the planner's statistics, attempts, running tasks.

-- name: stale_statistics
-- The tables a running job grows that hold twice the rows their last analysis counted (or were
-- never analyzed): a job grows `outputs` from nothing to millions of rows faster than autovacuum's
-- analyze follows, and a plan made with no statistics scans the whole table for each leased task's
-- inputs.
SELECT s.relname::text AS relname
FROM pg_stat_user_tables s JOIN pg_class c ON c.oid = s.relid
WHERE s.relname IN ('tasks', 'task_deps', 'attempts', 'outputs')
  AND s.n_live_tup > 1000 + 2 * greatest(c.reltuples, 0)
ORDER BY s.relname;

-- name: analyze_tasks
-- Fresh statistics for `tasks` (an analysis also replaces the cached plans that read it).
ANALYZE tasks;

-- name: analyze_task_deps
-- Fresh statistics for `task_deps`.
ANALYZE task_deps;

-- name: analyze_attempts
-- Fresh statistics for `attempts`.
ANALYZE attempts;

-- name: analyze_outputs
-- Fresh statistics for `outputs`.
ANALYZE outputs;

-- name: task_attempts
-- A task's attempts, oldest first: the ended ones are rows of `attempts`, a running one is its
-- task's row.
SELECT task_id, attempt, worker_id, started_ms, ended_ms, outcome, error FROM attempts WHERE task_id = $1
UNION ALL
SELECT id, attempt, lease_owner, COALESCE(leased_ms, updated_ms), NULL, NULL, NULL FROM tasks
WHERE id = $1 AND state = 'running'
ORDER BY attempt;

-- name: tasks_in_state
-- The tasks in state $1, by id (the running ones, for tests and operators).
SELECT id, job_id, key, stage, state, params_json, attempt, max_attempts, not_before_ms, lease_owner,
       lease_deadline_ms, last_error, engine_json, result_json, reused_from
FROM tasks WHERE state = $1 ORDER BY id;

-- name: insert_ended_attempt
-- The attempt $7 of task $6 ends at $1 with outcome $2, error $3, engine $4 and timings $5; run
-- before the task's row leaves `running`, which holds when the attempt started.
INSERT INTO attempts (task_id, attempt, worker_id, started_ms, ended_ms, outcome, error, engine_json, timings_json)
SELECT id, attempt, lease_owner, COALESCE(leased_ms, $1), $1, $2, $3, $4, $5 FROM tasks
WHERE id = $6 AND attempt = $7;

-- name: leases_held_by
-- How many running tasks are leased to a worker whose id starts with $1 (a token's `NAME/`),
-- through the partial index `tasks_leased`.
SELECT COUNT(*) AS n FROM tasks WHERE state = 'running' AND substr(lease_owner, 1, length($1)) = $1;
