//! `vintctl run`: the whole factory on one machine, with no server to install.
//!
//! It starts the coordinator in-process on a loopback port over SQLite and a local object store
//! (both under the state directory), spawns local worker processes, submits the spec, follows the
//! job with a progress bar, restarts any worker that dies, and exports the dataset. It is the
//! cluster code path with the deployment folded into one command: the same coordinator, store
//! semantics and worker binary.

use std::net::{Ipv4Addr, SocketAddr};
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::Duration;

use anyhow::{Context, anyhow};
use tokio::process::{Child, Command};
use vint_coordinator::CoordinatorConfig;
use vint_proto::v1 as pb;
use vint_store::{RetryPolicy, Store};

use crate::client::Coordinator;
use crate::formats::Target;
use crate::report::{self, JsonProgress, ProgressView};
use crate::spec_file::{LoadedSpec, load_spec};
use crate::{CliResult, Failure, bad_input, commands, export};

/// Lease used by local workers: short, so a crashed worker's task is retried within seconds.
const LOCAL_LEASE_MS: u32 = 10_000;

/// Where `vintctl run` keeps its state and how it runs its workers.
pub struct Local<'a> {
    /// The state directory: database, artifacts, logs.
    pub state: &'a Path,
    pub workers: u32,
    /// Whether workers reuse finished tasks' results (their `--no-reuse` when not).
    pub reuse: bool,
    /// The embedded coordinator's limits on the job.
    pub limits: vint_core::limits::Limits,
}

pub async fn run(spec_path: &Path, out: &Path, target: Target, local: &Local<'_>, json: bool) -> CliResult {
    let Local { state, workers, reuse, limits } = *local;
    let LoadedSpec { text, spec, assets } = load_spec(spec_path)?;
    crate::commands::check_limits(spec_path, &spec, &limits)?;
    export::check_destination(out)?;
    if workers == 0 || workers > 64 {
        return Err(bad_input(anyhow!("--workers: must be 1..=64, got {workers}")));
    }
    std::fs::create_dir_all(state.join("logs"))
        .with_context(|| format!("creating state directory {}", state.display()))?;
    let state = state.canonicalize().with_context(|| format!("resolving {}", state.display()))?;
    let (db_url, store_url) = crate::state_dir::state_urls(&state);
    let artifacts = vint_artifacts::ArtifactStore::open(&store_url)?;

    let retry = RetryPolicy { max_attempts: 4, backoff_base_ms: 500, backoff_cap_ms: 10_000 };
    let store = Store::open(&db_url, retry).await.with_context(|| format!("opening {db_url}"))?;
    let (listener, addr) = vint_coordinator::bind(SocketAddr::from((Ipv4Addr::LOCALHOST, 0))).await?;
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    // The coordinator stores the spec's user files where the local workers read artifacts.
    let config = CoordinatorConfig { artifacts: Some(artifacts.clone()), limits, ..CoordinatorConfig::default() };
    let server = tokio::spawn(vint_coordinator::serve(store.clone(), config, listener, async {
        let _ = stop_rx.await;
    }));
    let url = format!("http://{addr}");

    let result = async {
        // In-process on loopback with no tokens file: no token, no TLS.
        let remote = vint_connect::Remote { url: url.clone(), ..vint_connect::Remote::default() };
        let mut coordinator = Coordinator::connect(&remote).await?;
        let submitted = coordinator
            .submit(pb::SubmitJobRequest {
                spec_toml: text,
                idempotency_key: String::new(),
                assets,
                timing_only: false,
            })
            .await?;
        let job = submitted.job.ok_or_else(|| anyhow!("coordinator returned no job"))?;
        if !json {
            let verb = if submitted.created { "started" } else { "resumed" };
            eprintln!(
                "{verb} job {} ({}): up to {} samples, {workers} worker(s); state in {}",
                job.job_id,
                spec.dataset.name,
                spec.max_samples(),
                state.display()
            );
        }
        let mut pool = WorkerPool::start(&url, &store_url, &state, workers, reuse)?;
        let view = ProgressView::new(json.then_some(JsonProgress::Stderr));
        let followed = tokio::select! {
            r = coordinator.follow(&job.job_id, &view) => r,
            e = pool.supervise() => Err(e),
        };
        pool.stop().await;
        let last = followed?;
        let listed = coordinator.samples(&job.job_id).await?;
        let info = export::DatasetInfo { name: &spec.dataset.name, seed: spec.dataset.seed, split: &spec.split };
        let summary = export::export(&artifacts, &job.job_id, &info, &listed, out, target).await?;
        let outcome = commands::job_outcome(&last);
        if !json {
            println!("{}", report::work_line(&last));
            report::export_text(&summary);
            return outcome;
        }
        // One document: what was exported, how the job ended and, when it failed, why.
        let mut doc = report::export_json(&summary);
        doc["state"] = last.state.clone().into();
        doc["tasks_failed"] = last.tasks_failed.into();
        doc["failed_tasks"] = report::failed_tasks_json(&last.failed_tasks);
        doc["stages"] = report::progress_json(&last)["stages"].clone();
        match outcome {
            Ok(()) => {
                report::print_json(&doc);
                Ok(())
            }
            Err(f) => Err(f.with_report(doc)),
        }
    }
    .await;

    let _ = stop_tx.send(());
    let _ = server.await;
    store.close().await;
    result
}

/// Local worker processes, restarted when they die.
struct WorkerPool {
    children: Vec<Child>,
    coordinator: String,
    store_url: String,
    state: PathBuf,
    reuse: bool,
    restarts: u32,
}

impl WorkerPool {
    fn start(coordinator: &str, store_url: &str, state: &Path, n: u32, reuse: bool) -> Result<WorkerPool, Failure> {
        let mut pool = WorkerPool {
            children: Vec::new(),
            coordinator: coordinator.to_string(),
            store_url: store_url.to_string(),
            state: state.to_path_buf(),
            reuse,
            restarts: 0,
        };
        for i in 0..n {
            let child = pool.spawn(i as usize)?;
            pool.children.push(child);
        }
        Ok(pool)
    }

    fn spawn(&self, index: usize) -> Result<Child, Failure> {
        let bin = worker_binary()?;
        let log_path = self.state.join("logs").join(format!("worker-{index}.log"));
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&log_path)
            .with_context(|| format!("opening {}", log_path.display()))?;
        let mut command = Command::new(&bin);
        if !self.reuse {
            command.arg("--no-reuse");
        }
        let child = command
            .arg("--coordinator")
            .arg(&self.coordinator)
            .arg("--store")
            .arg(&self.store_url)
            .arg("--scratch")
            .arg(self.state.join("scratch").join(format!("worker-{index}")))
            .arg("--lease-ms")
            .arg(LOCAL_LEASE_MS.to_string())
            .arg("--worker-id")
            .arg(format!("local-{index}-{}", std::process::id()))
            // The embedded coordinator checks no token and speaks no TLS: a cluster's settings in
            // the environment do not apply to it.
            .env_remove("VINT_TOKEN")
            .env_remove("VINT_TLS_CA")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::from(log))
            .kill_on_drop(true)
            .spawn()
            .with_context(|| format!("starting worker {}", bin.display()))?;
        Ok(child)
    }

    /// Waits for a worker to die and restarts it; gives up after repeated deaths.
    async fn supervise(&mut self) -> Failure {
        loop {
            tokio::time::sleep(Duration::from_millis(500)).await;
            for i in 0..self.children.len() {
                let exited = match self.children[i].try_wait() {
                    Ok(Some(status)) => Some(status.to_string()),
                    Ok(None) => None,
                    Err(e) => Some(e.to_string()),
                };
                let Some(status) = exited else { continue };
                self.restarts += 1;
                tracing::warn!(worker = i, %status, "local worker exited; restarting");
                if self.restarts > 20 {
                    return Failure {
                        code: 1,
                        error: anyhow!(
                            "local workers keep dying (last: {status}); see {}",
                            self.state.join("logs").display()
                        ),
                    };
                }
                match self.spawn(i) {
                    Ok(child) => self.children[i] = child,
                    Err(f) => return f,
                }
            }
        }
    }

    /// Asks every worker to stop (SIGTERM), then kills what is left.
    async fn stop(&mut self) {
        for child in &self.children {
            if let Some(pid) = child.id() {
                let _ =
                    nix::sys::signal::kill(nix::unistd::Pid::from_raw(pid as i32), nix::sys::signal::Signal::SIGTERM);
            }
        }
        for child in &mut self.children {
            if tokio::time::timeout(Duration::from_secs(10), child.wait()).await.is_err() {
                let _ = child.kill().await;
            }
        }
    }
}

/// `vint-worker` next to this executable (as cargo builds them), or `VINT_WORKER_BIN`.
fn worker_binary() -> Result<PathBuf, Failure> {
    if let Ok(p) = std::env::var("VINT_WORKER_BIN") {
        return Ok(PathBuf::from(p));
    }
    let exe = std::env::current_exe().context("locating vintctl")?;
    let bin = exe.with_file_name("vint-worker");
    if bin.exists() {
        Ok(bin)
    } else {
        Err(anyhow!(
            "vint-worker not found next to {} (build the workspace: scripts/setup.sh; or install it beside \
             vintctl: cargo install --path workers/runtime; or set VINT_WORKER_BIN)",
            exe.display()
        )
        .into())
    }
}
