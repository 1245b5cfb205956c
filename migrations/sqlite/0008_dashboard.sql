-- The dashboard views of migrations/postgres/0008_dashboard.sql, with the same columns and
-- meaning. SQLite has no schemas: `dashboard.<name>` there is `dashboard_<name>` here, and JSON is
-- read with json_extract / json_each instead of jsonb. docs/dashboard.md describes each view.

-- The workers the coordinator has heard from (LeaseTasks and Heartbeat upsert their row).
CREATE TABLE workers (
    id                 TEXT PRIMARY KEY,
    stages             TEXT NOT NULL,   -- the stages of its last lease request, comma-separated
    first_seen_ms      BIGINT NOT NULL,
    last_seen_ms       BIGINT NOT NULL, -- its last lease request or heartbeat
    last_heartbeat_ms  BIGINT           -- its last heartbeat (NULL: never held a task long enough)
);

CREATE INDEX tasks_grasp_succeeded ON tasks (job_id) WHERE stage = 'grasp' AND state = 'succeeded';
CREATE INDEX tasks_render_succeeded ON tasks (job_id) WHERE stage = 'render' AND state = 'succeeded';
CREATE INDEX attempts_not_succeeded ON attempts (task_id) WHERE outcome <> 'succeeded';

CREATE VIEW dashboard_job_progress AS
SELECT job_id, stage, COUNT(*) AS tasks,
       SUM(CASE WHEN state = 'waiting' THEN 1 ELSE 0 END) AS waiting,
       SUM(CASE WHEN state = 'queued' THEN 1 ELSE 0 END) AS queued,
       SUM(CASE WHEN state = 'running' THEN 1 ELSE 0 END) AS running,
       SUM(CASE WHEN state = 'succeeded' THEN 1 ELSE 0 END) AS succeeded,
       SUM(CASE WHEN state = 'failed' THEN 1 ELSE 0 END) AS failed,
       SUM(CASE WHEN state = 'cancelled' THEN 1 ELSE 0 END) AS cancelled
FROM tasks
GROUP BY job_id, stage;

CREATE VIEW dashboard_throughput AS
SELECT t.job_id, t.stage, a.ended_ms - a.ended_ms % 60000 AS minute_ms,
       SUM(CASE WHEN a.outcome = 'succeeded' THEN 1 ELSE 0 END) AS succeeded,
       SUM(CASE WHEN a.outcome = 'succeeded' THEN 0 ELSE 1 END) AS failed,
       CAST(COALESCE(SUM(json_extract(a.timings_json, '$.engine_ms')), 0) / 1000.0 AS DOUBLE PRECISION) AS engine_s
FROM attempts a JOIN tasks t ON t.id = a.task_id
GROUP BY t.job_id, t.stage, a.ended_ms - a.ended_ms % 60000;

CREATE VIEW dashboard_failures AS
SELECT t.job_id, t.stage, a.outcome, substr(COALESCE(a.error, ''), 1, 200) AS reason,
       COUNT(*) AS attempts, COUNT(DISTINCT t.id) AS tasks,
       MIN(t.key) AS first_task_key, MAX(t.key) AS last_task_key
FROM attempts a JOIN tasks t ON t.id = a.task_id
WHERE a.outcome <> 'succeeded'
GROUP BY t.job_id, t.stage, a.outcome, substr(COALESCE(a.error, ''), 1, 200);

CREATE VIEW dashboard_workers AS
SELECT w.id AS worker_id, w.stages, w.first_seen_ms, w.last_seen_ms, w.last_heartbeat_ms,
       COALESCE(r.running, 0) AS running_tasks
FROM workers w
LEFT JOIN (SELECT lease_owner, COUNT(*) AS running FROM tasks WHERE state = 'running' GROUP BY lease_owner) r
    ON r.lease_owner = w.id;

-- Object and hand from the task's parameters (Postgres splits the key, grasp/OBJECT/HAND/cNNNNN:
-- the same names).
CREATE VIEW dashboard_grasp_acceptance AS
SELECT job_id, object, hand, COUNT(*) AS tasks,
       SUM(accepted + rejected) AS trials, SUM(accepted) AS accepted, SUM(rejected) AS rejected,
       CAST(SUM(accepted) AS DOUBLE PRECISION) / NULLIF(SUM(accepted + rejected), 0) AS acceptance
FROM (SELECT job_id, json_extract(params_json, '$.object.name') AS object,
             json_extract(params_json, '$.hand.name') AS hand,
             json_array_length(result_json, '$.accepted') AS accepted,
             (SELECT COALESCE(SUM(value), 0) FROM json_each(result_json, '$.rejected')) AS rejected
      FROM tasks WHERE stage = 'grasp' AND state = 'succeeded') g
GROUP BY job_id, object, hand;

CREATE VIEW dashboard_grasp_rejections AS
SELECT t.job_id, json_extract(t.params_json, '$.object.name') AS object,
       json_extract(t.params_json, '$.hand.name') AS hand, r.key AS reason, SUM(r.value) AS trials
FROM tasks t, json_each(t.result_json, '$.rejected') r
WHERE t.stage = 'grasp' AND t.state = 'succeeded'
GROUP BY t.job_id, json_extract(t.params_json, '$.object.name'), json_extract(t.params_json, '$.hand.name'), r.key;

CREATE VIEW dashboard_active_taxels AS
SELECT job_id, hand, region, COUNT(*) AS grasps, SUM(active) AS active_taxels,
       CAST(AVG(active) AS DOUBLE PRECISION) AS mean_per_grasp, MIN(active) AS min_per_grasp,
       MAX(active) AS max_per_grasp
FROM (SELECT t.job_id, json_extract(t.params_json, '$.hand.name') AS hand, c.key AS region, c.value AS active
      FROM tasks t, json_each(t.result_json, '$.active_taxels') g, json_each(g.value, '$.by_region') c
      WHERE t.stage = 'grasp' AND t.state = 'succeeded') x
GROUP BY job_id, hand, region;

CREATE VIEW dashboard_render_seconds AS
SELECT t.job_id, json_extract(t.params_json, '$.render.width') AS width,
       json_extract(t.params_json, '$.render.height') AS height,
       json_extract(t.params_json, '$.render.samples') AS samples,
       json_extract(t.result_json, '$.device') AS device, COUNT(*) AS renders,
       SUM(json_extract(t.result_json, '$.views')) AS views,
       CAST(SUM(json_extract(a.timings_json, '$.engine_ms')) / 1000.0 AS DOUBLE PRECISION) AS engine_s,
       CAST(SUM(json_extract(a.timings_json, '$.engine_ms')) / 1000.0
            / NULLIF(SUM(json_extract(t.result_json, '$.views')), 0) AS DOUBLE PRECISION) AS seconds_per_view
FROM tasks t JOIN attempts a ON a.task_id = t.id AND a.attempt = t.attempt
WHERE t.stage = 'render' AND t.state = 'succeeded'
GROUP BY t.job_id, json_extract(t.params_json, '$.render.width'), json_extract(t.params_json, '$.render.height'),
         json_extract(t.params_json, '$.render.samples'), json_extract(t.result_json, '$.device');

CREATE VIEW dashboard_bytes_written AS
SELECT t.job_id, t.stage, COUNT(*) AS files, SUM(a.size) AS bytes
FROM artifacts a JOIN tasks t ON t.id = a.task_id
GROUP BY t.job_id, t.stage;
