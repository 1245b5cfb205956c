-- Completing tasks: fenced, batched, with their outputs, attempts and what they unlock
-- (`queue/complete.rs`). Without data-modifying CTEs, what Postgres does in one statement takes
-- the fence and up to three statements after it, in one transaction. The fence: only a running
-- task ($2) leased to the caller, at this attempt, completes; a lease past its deadline still
-- does until the reaper has taken it (`queue/mod.rs`).

-- name: complete_ran
-- None: SQLite has no data-modifying CTEs; fence_ran and the statements after it.

-- name: complete_reused
-- None: SQLite has no data-modifying CTEs; fence_reused and the statements after it.

-- name: fence_ran
-- Completes at $3, in state $1, the fenced tasks a worker ran among the JSON rows $4 (id, worker,
-- attempt, engine, result, timings, reused); returns them with their jobs.
UPDATE tasks SET state = $1, lease_owner = NULL, lease_deadline_ms = NULL, engine_json = c.engine,
                 result_json = c.result, updated_ms = $3
FROM (SELECT json_extract(value, '$.id') AS id, json_extract(value, '$.worker') AS worker,
             json_extract(value, '$.attempt') AS attempt, json_extract(value, '$.engine') AS engine,
             json_extract(value, '$.result') AS result
      FROM json_each($4)) AS c
WHERE tasks.id = c.id AND tasks.state = $2 AND tasks.lease_owner = c.worker AND tasks.attempt = c.attempt
RETURNING tasks.id, tasks.job_id;

-- name: fence_reused
-- `fence_ran` for tasks that took another task's result (`reused`): no attempt ran, and the
-- attempt the lease counted is given back.
UPDATE tasks SET state = $1, lease_owner = NULL, lease_deadline_ms = NULL, engine_json = c.engine,
                 result_json = c.result, reused_from = c.reused, attempt = tasks.attempt - 1, updated_ms = $3
FROM (SELECT json_extract(value, '$.id') AS id, json_extract(value, '$.worker') AS worker,
             json_extract(value, '$.attempt') AS attempt, json_extract(value, '$.engine') AS engine,
             json_extract(value, '$.result') AS result, json_extract(value, '$.reused') AS reused
      FROM json_each($4)) AS c
WHERE tasks.id = c.id AND tasks.state = $2 AND tasks.lease_owner = c.worker AND tasks.attempt = c.attempt
RETURNING tasks.id, tasks.job_id;

-- name: insert_outputs
-- The packed outputs of completed tasks, the JSON rows $1 (task, files as hex, count, bytes,
-- samples).
INSERT INTO outputs (task_id, files, count, bytes, samples)
SELECT json_extract(value, '$.task'), unhex(json_extract(value, '$.files')), json_extract(value, '$.count'),
       json_extract(value, '$.bytes'), json_extract(value, '$.samples')
FROM json_each($1);

-- name: insert_succeeded_attempts
-- The attempts of the completed tasks among the JSON rows $3, ended at $1 with outcome $2
-- (the task's row still holds when it was leased).
INSERT INTO attempts (task_id, attempt, worker_id, started_ms, ended_ms, outcome, engine_json, timings_json)
SELECT e.id, e.attempt, e.worker, COALESCE(t.leased_ms, $1), $1, $2, e.engine, e.timings
FROM (SELECT json_extract(value, '$.id') AS id, json_extract(value, '$.worker') AS worker,
             json_extract(value, '$.attempt') AS attempt, json_extract(value, '$.engine') AS engine,
             json_extract(value, '$.timings') AS timings
      FROM json_each($3)) AS e
JOIN tasks t ON t.id = e.id;

-- name: unblock_dependents
-- Counts the success of the tasks of the JSON array $4 in their dependents, at $3, and queues ($2)
-- the waiting ($1) ones with no dependency left.
UPDATE tasks SET deps_pending = deps_pending - n.done,
                 state = CASE WHEN state = $1 AND deps_pending - n.done = 0 THEN $2 ELSE state END,
                 updated_ms = $3
FROM (SELECT task_id, COUNT(*) AS done FROM task_deps
      WHERE depends_on IN (SELECT value FROM json_each($4)) GROUP BY task_id) AS n
WHERE tasks.id = n.task_id;
