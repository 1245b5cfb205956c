-- Fewer bytes and index entries per task and per sample, for millions of samples (issue 11).
--
-- Lineage edges are derived, not stored: a task's inputs are exactly its dependencies' outputs
-- (task_deps JOIN artifacts), because a task is queued only after every dependency succeeded and
-- a succeeded task's outputs never change. The table repeated every input of every task.
DROP TABLE lineage_edges;

-- A task's id is its job id, '/', and its key (job ids hold no '/'), so the primary key already
-- makes (job_id, key) unique: the second unique index only cost an entry on every task update.
ALTER TABLE tasks DROP CONSTRAINT tasks_job_id_key_key;
