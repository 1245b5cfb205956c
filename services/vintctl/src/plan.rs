//! `vintctl plan SPEC`: what a spec will cost before anything runs — its tasks per stage, the
//! database rows and bytes they write, the object store's bytes and the CPU time per stage.
//!
//! It reads no server and no database. Tasks, CPU time and object-store bytes per stage come from
//! `vint_core::cost` (the planner's own counts: the chunks a pair splits into and what a chunk's
//! accepted grasps unlock; each stage's cost model), rows from the store's own footprint
//! (`vint_store::footprint`, held to what the store writes by its tests), bytes per row from
//! measured figures, each of which names its source.

use serde::Serialize;
use vint_core::DatasetSpec;
use vint_core::cost::{self, CostError};
use vint_store::footprint::{POSTGRES_BYTES_PER_ROW, POSTGRES_TASK_BYTES_BEYOND_PARAMS, TableRows, task_rows};

use crate::estimate;

/// How the counts are meant, said wherever they are shown.
pub const EXACT_QUOTA: &str = "exact if every grasp chunk fills its quota of accepted grasps within its share of \
     grasp.trials_per_pair (fewer otherwise)";
pub const UPPER_BOUND: &str = "upper bound: every grasp trial accepted (the spec sets no grasp.accepted_per_pair)";
/// Where the GPU figure would come from, and why there is none.
pub const NO_GPU: &str = "no GPU figure: Cycles on a GPU is not measured here (the project machine has no GPU and \
     docs/benchmarks.md holds no GPU render time); render CPU-hours are for Cycles on the CPU, one thread per engine";
pub const DATABASE_BASIS: &str = "rows as vint_store::footprint counts them (every task succeeding at its first \
     attempt; each retry adds one attempts row); bytes per row measured on Postgres (scripts/measure_db_bytes.py)";

/// One stage's line of the plan.
#[derive(Debug, Serialize, PartialEq)]
pub struct StagePlan {
    pub stage: &'static str,
    pub tasks: u64,
    /// Whether `tasks` is fixed by the spec alone (grasp tasks always are).
    pub tasks_exact: bool,
    pub cpu_hours: f64,
    /// `None`: not measured (`NO_GPU`).
    pub gpu_hours: Option<f64>,
    /// Bytes this stage adds to the object store.
    pub artifact_bytes: f64,
}

/// One table's line of the plan.
#[derive(Debug, Serialize, PartialEq)]
pub struct TablePlan {
    pub table: &'static str,
    pub rows: u64,
    pub bytes_per_row: f64,
    pub bytes: f64,
}

#[derive(Debug, Serialize, PartialEq)]
pub struct Counts {
    pub pairs: u64,
    pub trials_max: u64,
    pub grasps: u64,
    pub views_per_grasp: u64,
    pub samples: u64,
}

#[derive(Debug, Serialize, PartialEq)]
pub struct Database {
    pub tables: Vec<TablePlan>,
    pub rows: u64,
    pub bytes: f64,
    pub bytes_per_sample: f64,
    pub basis: &'static str,
}

#[derive(Debug, Serialize, PartialEq)]
pub struct Totals {
    pub tasks: u64,
    pub cpu_hours: f64,
    pub artifact_bytes: f64,
    /// The exported dataset in the native layout (`vintctl export`).
    pub dataset_bytes: f64,
}

/// A spec's plan: `vintctl plan --json` prints it as is.
#[derive(Debug, Serialize, PartialEq)]
pub struct Plan {
    pub name: String,
    /// Whether render, noise and package tasks, grasps and samples are the spec's fixed target
    /// (a quota) or an upper bound.
    pub exact: bool,
    pub counts_are: &'static str,
    pub counts: Counts,
    pub stages: Vec<StagePlan>,
    pub database: Database,
    pub totals: Totals,
    pub cost_basis: &'static str,
    pub gpu: &'static str,
}

impl Plan {
    pub fn of(spec: &DatasetSpec) -> Result<Plan, CostError> {
        let c = cost::of(spec)?;
        let w = &c.work;
        let user_files = spec.asset_uses().iter().map(|u| &u.path).collect::<std::collections::BTreeSet<_>>().len();
        let mut rows = TableRows::submit(user_files as u64);
        for group in &c.chunks {
            rows += task_rows(&group.tasks)?.times(group.chunks);
        }

        let stages: Vec<StagePlan> = c
            .stages
            .iter()
            .map(|s| StagePlan {
                stage: s.stage.as_str(),
                tasks: s.tasks,
                tasks_exact: s.tasks_exact,
                cpu_hours: s.cost.cpu_s / 3_600.0,
                gpu_hours: None,
                artifact_bytes: s.cost.bytes,
            })
            .collect();

        let mut bytes = POSTGRES_BYTES_PER_ROW.bytes(&rows);
        let mut per_row = POSTGRES_BYTES_PER_ROW.figures();
        // A task row is mostly its parameters: size it from the parameters this spec's tasks get.
        let task_bytes: f64 =
            c.stages.iter().map(|s| s.tasks as f64 * (s.params_bytes + POSTGRES_TASK_BYTES_BEYOND_PARAMS)).sum();
        bytes[2] = task_bytes;
        per_row[2] = if rows.tasks > 0 { task_bytes / rows.tasks as f64 } else { 0.0 };
        let tables = TableRows::TABLES
            .iter()
            .zip(rows.counts())
            .enumerate()
            .map(|(i, (table, n))| TablePlan { table, rows: n, bytes_per_row: per_row[i], bytes: bytes[i] })
            .collect();
        let db_bytes: f64 = bytes.iter().sum();
        let total = c.total();
        Ok(Plan {
            name: spec.dataset.name.clone(),
            exact: c.exact,
            counts_are: if c.exact { EXACT_QUOTA } else { UPPER_BOUND },
            counts: Counts {
                pairs: w.pairs,
                trials_max: w.trials,
                grasps: w.grasps,
                views_per_grasp: w.views_per_grasp,
                samples: w.samples,
            },
            totals: Totals {
                tasks: stages.iter().map(|s| s.tasks).sum(),
                cpu_hours: total.cpu_s / 3_600.0,
                artifact_bytes: total.bytes,
                dataset_bytes: estimate::dataset_bytes(spec, w),
            },
            stages,
            database: Database {
                tables,
                rows: rows.total(),
                bytes: db_bytes,
                bytes_per_sample: if w.samples > 0 { db_bytes / w.samples as f64 } else { 0.0 },
                basis: DATABASE_BASIS,
            },
            cost_basis: estimate::BASIS,
            gpu: NO_GPU,
        })
    }
}

/// A count with thousands separators: `1,560,000`.
pub fn count(n: u64) -> String {
    let digits = n.to_string();
    let mut out = String::new();
    for (i, c) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

/// Hours with the digits that matter: `2479`, `8.1`, `0.0047`.
fn hours(h: f64) -> String {
    if h >= 100.0 {
        format!("{h:.0}")
    } else if h >= 1.0 {
        format!("{h:.1}")
    } else if h > 0.0 {
        // Two significant digits.
        let digits = (-h.log10().floor()).clamp(0.0, 5.0) as usize + 1;
        format!("{h:.digits$}")
    } else {
        "0".to_string()
    }
}

/// The plan as an aligned table per stage and per table, with totals.
pub fn text(plan: &Plan) -> String {
    use std::fmt::Write;
    let c = &plan.counts;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{}: {} (object, hand) pair(s), {} accepted grasps, {} views each: {} samples",
        plan.name,
        count(c.pairs),
        count(c.grasps),
        c.views_per_grasp,
        count(c.samples)
    );
    let _ = writeln!(out, "  counts: {}", plan.counts_are);
    let _ = writeln!(
        out,
        "\n{:<8} {:>12} {:<6} {:>12} {:>10} {:>12}",
        "stage", "tasks", "", "CPU-hours", "GPU-hours", "artifacts"
    );
    for s in &plan.stages {
        let _ = writeln!(
            out,
            "{:<8} {:>12} {:<6} {:>12} {:>10} {:>12}",
            s.stage,
            count(s.tasks),
            if s.tasks_exact { "exact" } else { "≤" },
            hours(s.cpu_hours),
            s.gpu_hours.map_or_else(|| "—".to_string(), hours),
            estimate::size(s.artifact_bytes)
        );
    }
    let t = &plan.totals;
    let _ = writeln!(
        out,
        "{:<8} {:>12} {:<6} {:>12} {:>10} {:>12}",
        "total",
        count(t.tasks),
        "",
        hours(t.cpu_hours),
        "—",
        estimate::size(t.artifact_bytes)
    );
    let _ = writeln!(out, "  exported dataset (native layout): {}", estimate::size(t.dataset_bytes));
    let d = &plan.database;
    let _ = writeln!(out, "\n{:<14} {:>14} {:>10} {:>12}", "table", "rows", "B/row", "bytes");
    for r in &d.tables {
        let _ = writeln!(
            out,
            "{:<14} {:>14} {:>10.0} {:>12}",
            r.table,
            count(r.rows),
            r.bytes_per_row,
            estimate::size(r.bytes)
        );
    }
    let _ = writeln!(out, "{:<14} {:>14} {:>10} {:>12}", "total", count(d.rows), "", estimate::size(d.bytes));
    let _ = writeln!(out, "  database bytes per sample: {:.0}", d.bytes_per_sample);
    let _ = writeln!(out, "\n  ({})\n  ({})\n  ({})", d.basis, plan.cost_basis, plan.gpu);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    const TINY: &str = include_str!("../../../examples/tiny.toml");
    const VINT_SIM: &str = include_str!("../../../examples/vint-sim.toml");

    #[test]
    fn hours_keep_two_significant_digits_below_one() {
        assert_eq!(hours(2_479.4), "2479");
        assert_eq!(hours(8.13), "8.1");
        assert_eq!(hours(0.25), "0.25");
        assert_eq!(hours(0.00471), "0.0047");
        assert_eq!(hours(0.0), "0");
    }

    #[test]
    fn counts_read_with_thousands_separators() {
        assert_eq!(count(0), "0");
        assert_eq!(count(999), "999");
        assert_eq!(count(1_560_000), "1,560,000");
        assert_eq!(count(16_276), "16,276");
    }

    #[test]
    fn tiny_is_an_upper_bound_with_its_chunks_exact() {
        let p = Plan::of(&DatasetSpec::parse(TINY).unwrap()).unwrap();
        assert!(!p.exact);
        let tasks: Vec<(&str, u64, bool)> = p.stages.iter().map(|s| (s.stage, s.tasks, s.tasks_exact)).collect();
        // 2 hands × 3 objects × 2 trials in chunks of 2; 6 views per grasp.
        assert_eq!(tasks, [("grasp", 6, true), ("render", 12, false), ("noise", 12, false), ("package", 6, false)]);
        assert_eq!(p.counts.samples, 72);
        assert_eq!(p.database.tables[0].rows, 1, "one job");
    }

    #[test]
    fn the_paper_recipe_has_its_rows_from_the_footprint_of_each_chunk() {
        let spec = DatasetSpec::parse(VINT_SIM).unwrap();
        let p = Plan::of(&spec).unwrap();
        let rows = |name: &str| p.database.tables.iter().find(|t| t.table == name).unwrap().rows;
        assert_eq!(p.counts.samples, 1_560_000);
        assert_eq!(rows("tasks"), p.totals.tasks);
        assert_eq!(rows("outputs"), p.totals.tasks, "every task of the recipe makes files: one row each");
        // Per view: 6 render files, 1 noise file, and the sample's files in its package.
        assert!(rows("outputs.files") > 14 * p.counts.samples, "{}", rows("outputs.files"));
        assert_eq!(rows("attempts"), p.totals.tasks, "one attempt per task");
        assert!(p.database.bytes_per_sample > 0.0);
        assert!(p.stages.iter().all(|s| s.cpu_hours > 0.0 && s.artifact_bytes > 0.0), "{:?}", p.stages);
    }
}
