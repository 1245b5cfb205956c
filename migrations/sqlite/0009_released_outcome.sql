-- A worker that shuts down gives its leases back (WorkService.ReleaseTasks): the attempt ends
-- with the outcome 'released' and its task is queued again at once. The outcome triggers of
-- migration 0004 admit the new name; the lists still name exactly `AttemptOutcome::as_str`'s
-- values (services/store/tests/states.rs). Postgres: migrations/postgres/0009_released_outcome.sql.

DROP TRIGGER attempts_outcome_known_on_insert;
DROP TRIGGER attempts_outcome_known_on_update;

CREATE TRIGGER attempts_outcome_known_on_insert BEFORE INSERT ON attempts
    WHEN NEW.outcome IS NOT NULL
        AND NEW.outcome NOT IN ('succeeded', 'retry', 'failed', 'lease_expired', 'cancelled', 'released')
    BEGIN SELECT RAISE(ABORT, 'attempts_outcome_known: attempts.outcome is not an attempt outcome'); END;
CREATE TRIGGER attempts_outcome_known_on_update BEFORE UPDATE OF outcome ON attempts
    WHEN NEW.outcome IS NOT NULL
        AND NEW.outcome NOT IN ('succeeded', 'retry', 'failed', 'lease_expired', 'cancelled', 'released')
    BEGIN SELECT RAISE(ABORT, 'attempts_outcome_known: attempts.outcome is not an attempt outcome'); END;
