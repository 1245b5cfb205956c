-- A worker that shuts down gives its leases back (WorkService.ReleaseTasks): the attempt ends
-- with the outcome 'released' and its task is queued again at once. The outcome check of
-- migration 0004 admits the new name; the list still names exactly `AttemptOutcome::as_str`'s
-- values (services/store/tests/states.rs). SQLite: migrations/sqlite/0009_released_outcome.sql.

ALTER TABLE attempts DROP CONSTRAINT attempts_outcome_known;
ALTER TABLE attempts ADD CONSTRAINT attempts_outcome_known
    CHECK (outcome IS NULL OR outcome IN ('succeeded', 'retry', 'failed', 'lease_expired', 'cancelled', 'released'));
