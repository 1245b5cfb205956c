-- The queue's depth (`depth.rs`): live work only, never history.

-- name: live_tasks
-- Live tasks by stage and state: queued and running ones through their partial indexes
-- (`tasks_ready`, `tasks_leased`: the states are literals, since a partial index serves only a
-- query that names its state), waiting ones through `tasks_job_state` of the running jobs (only a
-- running job has waiting tasks).
SELECT stage, 'queued' AS state, COUNT(*) AS n FROM tasks WHERE state = 'queued' GROUP BY stage
UNION ALL
SELECT stage, 'running', COUNT(*) FROM tasks WHERE state = 'running' GROUP BY stage
UNION ALL
SELECT t.stage, 'waiting', COUNT(*) FROM jobs j JOIN tasks t ON t.job_id = j.id AND t.state = 'waiting'
WHERE j.state = 'running'
GROUP BY t.stage;

-- name: jobs_by_state
-- Jobs by state.
SELECT state, COUNT(*) AS n FROM jobs GROUP BY state;
