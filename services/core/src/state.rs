//! The task and job state machines: every state and every legal transition, in one place.
//!
//! ```text
//!            deps succeeded              lease                  complete (fenced)
//!  waiting ───────────────► queued ───────────────► running ───────────────────► succeeded
//!     │                      ▲  │                      │
//!     │                      │  │ cancel               │ fail(retryable) or lease expired,
//!     │                      │  ▼                      │ attempts left: back to queued with
//!     │ cancel               │ cancelled ◄─────────────┤ backoff (not_before); released by its
//!     │ upstream failed      └─────────────────────────┤ worker: back to queued at once
//!     ▼                                                │ fail(permanent) or attempts exhausted
//!  failed / cancelled ◄────────────────────────────────┘
//! ```
//!
//! Each attempt at a task ends with an `AttemptOutcome`, which says which of the transitions out of
//! `running` the task took (`AttemptOutcome::leaves_task_in`).
//!
//! The store implements these transitions in SQL and its database refuses any state, stage or
//! outcome not named here (migration `0004_state_checks.sql`). `TaskState::can_transition` is the
//! reference: `services/store/tests/states.rs` drives every store operation that changes a task,
//! against Postgres and SQLite, checks every change it sees against it, and checks that it saw
//! every transition allowed here.

use std::fmt;
use std::str::FromStr;

/// Ordered as a task moves through its life, so that counts by state read in that order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum TaskState {
    /// Some dependency has not succeeded yet.
    Waiting,
    /// Ready to lease once `not_before` has passed.
    Queued,
    /// Leased by a worker until its lease deadline.
    Running,
    Succeeded,
    /// Failed permanently; the last error is kept.
    Failed,
    Cancelled,
}

impl TaskState {
    pub const ALL: [TaskState; 6] = [
        TaskState::Waiting,
        TaskState::Queued,
        TaskState::Running,
        TaskState::Succeeded,
        TaskState::Failed,
        TaskState::Cancelled,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            TaskState::Waiting => "waiting",
            TaskState::Queued => "queued",
            TaskState::Running => "running",
            TaskState::Succeeded => "succeeded",
            TaskState::Failed => "failed",
            TaskState::Cancelled => "cancelled",
        }
    }

    pub fn is_terminal(self) -> bool {
        matches!(self, TaskState::Succeeded | TaskState::Failed | TaskState::Cancelled)
    }

    /// The legal transitions. Anything else is a bug in the store.
    pub fn can_transition(self, to: TaskState) -> bool {
        use TaskState::*;
        matches!(
            (self, to),
            (Waiting, Queued)
                | (Waiting, Failed)
                | (Waiting, Cancelled)
                | (Queued, Running)
                | (Queued, Cancelled)
                | (Running, Succeeded)
                | (Running, Queued)
                | (Running, Failed)
                | (Running, Cancelled)
        )
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum JobState {
    /// Tasks remain to be run.
    Running,
    /// Every task succeeded.
    Succeeded,
    /// Every task is final and at least one failed permanently: the samples that could be made are
    /// packaged, the others are missing.
    Failed,
    Cancelled,
}

impl JobState {
    pub const ALL: [JobState; 4] = [JobState::Running, JobState::Succeeded, JobState::Failed, JobState::Cancelled];

    pub fn as_str(self) -> &'static str {
        match self {
            JobState::Running => "running",
            JobState::Succeeded => "succeeded",
            JobState::Failed => "failed",
            JobState::Cancelled => "cancelled",
        }
    }

    pub fn is_terminal(self) -> bool {
        !matches!(self, JobState::Running)
    }
}

/// How one attempt at a task ended. An attempt that has not ended has no outcome.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum AttemptOutcome {
    /// The worker completed the task.
    Succeeded,
    /// The worker failed it retryably and attempts were left: the task is queued again.
    Retry,
    /// The worker failed it permanently, or retryably with no attempts left.
    Failed,
    /// The worker stopped heartbeating; the task is queued again, or fails if no attempts are left.
    LeaseExpired,
    /// The job was cancelled while the attempt ran.
    Cancelled,
    /// The worker gave the task back unfinished (it was shutting down): the task is queued again
    /// at once, and the attempt does not count against its `max_attempts`.
    Released,
}

impl AttemptOutcome {
    pub const ALL: [AttemptOutcome; 6] = [
        AttemptOutcome::Succeeded,
        AttemptOutcome::Retry,
        AttemptOutcome::Failed,
        AttemptOutcome::LeaseExpired,
        AttemptOutcome::Cancelled,
        AttemptOutcome::Released,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            AttemptOutcome::Succeeded => "succeeded",
            AttemptOutcome::Retry => "retry",
            AttemptOutcome::Failed => "failed",
            AttemptOutcome::LeaseExpired => "lease_expired",
            AttemptOutcome::Cancelled => "cancelled",
            AttemptOutcome::Released => "released",
        }
    }

    /// The states a running task may move to when its attempt ends with this outcome.
    pub fn leaves_task_in(self) -> &'static [TaskState] {
        match self {
            AttemptOutcome::Succeeded => &[TaskState::Succeeded],
            AttemptOutcome::Retry => &[TaskState::Queued],
            AttemptOutcome::Failed => &[TaskState::Failed],
            AttemptOutcome::LeaseExpired => &[TaskState::Queued, TaskState::Failed],
            AttemptOutcome::Cancelled => &[TaskState::Cancelled],
            AttemptOutcome::Released => &[TaskState::Queued],
        }
    }
}

#[derive(Debug, thiserror::Error)]
#[error("unknown state {0:?}")]
pub struct UnknownState(pub String);

macro_rules! impl_state_text {
    ($($ty:ty),+) => {$(
        impl FromStr for $ty {
            type Err = UnknownState;
            fn from_str(s: &str) -> Result<Self, Self::Err> {
                <$ty>::ALL.into_iter().find(|v| v.as_str() == s).ok_or_else(|| UnknownState(s.to_string()))
            }
        }
        impl fmt::Display for $ty {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str(self.as_str())
            }
        }
    )+};
}

impl_state_text!(TaskState, JobState, AttemptOutcome);

/// Delay before the next attempt after `attempts` failed ones: `base · 2^(attempts−1)`, capped.
pub fn retry_backoff_ms(attempts: u32, base_ms: i64, cap_ms: i64) -> i64 {
    let exp = attempts.saturating_sub(1).min(30);
    base_ms.saturating_mul(1_i64 << exp).min(cap_ms)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn terminal_states_have_no_way_out() {
        for from in TaskState::ALL.into_iter().filter(|s| s.is_terminal()) {
            for to in TaskState::ALL {
                assert!(!from.can_transition(to), "{from} -> {to} must be illegal");
            }
        }
    }

    #[test]
    fn only_a_lease_starts_running() {
        for from in TaskState::ALL {
            assert_eq!(from.can_transition(TaskState::Running), from == TaskState::Queued);
        }
    }

    #[test]
    fn states_and_outcomes_round_trip_through_text() {
        for s in TaskState::ALL {
            assert_eq!(s.as_str().parse::<TaskState>().unwrap(), s);
        }
        for s in JobState::ALL {
            assert_eq!(s.as_str().parse::<JobState>().unwrap(), s);
        }
        for o in AttemptOutcome::ALL {
            assert_eq!(o.as_str().parse::<AttemptOutcome>().unwrap(), o);
            assert_eq!(o.to_string(), o.as_str());
        }
        assert!("done".parse::<TaskState>().is_err());
        assert!("expired".parse::<AttemptOutcome>().is_err());
    }

    #[test]
    fn attempt_outcomes_are_exactly_the_ways_out_of_running() {
        let by_outcome: std::collections::BTreeSet<TaskState> =
            AttemptOutcome::ALL.iter().flat_map(|o| o.leaves_task_in().iter().copied()).collect();
        let out_of_running: std::collections::BTreeSet<TaskState> =
            TaskState::ALL.into_iter().filter(|&to| TaskState::Running.can_transition(to)).collect();
        assert_eq!(by_outcome, out_of_running);
    }

    #[test]
    fn backoff_doubles_and_caps() {
        assert_eq!(retry_backoff_ms(1, 100, 10_000), 100);
        assert_eq!(retry_backoff_ms(2, 100, 10_000), 200);
        assert_eq!(retry_backoff_ms(4, 100, 10_000), 800);
        assert_eq!(retry_backoff_ms(40, 100, 10_000), 10_000);
    }
}
