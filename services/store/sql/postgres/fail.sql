-- Attempts that end without success (`queue/fail.rs`): reported failures and expired leases,
-- retried after a backoff or failed for good with their dependents.

-- name: expired_leases
-- Running tasks whose lease ran out before $1 (through the partial index `tasks_leased`) and
-- whose worker has had one lease of its own length to be heard since $2, when the coordinator
-- could last start hearing heartbeats (a lease or a heartbeat sets `updated_ms` to its time and
-- the deadline one lease after it, so their difference is the lease's length).
SELECT id, lease_owner, attempt, updated_ms FROM tasks
WHERE state = 'running' AND lease_deadline_ms < $1 AND $2 + (lease_deadline_ms - updated_ms) <= $1;

-- name: fence_reported_failure
-- Locks task $1 while it is in state $2, leased to worker $3 at attempt $4 (the fence of a
-- reported failure: past its deadline too, until the reaper has taken it); returns its attempts
-- so far and allowed.
SELECT attempt, max_attempts FROM tasks
WHERE id = $1 AND state = $2 AND lease_owner = $3 AND attempt = $4
FOR UPDATE;

-- name: fence_expired_lease
-- `fence_reported_failure` for the reaper, which fails a lease only while its deadline is still
-- before $5: a heartbeat may have revived it since `expired_leases` read it.
SELECT attempt, max_attempts FROM tasks
WHERE id = $1 AND state = $2 AND lease_owner = $3 AND attempt = $4 AND lease_deadline_ms < $5
FOR UPDATE;

-- name: requeue_task
-- Queues task $5 again ($1) after a failure, with its message $2, not before $3, at $4, raising
-- its `max_attempts` by $6 (1 for an attempt that does not count: a lease that ran out while no
-- coordinator could hear its heartbeats).
UPDATE tasks SET state = $1, lease_owner = NULL, lease_deadline_ms = NULL, last_error = $2, not_before_ms = $3,
                 max_attempts = max_attempts + $6, updated_ms = $4
WHERE id = $5;

-- name: fail_task
-- Fails task $4 for good ($1) with its message $2, at $3.
UPDATE tasks SET state = $1, lease_owner = NULL, lease_deadline_ms = NULL, last_error = $2, updated_ms = $3
WHERE id = $4;

-- name: fail_waiting_dependents
-- Fails ($1, with message $2, at $3) the waiting ($4) tasks that depend on task $5; returns them,
-- whose own dependents fail next.
UPDATE tasks SET state = $1, last_error = $2, updated_ms = $3
WHERE state = $4 AND id IN (SELECT task_id FROM task_deps WHERE depends_on = $5)
RETURNING id;
