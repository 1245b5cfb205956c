-- Lineage (`lineage.rs`): from a sample or an artifact back through every task that made it, and
-- the packaged outputs of a job. Outputs are one packed row a task (`outputs.files`, decoded in
-- Rust), read by task.

-- name: task_dependencies
-- The tasks task $1 depends on.
SELECT depends_on FROM task_deps WHERE task_id = $1 ORDER BY depends_on;

-- name: task_inputs
-- The packed outputs of task $1's dependencies: its inputs.
SELECT o.task_id, t.key, o.files
FROM task_deps d JOIN outputs o ON o.task_id = d.depends_on JOIN tasks t ON t.id = o.task_id
WHERE d.task_id = $1
ORDER BY t.key;

-- name: task_outputs
-- Task $1's packed outputs.
SELECT o.task_id, t.key, o.files FROM tasks t JOIN outputs o ON o.task_id = t.id WHERE t.id = $1;

-- name: stage_outputs
-- The packed outputs of job $1's tasks of stage $2, by key (only a succeeded task has them).
SELECT o.task_id, t.key, o.files FROM tasks t JOIN outputs o ON o.task_id = t.id
WHERE t.job_id = $1 AND t.stage = $2
ORDER BY t.key;

-- name: stage_outputs_after
-- `stage_outputs` of the tasks whose keys sort after $3, at most $4 of them: one page.
SELECT o.task_id, t.key, o.files FROM tasks t JOIN outputs o ON o.task_id = t.id
WHERE t.job_id = $1 AND t.stage = $2 AND t.key > $3
ORDER BY t.key LIMIT $4;

-- name: job_outputs
-- The packed outputs of job $1's tasks.
SELECT o.task_id, t.key, o.files FROM tasks t JOIN outputs o ON o.task_id = t.id WHERE t.job_id = $1;

-- name: outputs_holding
-- The packed outputs that hold the 32 bytes of the hex digest $1, of job $2 ('': of every job),
-- by stage and task, up to $3 of them, packaged copies last. Outputs are not indexed by hash (an
-- index entry a file cost more than the packed file): this scans the job's (or every job's)
-- outputs.
SELECT o.task_id, t.key, o.files FROM tasks t JOIN outputs o ON o.task_id = t.id
WHERE instr(o.files, unhex($1)) > 0 AND ($2 = '' OR t.job_id = $2)
ORDER BY t.stage = 'package', t.stage, t.id
LIMIT $3;

-- name: tasks_naming
-- Up to $3 of job $1's tasks whose parameters name the text $2 (a submitted file's hash), by key.
-- Parameters are not indexed: this scans the job's tasks.
SELECT id FROM tasks WHERE job_id = $1 AND instr(params_json, $2) > 0
ORDER BY key
LIMIT $3;

-- name: job_plans
-- Job $1's stored plan ('': every job's), the newest job first.
SELECT id, plan_json FROM jobs WHERE ($1 = '' OR id = $1) ORDER BY created_ms DESC, id;

-- name: outputs_with_key_prefix
-- The packed outputs of job $1's tasks whose key matches the LIKE pattern $2 (escaped with `\`),
-- by key.
SELECT o.task_id, t.key, o.files FROM tasks t JOIN outputs o ON o.task_id = t.id
WHERE t.job_id = $1 AND t.key LIKE $2 ESCAPE '\'
ORDER BY t.key;
