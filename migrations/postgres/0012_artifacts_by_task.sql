-- Fewer bytes per sample (issue 21): the artifacts' primary key on (task_id, name) was 181 bytes an
-- entry, 2.6 KB of the 8.0 KB a sample took on the 2 M run (docs/benchmarks.md), for a check the
-- coordinator makes before anything is written (a completion naming an output twice is refused).
-- Every read of artifacts goes by task (a task's outputs, a task's inputs through task_deps, a
-- sample's files through its package task): a plain index on task_id serves them all, and its
-- B-tree deduplication keeps one entry per task for its many files.
ALTER TABLE artifacts DROP CONSTRAINT artifacts_pkey;
CREATE INDEX artifacts_by_task ON artifacts (task_id);
