-- Completing tasks: fenced, batched, with their outputs, attempts and what they unlock
-- (`queue/complete.rs`). A batch's fences are the JSON rows of $4 (id, worker, attempt, engine,
-- result, timings, reused) and its packed outputs those of $6 (task, files as hex, count, bytes,
-- samples). The fence: only a running task ($2) leased to the caller, at this attempt, completes;
-- a lease past its deadline still does until the reaper has taken it (`queue/mod.rs`).

-- name: complete_ran
-- Completes the fenced tasks a worker ran, at $3, in state $1: in ONE statement of data-modifying
-- CTEs keyed on the fenced rows, their attempts (outcome $5), their outputs, and their
-- dependents' counts of pending dependencies, queuing ($8) the waiting ($7) ones with none left.
-- Dependents are locked in id order, so two completions never wait on each other's rows in
-- opposite orders. Returns the completed tasks with their jobs.
WITH c AS (
  SELECT * FROM jsonb_to_recordset($4::jsonb)
    AS c(id text, worker text, attempt bigint, engine text, result text, timings text, reused text)
), done AS (
  UPDATE tasks SET state = $1, lease_owner = NULL, lease_deadline_ms = NULL, engine_json = c.engine,
                   result_json = c.result, updated_ms = $3
  FROM c
  WHERE tasks.id = c.id AND tasks.state = $2 AND tasks.lease_owner = c.worker AND tasks.attempt = c.attempt
  RETURNING tasks.id, tasks.job_id, tasks.attempt, tasks.leased_ms
), ended AS (
  INSERT INTO attempts (task_id, attempt, worker_id, started_ms, ended_ms, outcome, engine_json, timings_json)
  SELECT done.id, done.attempt, c.worker, COALESCE(done.leased_ms, $3), $3, $5, c.engine, c.timings
  FROM done JOIN c ON c.id = done.id
), outputs AS (
  INSERT INTO outputs (task_id, files, count, bytes, samples)
  SELECT o.task, decode(o.files, 'hex'), o.count, o.bytes, o.samples
  FROM jsonb_to_recordset($6::jsonb) AS o(task text, files text, count bigint, bytes bigint, samples bigint)
  JOIN done ON done.id = o.task
), finished AS (
  SELECT d.task_id, COUNT(*) AS n FROM done JOIN task_deps d ON d.depends_on = done.id GROUP BY d.task_id
), waiting AS (
  SELECT t.id, finished.n FROM tasks t JOIN finished ON finished.task_id = t.id ORDER BY t.id FOR UPDATE OF t
), unblocked AS (
  UPDATE tasks SET deps_pending = tasks.deps_pending - w.n,
                   state = CASE WHEN tasks.state = $7 AND tasks.deps_pending - w.n = 0 THEN $8 ELSE tasks.state END,
                   updated_ms = $3
  FROM waiting w WHERE tasks.id = w.id
)
SELECT id, job_id FROM done;

-- name: complete_reused
-- `complete_ran` for tasks that took another task's result (`reused`): no attempt ran, none is
-- recorded, and the attempt the lease counted is given back. Its own statement, so that the
-- completions of tasks that ran keep theirs as lean as they were (a `reused_from` and an attempt
-- adjustment in the shared statement cost ~17 % of the batch-256 rate). $5 is still bound: a
-- statement may leave a parameter unused only if it is typed.
WITH c AS (
  SELECT * FROM jsonb_to_recordset($4::jsonb)
    AS c(id text, worker text, attempt bigint, engine text, result text, timings text, reused text)
), done AS (
  UPDATE tasks SET state = $1, lease_owner = NULL, lease_deadline_ms = NULL, engine_json = c.engine,
                   result_json = c.result, reused_from = c.reused, attempt = tasks.attempt - 1, updated_ms = $3
  FROM c
  WHERE tasks.id = c.id AND tasks.state = $2 AND tasks.lease_owner = c.worker AND tasks.attempt = c.attempt
  RETURNING tasks.id, tasks.job_id, tasks.attempt, tasks.leased_ms
), ended AS (
  SELECT CAST($5 AS TEXT) AS outcome
), outputs AS (
  INSERT INTO outputs (task_id, files, count, bytes, samples)
  SELECT o.task, decode(o.files, 'hex'), o.count, o.bytes, o.samples
  FROM jsonb_to_recordset($6::jsonb) AS o(task text, files text, count bigint, bytes bigint, samples bigint)
  JOIN done ON done.id = o.task
), finished AS (
  SELECT d.task_id, COUNT(*) AS n FROM done JOIN task_deps d ON d.depends_on = done.id GROUP BY d.task_id
), waiting AS (
  SELECT t.id, finished.n FROM tasks t JOIN finished ON finished.task_id = t.id ORDER BY t.id FOR UPDATE OF t
), unblocked AS (
  UPDATE tasks SET deps_pending = tasks.deps_pending - w.n,
                   state = CASE WHEN tasks.state = $7 AND tasks.deps_pending - w.n = 0 THEN $8 ELSE tasks.state END,
                   updated_ms = $3
  FROM waiting w WHERE tasks.id = w.id
)
SELECT id, job_id FROM done;

-- name: fence_ran
-- None: part of complete_ran.

-- name: fence_reused
-- None: part of complete_reused.

-- name: insert_outputs
-- None: part of complete_ran and complete_reused.

-- name: insert_succeeded_attempts
-- None: part of complete_ran.

-- name: unblock_dependents
-- None: part of complete_ran and complete_reused.
