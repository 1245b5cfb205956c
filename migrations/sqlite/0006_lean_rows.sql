-- Fewer bytes per sample (issue 11): lineage edges are derived, not stored. A task's inputs are
-- exactly its dependencies' outputs (task_deps JOIN artifacts), because a task is queued only after
-- every dependency succeeded and a succeeded task's outputs never change. (Postgres also drops the
-- redundant UNIQUE (job_id, key); SQLite cannot drop a table constraint without rebuilding the
-- table, and the embedded store is small.)
DROP TABLE lineage_edges;
