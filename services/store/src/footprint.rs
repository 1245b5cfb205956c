//! The store's footprint: how many rows of each table a job writes, and what a row costs on
//! Postgres. It mirrors what `submit_job` and `complete` insert, so that `vintctl plan` can size a
//! job's database before it runs; `Store::table_rows` counts what was written, and
//! `tests/footprint.rs` holds the two to each other on both backends.
//!
//! Counted for the tasks of a job that succeed at their first attempt: each retry adds one
//! `attempts` row, and nothing else.

use std::ops::{Add, AddAssign};

use serde::Serialize;
use sqlx::Row;

use vint_core::contract::{self, BadParams};
use vint_core::plan::NewTask;

use crate::sql::sql;
use crate::{Result, Store};

/// One value per table: rows (`TableRows`) or bytes per row (`PerRow`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Tables<T> {
    pub jobs: T,
    pub job_assets: T,
    pub tasks: T,
    pub task_deps: T,
    pub attempts: T,
    /// `outputs` rows: one a task that made files.
    pub outputs: T,
    /// The files packed in `outputs` rows (bytes a file, beyond its row's).
    pub output_files: T,
    pub task_keys: T,
}

/// Rows per table.
pub type TableRows = Tables<u64>;

impl<T: Copy> Tables<T> {
    /// The tables in schema order, with their names.
    pub const TABLES: [&'static str; 8] =
        ["jobs", "job_assets", "tasks", "task_deps", "attempts", "outputs", "outputs.files", "task_keys"];

    /// Every table's value, in `TABLES` order.
    pub fn values(&self) -> [T; 8] {
        [
            self.jobs,
            self.job_assets,
            self.tasks,
            self.task_deps,
            self.attempts,
            self.outputs,
            self.output_files,
            self.task_keys,
        ]
    }

    fn from_values(v: [T; 8]) -> Tables<T> {
        let [jobs, job_assets, tasks, task_deps, attempts, outputs, output_files, task_keys] = v;
        Tables { jobs, job_assets, tasks, task_deps, attempts, outputs, output_files, task_keys }
    }
}

impl TableRows {
    /// What a submission writes besides its tasks: the job and the user files its spec names.
    pub fn submit(user_files: u64) -> TableRows {
        TableRows { jobs: 1, job_assets: user_files, ..TableRows::default() }
    }

    /// What one task writes over its life, succeeding at its first attempt: its row and one
    /// `task_deps` row per dependency (inserted by the completion that planned it), its reuse key
    /// (written when a worker that declares its engine leases it: every production worker, not
    /// the timing-only one), its attempt, its `outputs` files packed in one row (none when it made
    /// none). Its samples are named by its files (migration 0013), not rows of their own.
    /// Its inputs are derived (its dependencies' outputs), not stored.
    pub fn task(dependencies: usize, outputs: u64) -> TableRows {
        TableRows {
            tasks: 1,
            task_deps: dependencies as u64,
            attempts: 1,
            outputs: u64::from(outputs > 0),
            output_files: outputs,
            task_keys: 1,
            ..TableRows::default()
        }
    }

    /// Every table's count, in `TABLES` order.
    pub fn counts(&self) -> [u64; 8] {
        self.values()
    }

    pub fn total(&self) -> u64 {
        self.counts().iter().sum()
    }

    /// `n` times these rows.
    pub fn times(&self, n: u64) -> TableRows {
        let c = self.counts().map(|v| v.saturating_mul(n));
        TableRows::from_values(c)
    }
}

impl Add for TableRows {
    type Output = TableRows;

    fn add(self, other: TableRows) -> TableRows {
        let (a, b) = (self.counts(), other.counts());
        TableRows::from_values(std::array::from_fn(|i| a[i].saturating_add(b[i])))
    }
}

impl AddAssign for TableRows {
    fn add_assign(&mut self, other: TableRows) {
        *self = *self + other;
    }
}

/// The rows planned tasks write over their lives, each succeeding at its first attempt: a grasp
/// task and what its completion unlocks (`vint_core::plan::after_grasp`), say. Each task's file
/// count is its stage's own (`vint_core::contract::files_written`), so no stage is named here.
pub fn task_rows(tasks: &[NewTask]) -> Result<TableRows, BadParams> {
    let mut rows = TableRows::default();
    for t in tasks {
        rows += TableRows::task(t.deps.len(), contract::files_written(t.stage, &t.params)?);
    }
    Ok(rows)
}

/// Bytes one row of each table takes on Postgres with its indexes and TOAST
/// (`pg_total_relation_size` over the row count), measured by `scripts/measure_db_bytes.py` on
/// the rows of a real `vintctl run examples/tiny.toml` job (21 tasks, 30 samples) copied 400
/// times under fresh job ids into a scratch database with `migrations/postgres` applied, after
/// `VACUUM ANALYZE` (2026-11-28, migration 0013's schema, Postgres 15.20, this machine).
/// `outputs` splits into the row (366 bytes: heap tuple, primary key entry, TOAST pointer and
/// chunk overhead) and its packed files (50 bytes a file: the encoded bytes over the file count),
/// so that a spec whose tasks make more or fewer files is sized by its own count.
/// `tasks` is tiny's mix of stages; a task row is mostly its parameters, so `vintctl plan` sizes
/// it as `POSTGRES_TASK_BYTES_BEYOND_PARAMS` plus the parameters the planner makes for the spec.
/// `job_assets` is not measured (tiny names no user file): the figure of an `artifacts` row
/// (the same columns; 2026-11-25, before migration 0013 packed them) stands in.
/// `task_keys`: the tiny run's copies share their keys, which the key index then stores once
/// (231 bytes a row); taken instead from 200,000 rows of its real shape (a render task's id, a
/// 64-hex key) in a scratch table with its two indexes, after `VACUUM ANALYZE` (2026-11-28):
/// heap 149, primary key 100, key index 125 bytes a row.
/// Re-measure when the schema changes; the script prints this table.
pub const POSTGRES_BYTES_PER_ROW: PerRow = PerRow {
    jobs: 3_666.0,
    job_assets: 446.0,
    tasks: 1_661.0,
    task_deps: 304.0,
    attempts: 632.0,
    outputs: 366.0,
    output_files: 50.0,
    task_keys: 374.0,
};

/// A `tasks` row on Postgres beyond its `params_json`: 1 661 bytes per row less tiny's 982-byte
/// mean parameters (`scripts/measure_db_bytes.py`, as above).
pub const POSTGRES_TASK_BYTES_BEYOND_PARAMS: f64 = 679.0;

/// A figure per table (bytes per row).
pub type PerRow = Tables<f64>;

impl PerRow {
    /// Every table's figure, in `TableRows::TABLES` order.
    pub fn figures(&self) -> [f64; 8] {
        self.values()
    }

    /// Bytes of `rows`, table by table, in `TableRows::TABLES` order.
    pub fn bytes(&self, rows: &TableRows) -> [f64; 8] {
        let (per_row, counts) = (self.figures(), rows.counts());
        std::array::from_fn(|i| per_row[i] * counts[i] as f64)
    }
}

impl Store {
    /// Rows in each table, over every job: what `TableRows::submit` and `TableRows::task` predict.
    pub async fn table_rows(&self) -> Result<TableRows> {
        let row = sqlx::query(sql(self.backend, "table_rows")?).fetch_one(&self.pool).await?;
        let mut counts = [0u64; 8];
        for (i, count) in counts.iter_mut().enumerate() {
            *count = row.try_get::<i64, _>(i)?.max(0) as u64;
        }
        Ok(TableRows::from_values(counts))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_task_writes_its_row_deps_attempt_and_packed_outputs() {
        let package = TableRows::task(3, 15);
        assert_eq!(
            package,
            TableRows {
                tasks: 1,
                task_deps: 3,
                attempts: 1,
                outputs: 1,
                output_files: 15,
                task_keys: 1,
                ..TableRows::default()
            }
        );
        let job = TableRows::submit(2) + package.times(3);
        assert_eq!((job.jobs, job.job_assets, job.tasks, job.outputs, job.output_files), (1, 2, 3, 3, 45));
        assert_eq!(job.total(), 1 + 2 + 3 * (1 + 3 + 1 + 1 + 15 + 1));
        assert_eq!(TableRows::task(0, 0).outputs, 0, "a task that made no file has no outputs row");
    }

    #[test]
    fn bytes_are_rows_times_the_figure_of_their_table() {
        let per_row = PerRow {
            jobs: 1.0,
            job_assets: 2.0,
            tasks: 3.0,
            task_deps: 4.0,
            attempts: 5.0,
            outputs: 6.0,
            output_files: 7.0,
            task_keys: 9.0,
        };
        let rows = TableRows::task(2, 2);
        assert_eq!(per_row.bytes(&rows), [0.0, 0.0, 3.0, 8.0, 5.0, 6.0, 14.0, 9.0]);
    }
}
