-- Who submitted a job, and whether timing-only workers may serve it; the same as
-- migrations/postgres/0014_job_submitter_and_mode.sql.
ALTER TABLE jobs ADD COLUMN submitted_by TEXT;
ALTER TABLE jobs ADD COLUMN timing_only INTEGER NOT NULL DEFAULT 0;
CREATE INDEX jobs_running_by_submitter ON jobs (submitted_by) WHERE state = 'running';
