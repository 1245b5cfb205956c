//! `vintctl`: the command line of vint. It parses arguments and wires the libraries together:
//! `run` starts an embedded coordinator, SQLite store and local workers; the other commands talk
//! to a coordinator over gRPC (`client`), print with `report` and write datasets with `export`.
//!
//! Exit codes: 0 success, 1 failure (a job failed, a service is unreachable), 2 bad input
//! (an invalid spec, an unknown job or sample, a bad argument). With `--json`, a failure is JSON
//! on stdout too (`{"error": {"message", "code", …}}`), with the same exit code.

mod against;
mod bop_objects;
mod client;
mod commands;
mod delete;
mod depth;
mod diff;
mod embedded;
mod estimate;
mod eval;
mod export;
mod failure;
mod formats;
mod gc;
mod handover;
mod mjcf;
mod plan;
mod preview;
mod report;
mod spec_file;
mod state_dir;
mod stats;
mod study;

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::anyhow;
use clap::{CommandFactory, Parser, Subcommand};

pub use failure::{CliResult, Failure, InvalidSpec, bad_input};

/// Shown after `vintctl --help` and by a bare `vintctl`: how to start.
const GETTING_STARTED: &str = "\
Getting started:
  vintctl validate examples/tiny.toml                  check a spec: every problem, and what it would cost
  vintctl plan examples/vint-sim.toml                  a spec's tasks, database rows and bytes, CPU-hours
  vintctl run examples/tiny.toml --out out/tiny        make its dataset on this machine (no server needed)
  vintctl hands; vintctl objects                       what a spec can name

On a cluster (a running vint-coordinator; --coordinator URL or VINT_COORDINATOR):
  vintctl submit SPEC, then watch / status / jobs / cancel / lineage / export JOB
  vintctl dashboard VIEW [--job JOB]                   progress, throughput, failures, workers, … (docs/dashboard.md)

Specs, the cluster and every output are described in docs/guide.md (the README is the tour).";

#[derive(Parser)]
#[command(name = "vintctl", version, about = "Generate visuo-tactile in-hand datasets", after_help = GETTING_STARTED)]
struct Cli {
    /// Print machine-readable JSON instead of text (errors too, on stdout).
    #[arg(long, global = true)]
    json: bool,
    /// Coordinator URL for the commands that talk to one (all but validate, plan, run, convert, eval,
    /// diff, study, hands, objects, and stats and preview on a directory); HOST:PORT means http://HOST:PORT.
    #[arg(long, global = true, env = "VINT_COORDINATOR", default_value = "http://127.0.0.1:7700")]
    coordinator: String,
    /// Bearer token for a coordinator started with --auth-tokens (a submit token to submit and
    /// cancel, a read or submit token for the rest).
    #[arg(long, global = true, env = "VINT_TOKEN", hide_env_values = true)]
    token: Option<String>,
    /// PEM certificate of the authority that signed an https:// coordinator's certificate (default:
    /// the system's trusted roots).
    #[arg(long, global = true, env = "VINT_TLS_CA")]
    tls_ca: Option<PathBuf>,
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// Check a dataset spec and report every problem.
    Validate {
        /// The spec file (TOML; see examples/tiny.toml).
        spec: PathBuf,
        /// The limits to judge it by: a coordinator's defaults unless raised (or lowered) here.
        #[command(flatten)]
        limits: vint_coordinator::LimitFlags,
    },
    /// What a spec will cost before anything runs: tasks per stage, database rows and bytes, object
    /// store bytes and CPU-hours per stage (no server needed). With --against JOB: per stage, how
    /// many tasks a run would reuse from finished results and why the others would run.
    Plan {
        /// The spec file (TOML; see examples/vint-sim.toml).
        spec: PathBuf,
        /// A job in the state directory to forecast against (its id, as `vintctl run` prints it).
        #[arg(long)]
        against: Option<String>,
        /// The state directory of `vintctl run` (with --against).
        #[arg(long, default_value = ".vint", requires = "against")]
        state: PathBuf,
        /// A cluster's database URL, instead of --state (with --against).
        #[arg(long, requires = "against")]
        database: Option<String>,
        /// The limits to judge it by: a coordinator's defaults unless raised (or lowered) here.
        #[command(flatten)]
        limits: vint_coordinator::LimitFlags,
    },
    /// Run a spec on this machine: embedded coordinator, SQLite, local object store and workers.
    Run {
        /// The spec file (TOML; see examples/tiny.toml).
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
        /// Run every task, even one whose result (same stage, engine, parameters and input
        /// contents) is already in the state directory; by default such tasks are reused.
        #[arg(long)]
        no_reuse: bool,
        #[command(flatten)]
        format: FormatArgs,
        /// What the job may ask for (the embedded coordinator's limits).
        #[command(flatten)]
        limits: vint_coordinator::LimitFlags,
    },
    /// Submit a spec to a coordinator and print the job id.
    Submit {
        /// The spec file (TOML); the files it names travel with it.
        spec: PathBuf,
        /// Retrying with the same key returns the same job (default: the spec's content hash).
        #[arg(long)]
        idempotency_key: Option<String>,
        /// Let timing-only workers (`vint-worker --engine-mode timing-only`) serve the job, to
        /// measure the system: its files are then stand-ins, not data, and export refuses it.
        /// A timing-only worker never serves a job submitted without it.
        #[arg(long)]
        timing_only: bool,
    },
    /// Delete the stored objects no job references (outputs of attempts whose completion never
    /// landed), from a `vintctl run` state directory or a cluster's database and object store.
    Gc {
        /// The state directory of `vintctl run`.
        #[arg(long, default_value = ".vint", conflicts_with = "database")]
        state: PathBuf,
        /// A cluster's database URL (with --store instead of --state).
        #[arg(long, requires = "store")]
        database: Option<String>,
        /// A cluster's object store URL (file:///abs/dir or s3://bucket[/prefix]).
        #[arg(long, requires = "database")]
        store: Option<String>,
        /// Keep objects younger than this many seconds: a task's outputs are uploaded before its
        /// completion is recorded.
        #[arg(long, default_value_t = 3_600)]
        min_age_s: u64,
        /// Count what would be deleted, delete nothing.
        #[arg(long)]
        dry_run: bool,
    },
    /// Delete an ended job and every database row of it (tasks, attempts, output records,
    /// submitted files' records), from a `vintctl run` state directory or a cluster's database;
    /// `vintctl gc` then deletes the objects no job references. A running job is refused: cancel
    /// it first.
    Delete {
        /// The job id (`vintctl jobs` lists them).
        job: String,
        /// The state directory of `vintctl run`.
        #[arg(long, default_value = ".vint", conflicts_with = "database")]
        state: PathBuf,
        /// A cluster's database URL.
        #[arg(long)]
        database: Option<String>,
        /// Count what would be deleted, delete nothing.
        #[arg(long)]
        dry_run: bool,
    },
    /// Show a job's state and progress, and why its tasks failed.
    Status {
        /// The job id `submit` printed (`vintctl jobs` lists them).
        job: String,
    },
    /// Follow a job's progress until it ends.
    Watch {
        /// The job id `submit` printed (`vintctl jobs` lists them).
        job: String,
    },
    /// Cancel a job: nothing more of it is leased; running attempts are discarded.
    Cancel {
        /// The job id `submit` printed (`vintctl jobs` lists them).
        job: String,
    },
    /// List recent jobs.
    Jobs {
        /// How many jobs, most recent first.
        #[arg(long, default_value_t = 20)]
        limit: u32,
    },
    /// Query a dashboard view (docs/dashboard.md): job_progress, throughput, failures, workers,
    /// grasp_acceptance, grasp_rejections, active_taxels, render_seconds, bytes_written.
    Dashboard {
        /// The view's name.
        view: String,
        /// Only this job's rows (default: every job; the workers view is not per job).
        #[arg(long)]
        job: Option<String>,
        /// Most rows shown (at most 10,000; 0: 10,000).
        #[arg(long, default_value_t = 1000)]
        limit: u32,
    },
    /// Show the chain of tasks, parameters, engine versions and artifact hashes behind a sample
    /// (or, with --artifact, behind any artifact hash).
    Lineage {
        /// A sample id (OBJECT.HAND.gNNNNNN.vNN) or, with --artifact, a sha256.
        subject: String,
        /// The job that packaged the sample (default: the most recent one that did).
        #[arg(long)]
        job: Option<String>,
        /// SUBJECT is an artifact's (or a submitted file's) sha256, not a sample id.
        #[arg(long)]
        artifact: bool,
    },
    /// Write a finished job's samples and manifest.jsonl to a directory.
    Export {
        /// The job id `submit` printed (`vintctl jobs` lists them).
        job: String,
        /// Where the dataset and manifest.jsonl are written.
        #[arg(long)]
        out: PathBuf,
        /// Artifact store URL the workers wrote to (file:///… or s3://…); default: the
        /// coordinator's own --store.
        #[arg(long, env = "VINT_STORE", hide_env_values = true)]
        store: Option<String>,
        #[command(flatten)]
        format: FormatArgs,
    },
    /// Convert a dataset in the native layout (what `run` and `export` write by default) to BOP's
    /// layout or WebDataset shards.
    Convert {
        /// The native dataset directory (with dataset.json and manifest.jsonl).
        dataset: PathBuf,
        /// Where the converted dataset and its manifest.jsonl are written.
        #[arg(long)]
        out: PathBuf,
        #[command(flatten)]
        format: FormatArgs,
    },
    /// Accuracy-versus-cost studies: run the same work at several settings against a fine
    /// reference and write CSV, a log-log plot and a markdown table.
    Study {
        /// What to study: `grasp` (physics timestep and solver settings), `render` (Cycles samples
        /// and denoising against a high-sample reference) or `touch` (ICP pose accuracy with and
        /// without the taxels, by occlusion; makes its own dataset with this binary).
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
    /// A dataset's statistics: occlusion, camera distance, viewing direction in the object frame,
    /// active taxels per grasp by hand and region, grasp acceptance per (object, hand) pair — as PNG
    /// figures, stats.md (tables) and stats.json (the numbers; printed with --json).
    Stats {
        /// A dataset directory (native layout, or BOP from `--format bop`), or a finished job's id
        /// (its dataset is exported from the coordinator to a temporary directory first).
        dataset: String,
        /// Directory for the figures, stats.md and stats.json.
        #[arg(long)]
        out: PathBuf,
        /// For a job id: the artifact store its workers wrote to (file:///… or s3://…); default:
        /// the coordinator's own --store.
        #[arg(long, env = "VINT_STORE", hide_env_values = true)]
        store: Option<String>,
    },
    /// A contact sheet of a native dataset (PNG): per sample one row of RGB, depth, noisy depth,
    /// segmentation and the RGB with the grasp's active taxels, under a caption (docs/preview.md).
    Preview {
        /// A native dataset directory, or a finished job's id (its dataset is exported from the
        /// coordinator to a temporary directory first).
        dataset: String,
        /// The PNG to write.
        #[arg(long)]
        out: PathBuf,
        /// Rows: samples shown, spread over objects and hands (the first of each pair, then by id).
        #[arg(long, default_value_t = preview::DEFAULT_SAMPLES,
              value_parser = clap::value_parser!(u32).range(1..=i64::from(preview::MAX_SAMPLES)))]
        samples: u32,
        /// For a job id: the artifact store its workers wrote to (file:///… or s3://…); default:
        /// the coordinator's own --store.
        #[arg(long, env = "VINT_STORE", hide_env_values = true)]
        store: Option<String>,
    },
    /// Compare two exported datasets with a tolerance per kind of file (pixels, depth in metres,
    /// poses, touch readings); say which samples differ and by how much. Exit 0: all within
    /// tolerance; 1: some sample differs beyond it or is missing on one side.
    Diff(diff::DiffArgs),
    /// Score pose estimates (a BOP results CSV) against a BOP dataset: ADD, ADD-S and ADD(S) AUC up
    /// to 10 cm, ADD(S)-0.1d and -0.05d, overall, per object and per occlusion bucket.
    Eval(eval::EvalArgs),
    /// Print `[object.NAME]` tables for models of a BOP dataset's models folder (models_info.json
    /// and obj_NNNNNN.ply, millimetres, with their textures): each keeps its obj_id and its
    /// symmetries (in metres); paste them into a spec (docs/assets.md).
    BopObjects {
        /// The models folder, relative to the spec's directory (run this there), e.g. `ycbv_models/models`.
        models: PathBuf,
        /// The models' obj_ids, e.g. `--ids 2,5,14`.
        #[arg(long, value_delimiter = ',', required = true)]
        ids: Vec<u32>,
        /// Each model's mass (BOP gives none): `--mass 2=0.411,5=0.603,14=0.349`.
        #[arg(long, required = true)]
        mass: Vec<String>,
        /// The material tag of every model (roughness, metal, glass; the texture gives the colour).
        #[arg(long, default_value = "plastic")]
        material: String,
        /// The objects' names: PREFIX + obj_id.
        #[arg(long, default_value = "bop_")]
        prefix: String,
    },
    /// List the built-in hands with their DoF and taxel counts per region.
    Hands,
    /// List the built-in objects: BOP obj_id, the ycbv object each stands in for, mass, material,
    /// texture and symmetries (`--json`: the full entries, symmetries in BOP's form).
    Objects,
}

/// The dataset layout an export writes (`docs/formats.md`).
#[derive(clap::Args)]
struct FormatArgs {
    /// Layout of the dataset: native (a directory per sample and per grasp), bop (the BOP
    /// toolkit's layout, one scene per grasp), webdataset (tar shards) or bop-webdataset (BOP's
    /// training-set shards, one key per image, in a seeded order).
    #[arg(long, value_enum, default_value = "native")]
    format: formats::Format,
    /// Samples per shard (at most), for webdataset and bop-webdataset.
    #[arg(long, default_value_t = formats::SHARD_SAMPLES, value_parser = clap::value_parser!(u64).range(1..))]
    shard_samples: u64,
}

impl FormatArgs {
    fn target(&self) -> formats::Target {
        formats::Target {
            format: self.format,
            shard_samples: usize::try_from(self.shard_samples).unwrap_or(usize::MAX),
        }
    }
}

fn main() -> ExitCode {
    let json = std::env::args().any(|a| a == "--json");
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) if !json || !e.use_stderr() => e.exit(), // help and version, or a usage error for people
        Err(e) => {
            let rendered = e.render().to_string();
            let message = rendered.trim_end().trim_start_matches("error: ");
            report::failure(&bad_input(anyhow!("{message}")), true);
            return ExitCode::from(2);
        }
    };
    let Some(command) = cli.command else {
        return getting_started(cli.json);
    };
    let runtime = match tokio::runtime::Builder::new_multi_thread().enable_all().build() {
        Ok(rt) => rt,
        Err(e) => {
            report::failure(&anyhow!("cannot start the async runtime: {e}").into(), cli.json);
            return ExitCode::from(1);
        }
    };
    let remote = vint_connect::Remote { url: cli.coordinator, token: cli.token, tls_ca: cli.tls_ca };
    match runtime.block_on(dispatch(command, cli.json, &remote)) {
        Ok(()) => ExitCode::SUCCESS,
        Err(f) => {
            report::failure(&f, cli.json);
            ExitCode::from(f.code)
        }
    }
}

/// A bare `vintctl`: the commands and how to start, instead of a terse usage error (exit 2: no
/// command ran).
fn getting_started(json: bool) -> ExitCode {
    if json {
        report::failure(&bad_input(anyhow!("no command given\n\n{GETTING_STARTED}")), true);
    } else {
        let mut cli = Cli::command();
        eprintln!("{}", cli.render_help());
    }
    ExitCode::from(2)
}

async fn dispatch(command: Command, json: bool, coordinator: &vint_connect::Remote) -> CliResult {
    match command {
        Command::Validate { spec, limits } => commands::validate(&spec, &limits.limits(), json),
        Command::Plan { spec, against: None, limits, .. } => commands::plan(&spec, &limits.limits(), json),
        Command::Plan { spec, against: Some(job), state, database, .. } => {
            let records = match &database {
                Some(database) => state_dir::Records::Urls { database, store: "" },
                None => state_dir::Records::State(&state),
            };
            against::plan_against(&spec, &job, &records, json).await
        }
        Command::Run { spec, out, state, workers, no_reuse, format, limits } => {
            let local = embedded::Local { state: &state, workers, reuse: !no_reuse, limits: limits.limits() };
            embedded::run(&spec, &out, format.target(), &local, json).await
        }
        Command::Gc { state, database, store, min_age_s, dry_run } => {
            let records = match (&database, &store) {
                (Some(database), Some(store)) => state_dir::Records::Urls { database, store },
                _ => state_dir::Records::State(&state),
            };
            gc::gc(&records, min_age_s, dry_run, json).await
        }
        Command::Delete { job, state, database, dry_run } => {
            let records = match &database {
                Some(database) => state_dir::Records::Urls { database, store: "" },
                None => state_dir::Records::State(&state),
            };
            delete::delete(&records, &job, dry_run, json).await
        }
        Command::Submit { spec, idempotency_key, timing_only } => {
            commands::submit(coordinator, &spec, idempotency_key, timing_only, json).await
        }
        Command::Status { job } => commands::status(coordinator, &job, json).await,
        Command::Watch { job } => commands::watch(coordinator, &job, json).await,
        Command::Cancel { job } => commands::cancel(coordinator, &job, json).await,
        Command::Jobs { limit } => commands::jobs(coordinator, limit, json).await,
        Command::Dashboard { view, job, limit } => {
            commands::dashboard(coordinator, &view, job.as_deref(), limit, json).await
        }
        Command::Lineage { subject, job, artifact } => {
            commands::lineage(coordinator, &subject, job, artifact, json).await
        }
        Command::Export { job, out, store, format } => {
            commands::export(coordinator, &job, &out, format.target(), store, json).await
        }
        Command::Convert { dataset, out, format } => commands::convert(&dataset, &out, format.target(), json),
        Command::Study { subject, out, quick, extra } => study::run(&subject, &out, quick, &extra).await,
        Command::Stats { dataset, out, store } => stats::run(&dataset, &out, store, coordinator, json).await,
        Command::Preview { dataset, out, samples, store } => {
            preview::run(&dataset, &out, samples, store, coordinator, json).await
        }
        Command::Diff(args) => diff::run(&args, json),
        Command::Eval(args) => eval::run(&args, json),
        Command::BopObjects { models, ids, mass, material, prefix } => {
            bop_objects::run(&models, &ids, &mass, &material, &prefix)
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Every command, positional and flag says what it is in `--help`.
    #[test]
    fn every_argument_has_help_text() {
        let cli = Cli::command();
        let mut missing = Vec::new();
        for cmd in std::iter::once(&cli).chain(cli.get_subcommands()) {
            if cmd.get_about().is_none() {
                missing.push(cmd.get_name().to_string());
            }
            for arg in cmd.get_arguments().filter(|a| !matches!(a.get_id().as_str(), "help" | "version")) {
                if arg.get_help().is_none() {
                    missing.push(format!("{} {}", cmd.get_name(), arg.get_id()));
                }
            }
        }
        assert!(missing.is_empty(), "no help text: {missing:?}");
    }
}
