//! `vintctl stats DIR|JOB --out OUT`: a dataset's statistics (occlusion, camera distance, viewing
//! direction in the object frame, active taxels per grasp by hand and region, grasp acceptance per
//! pair) as PNG figures, `stats.md` and `stats.json`. The numbers and plots are the engines'
//! Python (`python -m vint_engines stats`, which owns numpy and matplotlib); this command only
//! decides what the subject is, finds the interpreter, hands over and prints. A job id is first
//! exported through the coordinator into a temporary directory, exactly as `vintctl export` writes
//! it (`commands::export_job`), and removed afterwards.

use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow};
use tokio::process::Command;

use crate::formats::{Format, SHARD_SAMPLES, Target};
use crate::{CliResult, Failure, bad_input, commands, report};

/// What `python -m vint_engines stats` writes into OUT besides its figures.
const STATS_JSON: &str = "stats.json";

pub async fn run(
    subject: &str,
    out: &Path,
    store: Option<String>,
    coordinator: &vint_connect::Remote,
    json: bool,
) -> CliResult {
    let dir = Path::new(subject);
    if dir.is_dir() {
        return compute(dir, out, json).await;
    }
    if dir.exists() || subject.contains(std::path::MAIN_SEPARATOR) {
        return Err(bad_input(anyhow!("stats: {subject} is not a dataset directory (nor a job id)")));
    }
    let staging = Staging::new(subject)?;
    let native = Target { format: Format::Native, shard_samples: SHARD_SAMPLES as usize };
    commands::export_job(coordinator, subject, &staging.0, native, store).await?;
    compute(&staging.0, out, json).await
}

/// Runs the engines' statistics on the dataset at `dataset`; prints stats.json with `--json`,
/// else the engine's one-line summary.
async fn compute(dataset: &Path, out: &Path, json: bool) -> CliResult {
    let vint_engine_env::EngineEnv { engines_dir, python } = vint_engine_env::EngineEnv::from_env();
    let done = Command::new(&python)
        .args(["-m", "vint_engines", "stats", "--dataset"])
        .arg(dataset)
        .arg("--out")
        .arg(out)
        .env("PYTHONPATH", &engines_dir)
        .output()
        .await
        .with_context(|| format!("starting {}", python.display()))?;
    let said = String::from_utf8_lossy(&done.stderr);
    let said = said.trim();
    match done.status.code() {
        Some(0) => {}
        Some(2) => return Err(bad_input(anyhow!("{}", said.trim_start_matches("stats: ")))),
        _ => return Err(Failure { code: 1, error: anyhow!("stats failed ({}): {said}", done.status) }),
    }
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

/// A temporary directory for a job's exported dataset, removed when dropped (on success and on
/// failure alike: the statistics are what the user asked for, not the dataset).
struct Staging(PathBuf);

impl Staging {
    fn new(job_id: &str) -> Result<Staging, Failure> {
        let safe: String =
            job_id.chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' { c } else { '_' }).collect();
        let dir = std::env::temp_dir().join(format!("vint-stats-{safe}-{}", std::process::id()));
        if dir.exists() {
            std::fs::remove_dir_all(&dir).with_context(|| format!("removing stale {}", dir.display()))?;
        }
        Ok(Staging(dir))
    }
}

impl Drop for Staging {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}
