-- The queue's shared statements (`queue/mod.rs`): the planner's statistics, attempts, running tasks.

-- name: stale_statistics
-- None: SQLite keeps no live row counts to compare; the embedded store's tables stay small
-- enough that its planner needs no refreshed statistics (`Store::refresh_statistics` does
-- nothing there).

-- name: analyze_tasks
-- None: see stale_statistics.

-- name: analyze_task_deps
-- None: see stale_statistics.

-- name: analyze_attempts
-- None: see stale_statistics.

-- name: analyze_outputs
-- None: see stale_statistics.

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
