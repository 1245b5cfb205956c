-- Leases handed back by a worker that stops (`queue/release.rs`): queued again at once, costing
-- no attempt.

-- name: release_leases
-- Queues again ($1), at $2 and with no backoff, the tasks worker $4 holds leases on
-- among the JSON rows $5 (id, attempt), raising each task's `max_attempts` by one so that a
-- release does not bring it closer to failing for good (state $3: running). Returns them with
-- when they were leased.
UPDATE tasks SET state = $1, lease_owner = NULL, lease_deadline_ms = NULL, not_before_ms = $2,
                 max_attempts = max_attempts + 1, updated_ms = $2
FROM jsonb_to_recordset($5::jsonb) AS r(id text, attempt bigint)
WHERE tasks.id = r.id AND tasks.state = $3 AND tasks.lease_owner = $4 AND tasks.attempt = r.attempt
RETURNING tasks.id, tasks.attempt, tasks.leased_ms;

-- name: insert_released_attempts
-- The released attempts, the JSON rows $5 (id, attempt, started), of worker $1, ended at $2 with
-- outcome $3 and message $4.
INSERT INTO attempts (task_id, attempt, worker_id, started_ms, ended_ms, outcome, error)
SELECT r.id, r.attempt, $1, r.started, $2, $3, $4
FROM jsonb_to_recordset($5::jsonb) AS r(id text, attempt bigint, started bigint);
