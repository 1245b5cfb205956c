-- The upgrade that packs the rows of the table `artifacts` (one a file, before migration 0013)
-- into `outputs` (`outputs.rs`), a batch of tasks a transaction, then drops the table.

-- name: legacy_artifacts_exists
-- Whether the table `artifacts` exists (`n` is 0 or 1).
SELECT COUNT(*) AS n FROM pg_tables WHERE tablename = 'artifacts' AND schemaname = current_schema();

-- name: legacy_artifact_tasks
-- Up to $1 tasks with rows in `artifacts`, by id.
SELECT DISTINCT task_id FROM artifacts ORDER BY task_id LIMIT $1;

-- name: legacy_artifacts_of
-- The `artifacts` rows of the tasks of the JSON array $1.
SELECT task_id, name, sha256, size, media_type, object_key FROM artifacts
WHERE task_id IN (SELECT jsonb_array_elements_text($1::jsonb));

-- name: insert_packed_legacy_outputs
-- Packed outputs, the JSON rows $1 (task, files as hex, count, bytes, samples); a task packed
-- already (an upgrade resumed) is left as it is.
INSERT INTO outputs (task_id, files, count, bytes, samples)
SELECT o.task, decode(o.files, 'hex'), o.count, o.bytes, o.samples
FROM jsonb_to_recordset($1::jsonb) AS o(task text, files text, count bigint, bytes bigint, samples bigint)
WHERE true
ON CONFLICT (task_id) DO NOTHING;

-- name: delete_legacy_artifacts
-- The `artifacts` rows of the tasks of the JSON array $1, packed now.
DELETE FROM artifacts WHERE task_id IN (SELECT jsonb_array_elements_text($1::jsonb));

-- name: drop_legacy_artifacts
-- The emptied table.
DROP TABLE artifacts;
