-- Leasing ready tasks with their inputs, and heartbeats (`queue/lease.rs`).
--
-- A worker's row in `workers` (migration 0008, the dashboard's `workers` view) records what it
-- asked for and when: an idle worker polls twice a second, so its row is written at most once a
-- second (1000 ms below) or when its stages change, and a poll that writes nothing locks nothing
-- (an upsert would lock the row, and make every empty poll a commit that waits for WAL).

-- name: lease_tasks
-- Leases up to $5 queued tasks of the stages $6 (comma-separated) to worker $2: state $1, until $3,
-- at $4; in the same statement the worker is recorded as seen and every leased task's inputs (its
-- dependencies' packed outputs, the bytes as hex) are read. The attempt is written when it ends;
-- until then the task's row is its record. Concurrent coordinators never lease the same task
-- (SKIP LOCKED).
WITH seen AS (
  UPDATE workers SET stages = $6, last_seen_ms = $4
  WHERE id = $2 AND (last_seen_ms <= $4 - 1000 OR stages <> $6)
), new_worker AS (
  INSERT INTO workers (id, stages, first_seen_ms, last_seen_ms)
  SELECT $2, $6, $4, $4 WHERE NOT EXISTS (SELECT 1 FROM workers WHERE id = $2)
  ON CONFLICT (id) DO NOTHING
), leased AS (
  UPDATE tasks SET state = $1, attempt = attempt + 1, lease_owner = $2, lease_deadline_ms = $3, leased_ms = $4,
                   updated_ms = $4
  WHERE id IN (SELECT id FROM tasks
               WHERE state = 'queued' AND not_before_ms <= $4 AND stage = ANY (string_to_array($6, ','))
               ORDER BY priority, created_ms, id LIMIT $5
               FOR UPDATE SKIP LOCKED)
  RETURNING id, job_id, key, stage, attempt, params_json, lease_deadline_ms
)
SELECT leased.*,
       (SELECT COALESCE(json_agg(json_build_object('task_id', o.task_id, 'key', t.key,
                                                   'files', encode(o.files, 'hex')) ORDER BY t.key), '[]')::text
        FROM task_deps d JOIN outputs o ON o.task_id = d.depends_on JOIN tasks t ON t.id = o.task_id
        WHERE d.task_id = leased.id) AS inputs_json
FROM leased;

-- name: lease_tasks_timing_only
-- `lease_tasks` for a timing-only worker: only tasks of jobs submitted with `timing_only`
-- (`jobs.timing_only`, migration 0014). Its own statement, so that the leases of real workers stay as they were.
-- Leases up to $5 queued tasks of the stages $6 (comma-separated) to worker $2: state $1, until $3,
-- at $4; in the same statement the worker is recorded as seen and every leased task's inputs (its
-- dependencies' packed outputs, the bytes as hex) are read. The attempt is written when it ends;
-- until then the task's row is its record. Concurrent coordinators never lease the same task
-- (SKIP LOCKED).
WITH seen AS (
  UPDATE workers SET stages = $6, last_seen_ms = $4
  WHERE id = $2 AND (last_seen_ms <= $4 - 1000 OR stages <> $6)
), new_worker AS (
  INSERT INTO workers (id, stages, first_seen_ms, last_seen_ms)
  SELECT $2, $6, $4, $4 WHERE NOT EXISTS (SELECT 1 FROM workers WHERE id = $2)
  ON CONFLICT (id) DO NOTHING
), leased AS (
  UPDATE tasks SET state = $1, attempt = attempt + 1, lease_owner = $2, lease_deadline_ms = $3, leased_ms = $4,
                   updated_ms = $4
  WHERE id IN (SELECT id FROM tasks
               WHERE state = 'queued' AND not_before_ms <= $4 AND stage = ANY (string_to_array($6, ','))
                 AND job_id IN (SELECT id FROM jobs WHERE timing_only = 1)
               ORDER BY priority, created_ms, id LIMIT $5
               FOR UPDATE SKIP LOCKED)
  RETURNING id, job_id, key, stage, attempt, params_json, lease_deadline_ms
)
SELECT leased.*,
       (SELECT COALESCE(json_agg(json_build_object('task_id', o.task_id, 'key', t.key,
                                                   'files', encode(o.files, 'hex')) ORDER BY t.key), '[]')::text
        FROM task_deps d JOIN outputs o ON o.task_id = d.depends_on JOIN tasks t ON t.id = o.task_id
        WHERE d.task_id = leased.id) AS inputs_json
FROM leased;

-- name: worker_seen_update
-- None: part of lease_tasks.

-- name: worker_seen_insert
-- None: part of lease_tasks.

-- name: lease_inputs
-- None: lease_tasks reads the inputs.

-- name: worker_heartbeat
-- None: part of heartbeat.

-- name: heartbeat
-- Extends to $1 the leases worker $4 still holds among the JSON rows $5 (id, attempt), at $2
-- (state $3: running), recording the worker's heartbeat; returns the leases kept. A heartbeat
-- never waits: a held row another statement has locked (its completion in flight, the reaper
-- expiring it) is not renewed and reads as lost. Waiting instead could deadlock with a completion
-- of the same leases locking them in another order. The worker's row is skipped the same way: a
-- lease of the same worker updating it that instant has just recorded it as seen.
WITH seen AS (
  UPDATE workers SET last_seen_ms = $2, last_heartbeat_ms = $2
  WHERE id = (SELECT id FROM workers WHERE id = $4 FOR UPDATE SKIP LOCKED)
), h AS (
  SELECT * FROM jsonb_to_recordset($5::jsonb) AS h(id text, attempt bigint)
), kept AS (
  SELECT t.id FROM tasks t JOIN h ON h.id = t.id
  WHERE t.state = $3 AND t.lease_owner = $4 AND t.attempt = h.attempt
  FOR UPDATE OF t SKIP LOCKED
)
UPDATE tasks SET lease_deadline_ms = $1, updated_ms = $2 FROM kept WHERE tasks.id = kept.id
RETURNING tasks.id, tasks.attempt;
