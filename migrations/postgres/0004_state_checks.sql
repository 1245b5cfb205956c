-- The database refuses a state, stage or attempt outcome that vint_core does not define
-- (`JobState`, `TaskState`, `Stage`, `AttemptOutcome`): a typo in SQL or a hand-edited row fails
-- loudly instead of leaving a task no query will ever pick up. Each list names exactly the enum's
-- `as_str` values; services/store/tests/states.rs holds them to that. SQLite says the same with
-- triggers (migrations/sqlite/0004_state_checks.sql).

ALTER TABLE jobs ADD CONSTRAINT jobs_state_known
    CHECK (state IN ('running', 'succeeded', 'failed', 'cancelled'));

ALTER TABLE tasks ADD CONSTRAINT tasks_state_known
    CHECK (state IN ('waiting', 'queued', 'running', 'succeeded', 'failed', 'cancelled'));

ALTER TABLE tasks ADD CONSTRAINT tasks_stage_known
    CHECK (stage IN ('grasp', 'render', 'noise', 'package'));

-- An attempt has no outcome while it runs.
ALTER TABLE attempts ADD CONSTRAINT attempts_outcome_known
    CHECK (outcome IS NULL OR outcome IN ('succeeded', 'retry', 'failed', 'lease_expired', 'cancelled'));
