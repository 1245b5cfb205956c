-- What an operator and a dataset owner ask of a running or finished job, as views in a schema of
-- their own (`dashboard`; docs/dashboard.md shows each with an example query). `vintctl
-- dashboard` and the coordinator's QueryDashboard read them through `Store::dashboard`; SQLite
-- names the same views `dashboard_<name>` (migrations/sqlite/0008_dashboard.sql).
--
-- Every per-job view groups by `job_id`, so a `WHERE job_id = …` on the view reaches the tables'
-- job indexes (`tasks_job_state`, and the two partial indexes below) instead of scanning every job.

-- The workers the coordinator has heard from: one row per worker, upserted by its LeaseTasks and
-- Heartbeat calls (one row per call, not per task), so an idle worker that only polls is seen too.
CREATE TABLE workers (
    id                 TEXT PRIMARY KEY,
    stages             TEXT NOT NULL,   -- the stages of its last lease request, comma-separated
    first_seen_ms      BIGINT NOT NULL,
    last_seen_ms       BIGINT NOT NULL, -- its last lease request or heartbeat
    last_heartbeat_ms  BIGINT           -- its last heartbeat (NULL: never held a task long enough)
);

-- A job's finished grasp and render tasks, for the grasp and render views: an entry per grasp
-- chunk and per render task (a few per cent of a job's tasks, none per sample), written once when
-- the task succeeds.
CREATE INDEX tasks_grasp_succeeded ON tasks (job_id) WHERE stage = 'grasp' AND state = 'succeeded';
CREATE INDEX tasks_render_succeeded ON tasks (job_id) WHERE stage = 'render' AND state = 'succeeded';
-- The attempts that did not succeed, for the failures view: an entry per failure (none in a
-- healthy job), so the view reads them instead of every attempt.
CREATE INDEX attempts_not_succeeded ON attempts (task_id) WHERE outcome <> 'succeeded';

CREATE SCHEMA dashboard;

-- Progress per job and stage: tasks in each state.
CREATE VIEW dashboard.job_progress AS
SELECT job_id, stage, COUNT(*) AS tasks,
       SUM(CASE WHEN state = 'waiting' THEN 1 ELSE 0 END) AS waiting,
       SUM(CASE WHEN state = 'queued' THEN 1 ELSE 0 END) AS queued,
       SUM(CASE WHEN state = 'running' THEN 1 ELSE 0 END) AS running,
       SUM(CASE WHEN state = 'succeeded' THEN 1 ELSE 0 END) AS succeeded,
       SUM(CASE WHEN state = 'failed' THEN 1 ELSE 0 END) AS failed,
       SUM(CASE WHEN state = 'cancelled' THEN 1 ELSE 0 END) AS cancelled
FROM tasks
GROUP BY job_id, stage;

-- Throughput per stage per minute: attempts that ended in each minute (Unix ms of its start),
-- those that succeeded and those that did not (failed, retried, lease expired, cancelled), and
-- the engine time they spent.
CREATE VIEW dashboard.throughput AS
SELECT t.job_id, t.stage, a.ended_ms - a.ended_ms % 60000 AS minute_ms,
       SUM(CASE WHEN a.outcome = 'succeeded' THEN 1 ELSE 0 END) AS succeeded,
       SUM(CASE WHEN a.outcome = 'succeeded' THEN 0 ELSE 1 END) AS failed,
       CAST(COALESCE(SUM((a.timings_json::jsonb ->> 'engine_ms')::double precision), 0) / 1000.0
            AS DOUBLE PRECISION) AS engine_s
FROM attempts a JOIN tasks t ON t.id = a.task_id
GROUP BY t.job_id, t.stage, a.ended_ms - a.ended_ms % 60000;

-- Attempts that did not succeed, by stage, outcome and reason (the error's first 200 characters),
-- with the first and last task key (in key order) that ended that way.
CREATE VIEW dashboard.failures AS
SELECT t.job_id, t.stage, a.outcome, substr(COALESCE(a.error, ''), 1, 200) AS reason,
       COUNT(*) AS attempts, COUNT(DISTINCT t.id) AS tasks,
       MIN(t.key) AS first_task_key, MAX(t.key) AS last_task_key
FROM attempts a JOIN tasks t ON t.id = a.task_id
WHERE a.outcome <> 'succeeded'
GROUP BY t.job_id, t.stage, a.outcome, substr(COALESCE(a.error, ''), 1, 200);

-- Workers: the stages they lease, when they were first and last heard from, their last heartbeat
-- and the tasks they hold now. Not per job.
CREATE VIEW dashboard.workers AS
SELECT w.id AS worker_id, w.stages, w.first_seen_ms, w.last_seen_ms, w.last_heartbeat_ms,
       COALESCE(r.running, 0) AS running_tasks
FROM workers w
LEFT JOIN (SELECT lease_owner, COUNT(*) AS running FROM tasks WHERE state = 'running' GROUP BY lease_owner) r
    ON r.lease_owner = w.id;

-- Grasp trials per (object, hand) over the finished grasp chunks: ran, accepted, rejected. A
-- grasp task's key is grasp/OBJECT/HAND/cNNNNN (vint_core::plan::GraspChunk).
CREATE VIEW dashboard.grasp_acceptance AS
SELECT job_id, object, hand, COUNT(*) AS tasks,
       CAST(SUM(accepted + rejected) AS BIGINT) AS trials,
       CAST(SUM(accepted) AS BIGINT) AS accepted,
       CAST(SUM(rejected) AS BIGINT) AS rejected,
       CAST(SUM(accepted) AS DOUBLE PRECISION) / NULLIF(SUM(accepted + rejected), 0) AS acceptance
FROM (SELECT t.job_id, split_part(t.key, '/', 2) AS object, split_part(t.key, '/', 3) AS hand,
             jsonb_array_length(r.result -> 'accepted') AS accepted,
             CAST((SELECT COALESCE(SUM(value::bigint), 0) FROM jsonb_each_text(r.result -> 'rejected')) AS BIGINT) AS rejected
      FROM tasks t CROSS JOIN LATERAL (SELECT t.result_json::jsonb AS result OFFSET 0) r
      WHERE t.stage = 'grasp' AND t.state = 'succeeded') g
GROUP BY job_id, object, hand;

-- Rejected grasp trials per (object, hand) by reason class (`no_contact`, `dropped`, …).
CREATE VIEW dashboard.grasp_rejections AS
SELECT t.job_id, split_part(t.key, '/', 2) AS object, split_part(t.key, '/', 3) AS hand, r.key AS reason,
       CAST(SUM(r.value::bigint) AS BIGINT) AS trials
FROM tasks t CROSS JOIN LATERAL jsonb_each_text(t.result_json::jsonb -> 'rejected') r
WHERE t.stage = 'grasp' AND t.state = 'succeeded'
GROUP BY t.job_id, split_part(t.key, '/', 2), split_part(t.key, '/', 3), r.key;

-- Active taxels per accepted grasp, by hand and region (tip, pulp, palm): the grasp result's
-- `active_taxels` (every region of the hand's layout, 0 included).
CREATE VIEW dashboard.active_taxels AS
SELECT job_id, hand, region, COUNT(*) AS grasps, CAST(SUM(active) AS BIGINT) AS active_taxels,
       CAST(AVG(active) AS DOUBLE PRECISION) AS mean_per_grasp, MIN(active) AS min_per_grasp,
       MAX(active) AS max_per_grasp
FROM (SELECT t.job_id, split_part(t.key, '/', 3) AS hand, c.key AS region, c.value::bigint AS active
      FROM tasks t
      CROSS JOIN LATERAL jsonb_array_elements(t.result_json::jsonb -> 'active_taxels') g
      CROSS JOIN LATERAL jsonb_each_text(g.value -> 'by_region') c
      WHERE t.stage = 'grasp' AND t.state = 'succeeded') x
GROUP BY job_id, hand, region;

-- Render time per view by resolution, samples per pixel and device: the successful attempt's
-- engine time (scene set-up included) over the views its task rendered.
CREATE VIEW dashboard.render_seconds AS
SELECT t.job_id, p.width, p.height, p.samples, r.device, COUNT(*) AS renders, CAST(SUM(r.views) AS BIGINT) AS views,
       CAST(SUM((a.timings_json::jsonb ->> 'engine_ms')::double precision) / 1000.0 AS DOUBLE PRECISION) AS engine_s,
       CAST(SUM((a.timings_json::jsonb ->> 'engine_ms')::double precision) / 1000.0 / NULLIF(SUM(r.views), 0)
            AS DOUBLE PRECISION) AS seconds_per_view
FROM tasks t
JOIN attempts a ON a.task_id = t.id AND a.attempt = t.attempt
CROSS JOIN LATERAL jsonb_to_record(t.params_json::jsonb -> 'render') AS p(width bigint, height bigint, samples bigint)
CROSS JOIN LATERAL jsonb_to_record(t.result_json::jsonb) AS r(views bigint, device text)
WHERE t.stage = 'render' AND t.state = 'succeeded'
GROUP BY t.job_id, p.width, p.height, p.samples, r.device;

-- Files recorded per job and stage, and their bytes. Grasp, render and noise rows are what those
-- stages uploaded; a package task's rows are its samples' files, most of them references to
-- render and noise files by hash (packaging copies no pixels), so the package row is the size of
-- the dataset as exported, not bytes uploaded again.
CREATE VIEW dashboard.bytes_written AS
SELECT t.job_id, t.stage, COUNT(*) AS files, CAST(SUM(a.size) AS BIGINT) AS bytes
FROM artifacts a JOIN tasks t ON t.id = a.task_id
GROUP BY t.job_id, t.stage;
