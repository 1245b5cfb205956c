//! `vintctl`: the command line of vint. It parses arguments and wires the libraries together:
//! `run` starts an embedded coordinator, SQLite store and local workers; the other commands talk
//! to a coordinator over gRPC.
//!
//! Exit codes: 0 success, 1 failure (a job failed, a service is unreachable), 2 bad input
//! (an invalid spec, an unknown job or sample, a bad argument).

mod client;
mod diff;
mod embedded;
mod export;
mod report;
mod study;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "vintctl", version, about = "Generate visuo-tactile in-hand datasets")]
struct Cli {
    /// Print machine-readable JSON instead of text.
    #[arg(long, global = true)]
    json: bool,
    /// Coordinator URL for the commands that talk to one (all but validate, run, hands and objects).
    #[arg(long, global = true, env = "VINT_COORDINATOR", default_value = "http://127.0.0.1:7700")]
    coordinator: String,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Check a dataset spec and report every problem.
    Validate { spec: PathBuf },
    /// Run a spec on this machine: embedded coordinator, SQLite, local object store and workers.
    Run {
        spec: PathBuf,
        /// Where the packaged dataset and manifest.jsonl are written.
        #[arg(long)]
        out: PathBuf,
        /// State directory (database, artifacts, logs). Re-running a spec with the same state
        /// resumes its job.
        #[arg(long, default_value = ".vint")]
        state: PathBuf,
        /// Worker processes to start.
        #[arg(long, default_value_t = 2)]
        workers: u32,
    },
    /// Submit a spec to a coordinator and print the job id.
    Submit {
        spec: PathBuf,
        /// Retrying with the same key returns the same job (default: the spec's content hash).
        #[arg(long)]
        idempotency_key: Option<String>,
    },
    /// Show a job's state and progress.
    Status { job: String },
    /// Follow a job's progress until it ends.
    Watch { job: String },
    /// Cancel a job: nothing more of it is leased; running attempts are discarded.
    Cancel { job: String },
    /// List recent jobs.
    Jobs {
        #[arg(long, default_value_t = 20)]
        limit: u32,
    },
    /// Show the chain of tasks, parameters, engine versions and artifact hashes behind a sample
    /// (or, with --artifact, behind any artifact hash).
    Lineage {
        /// A sample id (OBJECT.HAND.gNNNNNN.vNN) or, with --artifact, a sha256.
        subject: String,
        #[arg(long)]
        job: Option<String>,
        #[arg(long)]
        artifact: bool,
    },
    /// Write a finished job's samples and manifest.jsonl to a directory.
    Export {
        job: String,
        #[arg(long)]
        out: PathBuf,
        /// Artifact store URL the workers wrote to (file:///… or s3://…).
        #[arg(long, env = "VINT_STORE")]
        store: String,
    },
    /// Accuracy-versus-cost studies: run the same work at several settings against a fine
    /// reference and write CSV, a log-log plot and a markdown table.
    Study {
        /// What to study: `grasp` (physics timestep and solver settings) or `render` (Cycles samples
        /// and denoising against a high-sample reference).
        subject: String,
        /// Directory for the CSV, PNG and markdown outputs.
        #[arg(long)]
        out: PathBuf,
        /// A small, fast version of the study (seconds, for smoke tests).
        #[arg(long)]
        quick: bool,
        /// Extra arguments for the study (e.g. `--hands trx3 --seeds 4`), after `--`.
        #[arg(last = true)]
        extra: Vec<String>,
    },
    /// Compare two exported datasets with a tolerance per kind of file (pixels, depth in metres,
    /// poses, touch readings); say which samples differ and by how much. Exit 0: all within
    /// tolerance; 1: some sample differs beyond it or is missing on one side.
    Diff(diff::DiffArgs),
    /// List the built-in hands with their DoF and taxel counts per region.
    Hands,
    /// List the built-in objects with their mass, material and symmetry tags.
    Objects,
}

/// A failure and the exit code it deserves.
pub struct Failure {
    pub code: u8,
    pub error: anyhow::Error,
}

impl<E: Into<anyhow::Error>> From<E> for Failure {
    fn from(e: E) -> Self {
        Failure { code: 1, error: e.into() }
    }
}

/// Bad input from the user: exit code 2.
pub fn bad_input(error: anyhow::Error) -> Failure {
    Failure { code: 2, error }
}

pub type CliResult = Result<(), Failure>;

fn main() -> ExitCode {
    let cli = Cli::parse();
    let runtime = match tokio::runtime::Builder::new_multi_thread().enable_all().build() {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("error: cannot start the async runtime: {e}");
            return ExitCode::from(1);
        }
    };
    match runtime.block_on(dispatch(cli)) {
        Ok(()) => ExitCode::SUCCESS,
        Err(f) => {
            eprintln!("error: {:#}", f.error);
            ExitCode::from(f.code)
        }
    }
}

async fn dispatch(cli: Cli) -> CliResult {
    let json = cli.json;
    let coordinator = cli.coordinator;
    match cli.command {
        Command::Validate { spec } => client::validate(&spec, json),
        Command::Run { spec, out, state, workers } => embedded::run(&spec, &out, &state, workers, json).await,
        Command::Submit { spec, idempotency_key } => client::submit(&coordinator, &spec, idempotency_key, json).await,
        Command::Status { job } => client::status(&coordinator, &job, json).await,
        Command::Watch { job } => client::watch(&coordinator, &job, json).await,
        Command::Cancel { job } => client::cancel(&coordinator, &job, json).await,
        Command::Jobs { limit } => client::jobs(&coordinator, limit, json).await,
        Command::Lineage { subject, job, artifact } => {
            client::lineage(&coordinator, &subject, job, artifact, json).await
        }
        Command::Export { job, out, store } => client::export(&coordinator, &job, &out, &store, json).await,
        Command::Study { subject, out, quick, extra } => study::run(&subject, &out, quick, &extra).await,
        Command::Diff(args) => diff::run(&args, json),
        Command::Hands => {
            report::hands(json);
            Ok(())
        }
        Command::Objects => {
            report::objects(json);
            Ok(())
        }
    }
}
