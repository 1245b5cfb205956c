//! The task queue: lease, heartbeat, complete, fail, release and reap expired leases.
//!
//! Leasing is one `UPDATE … WHERE id IN (SELECT … LIMIT n FOR UPDATE SKIP LOCKED) RETURNING …`,
//! so concurrent coordinators never hand out the same task. Completion and failure are fenced:
//! they change a task only while it is `running`, leased by the caller, at the caller's attempt
//! and (for completion and heartbeats) before the lease deadline.
//!
//! One file per verb: `lease` (and heartbeats), `complete`, `fail` (and the reaper), `release`.

mod complete;
mod fail;
mod lease;
mod release;

use sqlx::{Any, Row, Transaction};
use vint_core::{AttemptOutcome, TaskState};

use crate::jobs::task_from_row;
use crate::{Backend, Fence, Result, Store, StoreError, literal, parse, to_u32, trusted};

pub(crate) use complete::OUTPUT_COLUMNS;

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
        let stale: Vec<String> = sqlx::query(
            "SELECT s.relname::text AS relname FROM pg_stat_user_tables s JOIN pg_class c ON c.oid = s.relid \
             WHERE s.relname IN ('tasks', 'task_deps', 'attempts', 'outputs') \
             AND s.n_live_tup > 1000 + 2 * greatest(c.reltuples, 0) ORDER BY s.relname",
        )
        .fetch_all(&self.pool)
        .await?
        .iter()
        .map(|row| row.try_get::<String, _>("relname"))
        .collect::<std::result::Result<_, _>>()?;
        for table in &stale {
            // The names come from the fixed list above.
            sqlx::query(trusted(format!("ANALYZE {table}"))).execute(&self.pool).await?;
        }
        Ok(stale)
    }

    /// The task's attempts, oldest first.
    pub async fn attempts(&self, task_id: &str) -> Result<Vec<crate::AttemptRecord>> {
        // Ended attempts are rows of `attempts`; a running one is its task's row.
        let sql = format!(
            "SELECT task_id, attempt, worker_id, started_ms, ended_ms, outcome, error FROM attempts \
             WHERE task_id = $1 UNION ALL SELECT id, attempt, lease_owner, COALESCE(leased_ms, updated_ms), NULL, \
             NULL, NULL FROM tasks WHERE id = $1 AND state = {running} ORDER BY attempt",
            running = literal(TaskState::Running.as_str()),
        );
        let rows = sqlx::query(trusted(sql)).bind(task_id).fetch_all(&self.pool).await?;
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

    /// Running tasks, for tests and operators.
    pub async fn running_tasks(&self) -> Result<Vec<crate::TaskRecord>> {
        let sql = format!("SELECT {} FROM tasks WHERE state = $1 ORDER BY id", crate::jobs::TASK_COLUMNS);
        let rows = sqlx::query(trusted(sql)).bind(TaskState::Running.as_str()).fetch_all(&self.pool).await?;
        rows.iter().map(task_from_row).collect()
    }
}

pub(super) fn lease_lost(f: &Fence) -> StoreError {
    StoreError::LeaseLost { task_id: f.task_id.clone(), attempt: f.attempt, worker_id: f.worker_id.clone() }
}

pub(super) async fn end_attempt(
    tx: &mut Transaction<'static, Any>,
    f: &Fence,
    now_ms: i64,
    outcome: AttemptOutcome,
    error: Option<&str>,
    engine_and_timings: Option<(&str, &str)>,
) -> Result<()> {
    let (engine, timings) = engine_and_timings.unzip();
    // Before the task's row leaves `running`: it holds when the attempt started.
    sqlx::query(
        "INSERT INTO attempts (task_id, attempt, worker_id, started_ms, ended_ms, outcome, error, engine_json, \
         timings_json) SELECT id, attempt, lease_owner, COALESCE(leased_ms, $1), $1, $2, $3, $4, $5 FROM tasks \
         WHERE id = $6 AND attempt = $7",
    )
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
