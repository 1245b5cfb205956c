-- The dashboard (`dashboard.rs`): up to $1 rows of each view of migration 0008, of job $2
-- ('': of the $3 newest jobs, those the dashboard lists, so a page reads what it shows and not
-- every job's history) where the view is per job, in the order of its grouping columns (the jobs as one array, so each
-- job's rows are read through its index).
-- The columns are those `DashboardView::columns` declares, with their types.

-- name: dashboard_job_progress
-- Tasks per job and stage in each state.
SELECT job_id, stage, tasks, waiting, queued, running, succeeded, failed, cancelled
FROM dashboard.job_progress
WHERE job_id = ANY (ARRAY(SELECT id FROM jobs WHERE $2 = '' OR id = $2 ORDER BY created_ms DESC, id LIMIT $3))
ORDER BY job_id, stage
LIMIT $1;

-- name: dashboard_throughput
-- Attempts ended per job, stage and minute, with their engine time.
SELECT job_id, stage, minute_ms, succeeded, failed, engine_s
FROM dashboard.throughput
WHERE job_id = ANY (ARRAY(SELECT id FROM jobs WHERE $2 = '' OR id = $2 ORDER BY created_ms DESC, id LIMIT $3))
ORDER BY job_id, minute_ms, stage
LIMIT $1;

-- name: dashboard_failures
-- Attempts that did not succeed, by stage, outcome and reason.
SELECT job_id, stage, outcome, reason, attempts, tasks, first_task_key, last_task_key
FROM dashboard.failures
WHERE job_id = ANY (ARRAY(SELECT id FROM jobs WHERE $2 = '' OR id = $2 ORDER BY created_ms DESC, id LIMIT $3))
ORDER BY job_id, stage, attempts DESC, outcome, reason
LIMIT $1;

-- name: dashboard_workers
-- Workers, their stages, when they were last heard from, the tasks they hold. Not per job.
SELECT worker_id, stages, first_seen_ms, last_seen_ms, last_heartbeat_ms, running_tasks
FROM dashboard.workers
ORDER BY worker_id
LIMIT $1;

-- name: dashboard_grasp_acceptance
-- Grasp trials per (object, hand): ran, accepted, rejected.
SELECT job_id, object, hand, tasks, trials, accepted, rejected, acceptance
FROM dashboard.grasp_acceptance
WHERE job_id = ANY (ARRAY(SELECT id FROM jobs WHERE $2 = '' OR id = $2 ORDER BY created_ms DESC, id LIMIT $3))
ORDER BY job_id, object, hand
LIMIT $1;

-- name: dashboard_grasp_rejections
-- Rejected grasp trials per (object, hand) by reason.
SELECT job_id, object, hand, reason, trials
FROM dashboard.grasp_rejections
WHERE job_id = ANY (ARRAY(SELECT id FROM jobs WHERE $2 = '' OR id = $2 ORDER BY created_ms DESC, id LIMIT $3))
ORDER BY job_id, object, hand, reason
LIMIT $1;

-- name: dashboard_active_taxels
-- Active taxels per accepted grasp, by hand and region.
SELECT job_id, hand, region, grasps, active_taxels, mean_per_grasp, min_per_grasp, max_per_grasp
FROM dashboard.active_taxels
WHERE job_id = ANY (ARRAY(SELECT id FROM jobs WHERE $2 = '' OR id = $2 ORDER BY created_ms DESC, id LIMIT $3))
ORDER BY job_id, hand, region
LIMIT $1;

-- name: dashboard_render_seconds
-- Render engine seconds per view by resolution, samples per pixel and device.
SELECT job_id, width, height, samples, device, renders, views, engine_s, seconds_per_view
FROM dashboard.render_seconds
WHERE job_id = ANY (ARRAY(SELECT id FROM jobs WHERE $2 = '' OR id = $2 ORDER BY created_ms DESC, id LIMIT $3))
ORDER BY job_id, width, height, samples, device
LIMIT $1;

-- name: dashboard_bytes_written
-- Files and bytes recorded per job and stage.
SELECT job_id, stage, files, bytes
FROM dashboard.bytes_written
WHERE job_id = ANY (ARRAY(SELECT id FROM jobs WHERE $2 = '' OR id = $2 ORDER BY created_ms DESC, id LIMIT $3))
ORDER BY job_id, stage
LIMIT $1;

-- name: dashboard_occlusion
-- Rendered views per job and object by occlusion, in tenths.
SELECT job_id, object, bin, views
FROM dashboard.occlusion
WHERE job_id = ANY (ARRAY(SELECT id FROM jobs WHERE $2 = '' OR id = $2 ORDER BY created_ms DESC, id LIMIT $3))
ORDER BY job_id, object, bin
LIMIT $1;
