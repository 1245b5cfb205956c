-- What a job's later tasks need, fixed at submit (vint_core::plan::JobPlan as JSON): completions
-- plan render, noise and package tasks from it instead of re-reading the spec. NULL for jobs
-- submitted before it existed; the coordinator then derives it from spec_toml.
ALTER TABLE jobs ADD COLUMN plan_json TEXT;
