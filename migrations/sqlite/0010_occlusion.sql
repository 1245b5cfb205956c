-- Views by how much of the object the hand hides, per job and object, in tenths (bin 0 is
-- [0, 0.1), ..., bin 9 is [0.9, 1]): migrations/postgres/0010_occlusion.sql. A render task's key is
-- render/OBJECT/HAND/gNNNNNN.
CREATE VIEW dashboard_occlusion AS
SELECT t.job_id, substr(substr(t.key, 8), 1, instr(substr(t.key, 8), '/') - 1) AS object,
       MIN(CAST(o.value * 10 AS INTEGER), 9) AS bin, COUNT(*) AS views
FROM tasks t, json_each(t.result_json, '$.occlusion') o
WHERE t.stage = 'render' AND t.state = 'succeeded'
GROUP BY 1, 2, 3;
