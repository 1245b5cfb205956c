-- Views by how much of the object the hand hides, per job and object: each finished render task's
-- result lists its views' occlusion (the share of the object's pixels hidden; 1 when none of it is
-- in view), binned in tenths: bin 0 is [0, 0.1), ..., bin 9 is [0.9, 1]. A render task's key is
-- render/OBJECT/HAND/gNNNNNN (vint_core::plan::render_key). Reads the tasks_render_succeeded index
-- of migration 0008.
CREATE VIEW dashboard.occlusion AS
SELECT t.job_id, split_part(t.key, '/', 2) AS object,
       CAST(LEAST(FLOOR(CAST(o.value AS DOUBLE PRECISION) * 10), 9) AS BIGINT) AS bin,
       COUNT(*) AS views
FROM tasks t CROSS JOIN LATERAL jsonb_array_elements_text(t.result_json::jsonb -> 'occlusion') o
WHERE t.stage = 'render' AND t.state = 'succeeded'
GROUP BY t.job_id, split_part(t.key, '/', 2), CAST(LEAST(FLOOR(CAST(o.value AS DOUBLE PRECISION) * 10), 9) AS BIGINT);
