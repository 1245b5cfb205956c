-- A job's permanently failed tasks (`failures.rs`).

-- name: failed_tasks
-- Up to $3 of job $1's tasks in state $2 (failed): those that ran and failed, by key, then those
-- failed by an upstream task (no attempt), by key.
SELECT key, stage, attempt, last_error FROM tasks
WHERE job_id = $1 AND state = $2
ORDER BY attempt = 0, key
LIMIT $3;
