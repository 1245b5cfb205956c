//! The task queue: lease, heartbeat, complete, fail, release and reap expired leases.
//!
//! Leasing is one `UPDATE … WHERE id IN (SELECT … LIMIT n FOR UPDATE SKIP LOCKED) RETURNING …`,
//! so concurrent coordinators never hand out the same task. Completion and failure are fenced:
//! they change a task only while it is `running`, leased by the caller and at the caller's
//! attempt. A lease past its deadline is still its owner's until the reaper takes it: a
//! heartbeat revives it and a completion is accepted. So a worker that could not reach the
//! coordinator for longer than a lease (the coordinator or its database was down) keeps its
//! work when it comes back, and the reaper alone decides when a lease is gone (the coordinator
//! waits one lease length after it starts, or after the database returns, before it reaps).
//!
//! One file per verb: `lease` (and heartbeats), `complete`, `fail` (and the reaper), `release`.

mod complete;
mod fail;
mod lease;
mod release;

pub use lease::Heartbeat;

/// Where a lease or heartbeat reads the time, in ms since the epoch. The store reads it only once
/// it holds a database connection: a request that waited for one (the database was down, the pool
/// was busy) must not write a deadline dated from before the wait, or the lease it grants or
/// renews is already stale when written, and the reaper takes it from a live worker. The
/// coordinator passes its clock; tests pass a fixed instant (`i64`).
pub trait Clock {
    fn now_ms(&self) -> i64;
}

impl Clock for i64 {
    fn now_ms(&self) -> i64 {
        *self
    }
}

impl<F: Fn() -> i64> Clock for F {
    fn now_ms(&self) -> i64 {
        self()
    }
}

use sqlx::{Any, Row, Transaction};
use vint_core::{AttemptOutcome, TaskState};

use crate::jobs::task_from_row;
use crate::sql::sql;
use crate::{Backend, Fence, Result, Store, StoreError, parse, to_u32};

impl Store {
    /// Keeps the planner's statistics of the tables a running job grows (Postgres): analyzes each
    /// one that holds twice the rows its last analysis counted (or was never analyzed),
    /// returning their names. A job grows `outputs` from nothing to millions of rows in
    /// minutes, faster than autovacuum's analyze follows (seen: none in the first 3 minutes of a
    /// 2 M-sample job), and a plan made with no statistics scans the whole table for each leased
    /// task's inputs. An analysis also replaces the cached plans of the statements that read the
    /// table. Updates do not count: they leave the row counts, and the plans, as they were.
    pub async fn refresh_statistics(&self) -> Result<Vec<String>> {
        if self.backend != Backend::Postgres {
            return Ok(Vec::new());
        }
        let stale: Vec<String> = sqlx::query(sql(self.backend, "stale_statistics")?)
            .fetch_all(&self.pool)
            .await?
            .iter()
            .map(|row| row.try_get::<String, _>("relname"))
            .collect::<std::result::Result<_, _>>()?;
        for table in &stale {
            let statement = match table.as_str() {
                "tasks" => "analyze_tasks",
                "task_deps" => "analyze_task_deps",
                "attempts" => "analyze_attempts",
                "outputs" => "analyze_outputs",
                other => return Err(StoreError::Corrupt(format!("statistics of an unexpected table {other:?}"))),
            };
            sqlx::query(sql(self.backend, statement)?).execute(&self.pool).await?;
        }
        Ok(stale)
    }

    /// The task's attempts, oldest first.
    pub async fn attempts(&self, task_id: &str) -> Result<Vec<crate::AttemptRecord>> {
        let rows = sqlx::query(sql(self.backend, "task_attempts")?).bind(task_id).fetch_all(&self.pool).await?;
        rows.iter()
            .map(|r| {
                Ok(crate::AttemptRecord {
                    task_id: r.try_get("task_id")?,
                    attempt: to_u32("attempt", r.try_get("attempt")?)?,
                    worker_id: r.try_get("worker_id")?,
                    started_ms: r.try_get("started_ms")?,
                    ended_ms: r.try_get("ended_ms")?,
                    outcome: r
                        .try_get::<Option<String>, _>("outcome")?
                        .map(|o| parse("attempt outcome", &o))
                        .transpose()?,
                    error: r.try_get("error")?,
                })
            })
            .collect()
    }

    /// How many running tasks are leased to workers whose ids start with `prefix` (a token's
    /// `NAME/`: the coordinator caps the leases one token holds).
    pub async fn leases_held_by(&self, prefix: &str) -> Result<u64> {
        let n: i64 =
            sqlx::query(sql(self.backend, "leases_held_by")?).bind(prefix).fetch_one(&self.pool).await?.try_get("n")?;
        Ok(u64::try_from(n).unwrap_or(0))
    }

    /// Running tasks, for tests and operators.
    pub async fn running_tasks(&self) -> Result<Vec<crate::TaskRecord>> {
        let rows = sqlx::query(sql(self.backend, "tasks_in_state")?)
            .bind(TaskState::Running.as_str())
            .fetch_all(&self.pool)
            .await?;
        rows.iter().map(task_from_row).collect()
    }
}

pub(super) fn lease_lost(f: &Fence) -> StoreError {
    StoreError::LeaseLost { task_id: f.task_id.clone(), attempt: f.attempt, worker_id: f.worker_id.clone() }
}

pub(super) async fn end_attempt(
    tx: &mut Transaction<'static, Any>,
    backend: Backend,
    f: &Fence,
    now_ms: i64,
    outcome: AttemptOutcome,
    error: Option<&str>,
    engine_and_timings: Option<(&str, &str)>,
) -> Result<()> {
    let (engine, timings) = engine_and_timings.unzip();
    // Before the task's row leaves `running`: it holds when the attempt started.
    sqlx::query(sql(backend, "insert_ended_attempt")?)
        .bind(now_ms)
        .bind(outcome.as_str())
        .bind(error)
        .bind(engine)
        .bind(timings)
        .bind(&f.task_id)
        .bind(i64::from(f.attempt))
        .execute(&mut **tx)
        .await?;
    Ok(())
}
