-- Task reuse by content (`reuse.rs`): each leased task's reuse key, the stored results a key
-- finds, and the objects some job still references.

-- name: set_content_keys
-- The reuse key of each task of the JSON rows $1 (id, attempt, key) still running ($2) at that
-- attempt, replacing the key of an earlier attempt.
INSERT INTO task_keys (task_id, content_key)
SELECT k.id, k.key FROM jsonb_to_recordset($1::jsonb) AS k(id text, attempt bigint, key text)
JOIN tasks t ON t.id = k.id
WHERE t.attempt = k.attempt AND t.state = $2
ON CONFLICT (task_id) DO UPDATE SET content_key = excluded.content_key;

-- name: tasks_with_keys
-- The tasks in state $2 (succeeded) holding one of the keys of the JSON array $1, by id.
SELECT t.id, k.content_key, t.result_json, t.engine_json
FROM task_keys k JOIN tasks t ON t.id = k.task_id
WHERE k.content_key IN (SELECT jsonb_array_elements_text($1::jsonb)) AND t.state = $2
ORDER BY t.id;

-- name: outputs_of_tasks
-- The packed outputs of the tasks of the JSON array $1.
SELECT o.task_id, t.key, o.files FROM outputs o JOIN tasks t ON t.id = o.task_id
WHERE o.task_id IN (SELECT jsonb_array_elements_text($1::jsonb));

-- name: asset_object_keys
-- The object keys of every job's submitted files.
SELECT object_key FROM job_assets;

-- name: outputs_page
-- Up to 1,000 tasks' packed outputs after task id $1, by id (only the hashes are wanted: the
-- task's id stands in for its key).
SELECT o.task_id, o.task_id AS key, o.files FROM outputs o WHERE o.task_id > $1 ORDER BY o.task_id LIMIT 1000;

-- name: content_key
-- A task's reuse key.
SELECT content_key FROM task_keys WHERE task_id = $1;
