-- Who submitted a job, and whether timing-only workers may serve it.
--
-- `submitted_by`: the name of the token that submitted it (`--auth-tokens`, docs/security.md);
-- NULL without tokens. The coordinator caps the jobs in flight per token on it.
-- `timing_only`: 1 only for a job submitted with `--timing-only`: timing-only workers
-- (`vint-worker --engine-mode timing-only`, which run no engine and answer stand-in files of the
-- right sizes) lease only such jobs' tasks, and export refuses them.
ALTER TABLE jobs ADD COLUMN submitted_by TEXT;
ALTER TABLE jobs ADD COLUMN timing_only INTEGER NOT NULL DEFAULT 0;
CREATE INDEX jobs_running_by_submitter ON jobs (submitted_by) WHERE state = 'running';
