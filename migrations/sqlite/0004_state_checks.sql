-- The database refuses a state, stage or attempt outcome that vint_core does not define
-- (`JobState`, `TaskState`, `Stage`, `AttemptOutcome`): a typo in SQL or a hand-edited row fails
-- loudly instead of leaving a task no query will ever pick up. Each list names exactly the enum's
-- `as_str` values; services/store/tests/states.rs holds them to that.
--
-- SQLite cannot add a CHECK constraint to an existing table, and rebuilding `tasks` would mean
-- switching foreign keys off around a copy of every table that references it; a pair of triggers
-- per column (insert, update) says the same as the Postgres constraints of the same name
-- (migrations/postgres/0004_state_checks.sql).

CREATE TRIGGER jobs_state_known_on_insert BEFORE INSERT ON jobs
    WHEN NEW.state NOT IN ('running', 'succeeded', 'failed', 'cancelled')
    BEGIN SELECT RAISE(ABORT, 'jobs_state_known: jobs.state is not a job state'); END;
CREATE TRIGGER jobs_state_known_on_update BEFORE UPDATE OF state ON jobs
    WHEN NEW.state NOT IN ('running', 'succeeded', 'failed', 'cancelled')
    BEGIN SELECT RAISE(ABORT, 'jobs_state_known: jobs.state is not a job state'); END;

CREATE TRIGGER tasks_state_known_on_insert BEFORE INSERT ON tasks
    WHEN NEW.state NOT IN ('waiting', 'queued', 'running', 'succeeded', 'failed', 'cancelled')
    BEGIN SELECT RAISE(ABORT, 'tasks_state_known: tasks.state is not a task state'); END;
CREATE TRIGGER tasks_state_known_on_update BEFORE UPDATE OF state ON tasks
    WHEN NEW.state NOT IN ('waiting', 'queued', 'running', 'succeeded', 'failed', 'cancelled')
    BEGIN SELECT RAISE(ABORT, 'tasks_state_known: tasks.state is not a task state'); END;

CREATE TRIGGER tasks_stage_known_on_insert BEFORE INSERT ON tasks
    WHEN NEW.stage NOT IN ('grasp', 'render', 'noise', 'package')
    BEGIN SELECT RAISE(ABORT, 'tasks_stage_known: tasks.stage is not a stage'); END;
CREATE TRIGGER tasks_stage_known_on_update BEFORE UPDATE OF stage ON tasks
    WHEN NEW.stage NOT IN ('grasp', 'render', 'noise', 'package')
    BEGIN SELECT RAISE(ABORT, 'tasks_stage_known: tasks.stage is not a stage'); END;

-- An attempt has no outcome while it runs.
CREATE TRIGGER attempts_outcome_known_on_insert BEFORE INSERT ON attempts
    WHEN NEW.outcome IS NOT NULL AND NEW.outcome NOT IN ('succeeded', 'retry', 'failed', 'lease_expired', 'cancelled')
    BEGIN SELECT RAISE(ABORT, 'attempts_outcome_known: attempts.outcome is not an attempt outcome'); END;
CREATE TRIGGER attempts_outcome_known_on_update BEFORE UPDATE OF outcome ON attempts
    WHEN NEW.outcome IS NOT NULL AND NEW.outcome NOT IN ('succeeded', 'retry', 'failed', 'lease_expired', 'cancelled')
    BEGIN SELECT RAISE(ABORT, 'attempts_outcome_known: attempts.outcome is not an attempt outcome'); END;
