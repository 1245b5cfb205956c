//! `vintctl study`: accuracy-versus-cost studies. Each study runs inside the engine that owns the
//! physics or pixels (`python -m vint_engines study SUBJECT`), so it measures exactly the code
//! that produces datasets; this command finds the engines' interpreter and hands over. The touch
//! study scores an estimator on a dataset that vintctl itself makes, so it is also given this
//! binary's path (`--vintctl`) to run the spec, convert and score with.

use std::path::Path;

use anyhow::{Context, anyhow};
use tokio::process::Command;

use crate::{CliResult, Failure, bad_input};

/// Studies the engines implement.
const SUBJECTS: &[&str] = &["grasp", "render", "touch"];

pub async fn run(subject: &str, out: &Path, quick: bool, extra: &[String]) -> CliResult {
    if !SUBJECTS.contains(&subject) {
        return Err(bad_input(anyhow!("study: unknown subject {subject:?}; expected one of {}", SUBJECTS.join(", "))));
    }
    let vint_engine_env::EngineEnv { engines_dir: engines, python } = vint_engine_env::EngineEnv::from_env();
    let mut cmd = Command::new(&python);
    cmd.args(["-m", "vint_engines", "study", subject, "--out"]).arg(out).env("PYTHONPATH", &engines);
    if quick {
        cmd.arg("--quick");
    }
    if subject == "touch" {
        let vintctl = std::env::current_exe().context("finding the vintctl binary for the touch study")?;
        cmd.arg("--vintctl").arg(vintctl);
    }
    cmd.args(extra);
    let status = cmd.status().await.with_context(|| format!("starting {}", python.display()))?;
    match status.code() {
        Some(0) => Ok(()),
        Some(2) => Err(bad_input(anyhow!("study {subject}: invalid arguments (see above)"))),
        _ => Err(Failure { code: 1, error: anyhow!("study {subject} failed ({status})") }),
    }
}
