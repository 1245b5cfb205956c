-- Leasing ready tasks with their inputs, and heartbeats (`queue/lease.rs`).
--
-- A worker's row in `workers` (migration 0008, the dashboard's `workers` view) records what it
-- asked for and when: an idle worker polls twice a second, so its row is written at most once a
-- second (1000 ms below) or when its stages change. SQLite has one writer, so nothing here locks
-- rows; without data-modifying CTEs, what Postgres does in one statement takes several.

-- name: lease_tasks
-- Leases up to $5 queued tasks of the stages $6 (comma-separated) to worker $2: state $1, until $3,
-- at $4. The attempt is written when it ends; until then the task's row is its record.
UPDATE tasks SET state = $1, attempt = attempt + 1, lease_owner = $2, lease_deadline_ms = $3, leased_ms = $4,
                 updated_ms = $4
WHERE id IN (SELECT id FROM tasks
             WHERE state = 'queued' AND not_before_ms <= $4 AND instr(',' || $6 || ',', ',' || stage || ',') > 0
             ORDER BY priority, created_ms, id LIMIT $5)
RETURNING id, job_id, key, stage, attempt, params_json, lease_deadline_ms;

-- name: lease_tasks_timing_only
-- `lease_tasks` for a timing-only worker: only tasks of jobs submitted with `timing_only`
-- (`jobs.timing_only`, migration 0014). Its own statement, so that the leases of real workers stay as they were.
-- Leases up to $5 queued tasks of the stages $6 (comma-separated) to worker $2: state $1, until $3,
-- at $4. The attempt is written when it ends; until then the task's row is its record.
UPDATE tasks SET state = $1, attempt = attempt + 1, lease_owner = $2, lease_deadline_ms = $3, leased_ms = $4,
                 updated_ms = $4
WHERE id IN (SELECT id FROM tasks
             WHERE state = 'queued' AND not_before_ms <= $4 AND instr(',' || $6 || ',', ',' || stage || ',') > 0
               AND job_id IN (SELECT id FROM jobs WHERE timing_only = 1)
             ORDER BY priority, created_ms, id LIMIT $5)
RETURNING id, job_id, key, stage, attempt, params_json, lease_deadline_ms;

-- name: worker_seen_update
-- Records that worker $1 asked for tasks of the stages $2 at $3, if its row is a second old or
-- its stages changed.
UPDATE workers SET stages = $2, last_seen_ms = $3
WHERE id = $1 AND (last_seen_ms <= $3 - 1000 OR stages <> $2);

-- name: worker_seen_insert
-- The row of a worker not seen before.
INSERT INTO workers (id, stages, first_seen_ms, last_seen_ms)
SELECT $1, $2, $3, $3 WHERE NOT EXISTS (SELECT 1 FROM workers WHERE id = $1)
ON CONFLICT (id) DO NOTHING;

-- name: lease_inputs
-- The inputs of the tasks of the JSON array $1: their dependencies' packed outputs, by task.
-- Inputs are outputs of succeeded tasks, which never change: read after the lease.
SELECT d.task_id AS consumer, o.task_id, t.key, o.files
FROM task_deps d JOIN outputs o ON o.task_id = d.depends_on JOIN tasks t ON t.id = o.task_id
WHERE d.task_id IN (SELECT value FROM json_each($1))
ORDER BY d.task_id, t.key;

-- name: worker_heartbeat
-- Records that worker $1 heartbeated at $2 (its stages stay those of its last lease).
UPDATE workers SET last_seen_ms = $2, last_heartbeat_ms = $2 WHERE id = $1;

-- name: heartbeat
-- Extends to $1 the leases worker $4 still holds among the JSON rows $5 (id, attempt), at $2
-- (state $3: running); returns the leases kept.
WITH h AS (
  SELECT json_extract(value, '$.id') AS id, json_extract(value, '$.attempt') AS attempt FROM json_each($5)
), kept AS (
  SELECT t.id FROM tasks t JOIN h ON h.id = t.id
  WHERE t.state = $3 AND t.lease_owner = $4 AND t.attempt = h.attempt
)
UPDATE tasks SET lease_deadline_ms = $1, updated_ms = $2 FROM kept WHERE tasks.id = kept.id
RETURNING tasks.id, tasks.attempt;
