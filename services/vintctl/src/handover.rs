//! What the commands that hand a dataset over to the engines' Python share (`stats`, `preview`):
//! the dataset named on the command line — a directory, or a finished job's id, first exported
//! through the coordinator into a temporary directory exactly as `vintctl export` writes it
//! (`commands::export_job`) and removed afterwards — and running `python -m vint_engines COMMAND`
//! on it, its exit status 2 (the engine's "not a dataset I read", said on stderr) becoming bad
//! input.

use std::path::{Path, PathBuf};
use std::process::Output;

use anyhow::{Context, anyhow};
use tokio::process::Command;

use crate::formats::{Format, SHARD_SAMPLES, Target};
use crate::{Failure, bad_input, commands};

/// A dataset directory to read: the user's own, or a job's export that lives as long as this.
pub struct DatasetDir {
    path: PathBuf,
    _staging: Option<Staging>,
}

impl DatasetDir {
    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// `subject` as `command` (the command's name, for messages and the temporary directory's) reads
/// it: an existing directory as it is, anything else that could be a job id exported from the
/// coordinator in the native layout.
pub async fn dataset(
    command: &str,
    subject: &str,
    store: Option<String>,
    coordinator: &vint_connect::Remote,
) -> Result<DatasetDir, Failure> {
    let dir = Path::new(subject);
    if dir.is_dir() {
        return Ok(DatasetDir { path: dir.to_path_buf(), _staging: None });
    }
    if dir.exists() || subject.contains(std::path::MAIN_SEPARATOR) {
        return Err(bad_input(anyhow!("{command}: {subject} is not a dataset directory (nor a job id)")));
    }
    let staging = Staging::new(command, subject)?;
    let native = Target { format: Format::Native, shard_samples: SHARD_SAMPLES as usize };
    commands::export_job(coordinator, subject, &staging.0, native, store).await?;
    Ok(DatasetDir { path: staging.0.clone(), _staging: Some(staging) })
}

/// Runs `python -m vint_engines COMMAND ARGS…` with the engines' interpreter and returns what it
/// printed; exit status 2 is bad input carrying the engine's message (less its `COMMAND: `
/// prefix), any other failure exit code 1.
pub async fn engines(command: &str, args: &[&std::ffi::OsStr]) -> Result<Output, Failure> {
    let vint_engine_env::EngineEnv { engines_dir, python } = vint_engine_env::EngineEnv::from_env();
    let done = Command::new(&python)
        .args(["-m", "vint_engines", command])
        .args(args)
        .env("PYTHONPATH", &engines_dir)
        .output()
        .await
        .with_context(|| format!("starting {}", python.display()))?;
    let said = String::from_utf8_lossy(&done.stderr);
    let said = said.trim();
    match done.status.code() {
        Some(0) => Ok(done),
        Some(2) => Err(bad_input(anyhow!("{}", said.trim_start_matches(&format!("{command}: "))))),
        _ => Err(Failure { code: 1, error: anyhow!("{command} failed ({}): {said}", done.status) }),
    }
}

/// A temporary directory for a job's exported dataset, removed when dropped (on success and on
/// failure alike: what the command makes of it is what the user asked for, not the dataset).
struct Staging(PathBuf);

impl Staging {
    fn new(command: &str, job_id: &str) -> Result<Staging, Failure> {
        let safe: String =
            job_id.chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' { c } else { '_' }).collect();
        let dir = std::env::temp_dir().join(format!("vint-{command}-{safe}-{}", std::process::id()));
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
