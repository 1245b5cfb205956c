-- Jobs and their tasks: submit, read, progress, cancel, finalize, and inserting planned tasks
-- (`jobs.rs`). A batch travels as one JSON parameter, read as rows with `json_each`.

-- name: insert_job
-- A submitted job; nothing when its idempotency key is taken (a concurrent submit won).
INSERT INTO jobs (id, name, seed, spec_toml, plan_json, idempotency_key, state, created_ms, timing_only,
                  submitted_by)
VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10)
ON CONFLICT (idempotency_key) DO NOTHING;

-- name: insert_job_asset
-- One user file a job's spec names.
INSERT INTO job_assets (job_id, path, sha256, size, media_type, object_key) VALUES ($1, $2, $3, $4, $5, $6);

-- name: job_by_idempotency_key
-- The job submitted with this idempotency key.
SELECT id, name, seed, spec_toml, plan_json, state, created_ms, finished_ms, timing_only FROM jobs WHERE idempotency_key = $1;

-- name: job_by_id
-- One job.
SELECT id, name, seed, spec_toml, plan_json, state, created_ms, finished_ms, timing_only FROM jobs WHERE id = $1;

-- name: jobs_newest_first
-- Up to $1 jobs, the most recent first.
SELECT id, name, seed, spec_toml, plan_json, state, created_ms, finished_ms, timing_only FROM jobs
ORDER BY created_ms DESC, id LIMIT $1;

-- name: job_assets
-- A job's user files, by path.
SELECT path, sha256, size, media_type, object_key FROM job_assets WHERE job_id = $1 ORDER BY path;

-- name: user_files_with
-- Submitted user files with the content $1, of job $2 ('': of every job).
SELECT job_id, path, sha256, size, media_type, object_key FROM job_assets
WHERE sha256 = $1 AND ($2 = '' OR job_id = $2)
ORDER BY job_id, path;

-- name: progress_counts
-- The tasks of the jobs of the JSON array $1 by job, stage and state, with how
-- many of them were reused: one statement for a page of jobs, not one per job.
SELECT job_id, stage, state, COUNT(*) AS n, COUNT(reused_from) AS reused FROM tasks
WHERE job_id IN (SELECT value FROM json_each($1))
GROUP BY job_id, stage, state;

-- name: progress_samples
-- The samples the package tasks ($2: the stage) of the jobs of the JSON array $1 made, by job:
-- their outputs rows count them.
SELECT t.job_id, CAST(COALESCE(SUM(o.samples), 0) AS BIGINT) AS n
FROM tasks t JOIN outputs o ON o.task_id = t.id
WHERE t.job_id IN (SELECT value FROM json_each($1)) AND t.stage = $2
GROUP BY t.job_id;

-- name: end_job
-- Ends job $3 in state $1 at $2, if it is still in state $4.
UPDATE jobs SET state = $1, finished_ms = $2 WHERE id = $3 AND state = $4;

-- name: cancel_running_attempts
-- The running attempts of a cancelled job end as cancelled ($2), written once like every attempt.
INSERT INTO attempts (task_id, attempt, worker_id, started_ms, ended_ms, outcome)
SELECT id, attempt, lease_owner, COALESCE(leased_ms, $1), $1, $2 FROM tasks
WHERE job_id = $3 AND state = $4;

-- name: cancel_live_tasks
-- A cancelled job's waiting, queued and running tasks ($4, $5, $6) become cancelled ($1).
UPDATE tasks SET state = $1, lease_owner = NULL, lease_deadline_ms = NULL, updated_ms = $2
WHERE job_id = $3 AND state IN ($4, $5, $6);

-- name: finished_jobs
-- Running jobs ($2) none of whose tasks waits, is queued or runs ($3, $4, $5), with how many of
-- their tasks failed ($1).
SELECT j.id, (SELECT COUNT(*) FROM tasks t WHERE t.job_id = j.id AND t.state = $1) AS failed
FROM jobs j
WHERE j.state = $2
  AND NOT EXISTS (SELECT 1 FROM tasks t WHERE t.job_id = j.id AND t.state IN ($3, $4, $5));

-- name: finished_jobs_among
-- `finished_jobs` among the jobs of the JSON array $6: what a batch of completions may finish.
SELECT j.id, (SELECT COUNT(*) FROM tasks t WHERE t.job_id = j.id AND t.state = $1) AS failed
FROM jobs j
WHERE j.state = $2
  AND j.id IN (SELECT value FROM json_each($6))
  AND NOT EXISTS (SELECT 1 FROM tasks t WHERE t.job_id = j.id AND t.state IN ($3, $4, $5));

-- name: task_by_id
-- One task.
SELECT id, job_id, key, stage, state, params_json, attempt, max_attempts, not_before_ms, lease_owner,
       lease_deadline_ms, last_error, engine_json, result_json, reused_from
FROM tasks WHERE id = $1;

-- name: tasks_by_ids
-- The tasks among the JSON array of ids $1 that exist.
SELECT id, job_id, key, stage, state, params_json, attempt, max_attempts, not_before_ms, lease_owner,
       lease_deadline_ms, last_error, engine_json, result_json, reused_from
FROM tasks WHERE id IN (SELECT value FROM json_each($1));

-- name: tasks_of_job
-- A job's tasks, by key.
SELECT id, job_id, key, stage, state, params_json, attempt, max_attempts, not_before_ms, lease_owner,
       lease_deadline_ms, last_error, engine_json, result_json, reused_from
FROM tasks WHERE job_id = $1 ORDER BY key;

-- name: tasks_in_state_among
-- The ids among the JSON array $2 of tasks in state $1 (the dependencies of new tasks that
-- have succeeded already).
SELECT id FROM tasks WHERE state = $1 AND id IN (SELECT value FROM json_each($2));

-- name: insert_tasks
-- Planned tasks of job $1, the JSON rows $4, each with its state and the count of dependencies
-- it still waits for; a task already present is skipped. Returns the ids inserted.
INSERT INTO tasks (id, job_id, key, stage, priority, params_json, state, deps_pending, max_attempts,
                   created_ms, updated_ms)
SELECT n.id, $1, n.key, n.stage, n.priority, n.params, n.state, n.pending, $2, $3, $3
FROM (SELECT json_extract(value, '$.id') AS id, json_extract(value, '$.key') AS key,
             json_extract(value, '$.stage') AS stage, json_extract(value, '$.priority') AS priority,
             json_extract(value, '$.params') AS params, json_extract(value, '$.state') AS state,
             json_extract(value, '$.pending') AS pending
      FROM json_each($4)) AS n
WHERE true
ON CONFLICT (id) DO NOTHING
RETURNING id;

-- name: insert_task_deps
-- Dependency edges, the JSON rows $1 (`task` depends on `dep`).
INSERT INTO task_deps (task_id, depends_on)
SELECT e.task, e.dep
FROM (SELECT json_extract(value, '$.task') AS task, json_extract(value, '$.dep') AS dep FROM json_each($1)) AS e
WHERE true
ON CONFLICT DO NOTHING;

-- name: running_jobs_submitted_by
-- How many jobs the token named $1 submitted are still running (migration 0014's partial index).
SELECT COUNT(*) AS n FROM jobs WHERE submitted_by = $1 AND state = 'running';

-- name: delete_job_attempts
-- Deleting job $1 (`Store::delete_job`), children first: its tasks' attempts.
DELETE FROM attempts WHERE task_id IN (SELECT id FROM tasks WHERE job_id = $1);

-- name: delete_job_outputs
-- Its tasks' packed outputs (the objects they name stay until `vintctl gc` finds them unreferenced).
DELETE FROM outputs WHERE task_id IN (SELECT id FROM tasks WHERE job_id = $1);

-- name: delete_job_task_keys
-- Its tasks' reuse keys: no later job reuses a deleted job's results.
DELETE FROM task_keys WHERE task_id IN (SELECT id FROM tasks WHERE job_id = $1);

-- name: delete_job_task_deps
-- Its dependency edges (both ends are its own tasks).
DELETE FROM task_deps WHERE task_id IN (SELECT id FROM tasks WHERE job_id = $1);

-- name: delete_job_tasks
-- Its tasks.
DELETE FROM tasks WHERE job_id = $1;

-- name: delete_job_assets
-- Its submitted files' records.
DELETE FROM job_assets WHERE job_id = $1;

-- name: delete_job_row
-- The job itself.
DELETE FROM jobs WHERE id = $1;
