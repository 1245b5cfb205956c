//! `vintctl stats DIR|JOB --out OUT`: a dataset's statistics (occlusion, camera distance, viewing
//! direction in the object frame, active taxels per grasp by hand and region, grasp acceptance per
//! pair) as PNG figures, `stats.md` and `stats.json`. The numbers and plots are the engines'
//! Python (`python -m vint_engines stats`, which owns numpy and matplotlib); this command only
//! decides what the subject is, finds the interpreter, hands over and prints (`handover`: a job id
//! is first exported through the coordinator into a temporary directory, and removed afterwards).

use std::path::Path;

use anyhow::Context;

use crate::{CliResult, handover, report};

/// What `python -m vint_engines stats` writes into OUT besides its figures.
const STATS_JSON: &str = "stats.json";

pub async fn run(
    subject: &str,
    out: &Path,
    store: Option<String>,
    coordinator: &vint_connect::Remote,
    json: bool,
) -> CliResult {
    let dataset = handover::dataset("stats", subject, store, coordinator).await?;
    compute(dataset.path(), out, json).await
}

/// Runs the engines' statistics on the dataset at `dataset`; prints stats.json with `--json`,
/// else the engine's one-line summary.
async fn compute(dataset: &Path, out: &Path, json: bool) -> CliResult {
    let done =
        handover::engines("stats", &["--dataset".as_ref(), dataset.as_os_str(), "--out".as_ref(), out.as_os_str()])
            .await?;
    if json {
        let path = out.join(STATS_JSON);
        let text = std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
        let stats: serde_json::Value =
            serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))?;
        report::print_json(&stats);
    } else {
        print!("{}", String::from_utf8_lossy(&done.stdout));
    }
    Ok(())
}
