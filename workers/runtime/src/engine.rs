//! The engine host: one long-lived Python engine process per stage, spoken to over the framed
//! protocol of `workers/engines/PROTOCOL.md` (4-byte big-endian length + a JSON object).
//!
//! The host owns the child process. An engine that exits is reported as `EngineError::Crashed`;
//! one that overruns its task (or start-up) deadline is killed and reported as
//! `EngineError::TimedOut`; one that breaks a frame or answers with a reply that
//! breaks the protocol or its stage's contract (a result of the wrong shape, an output outside its
//! directory) is an `EngineError::Protocol`. Either way the engine is at fault, not the task: the
//! worker fails the task as retryable and starts a fresh engine for the next one.

use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::Duration;

use serde::{Deserialize, Serialize};
use serde_json::Value;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::process::{Child, ChildStdin, ChildStdout, Command};
use vint_core::Stage;

/// Frames above this size are a protocol error (matches the engines' limit).
const MAX_FRAME_BYTES: u32 = 64 << 20;

#[derive(Debug, thiserror::Error)]
pub enum EngineError {
    #[error("could not start the {stage} engine ({python}): {source}")]
    Spawn { stage: Stage, python: String, source: std::io::Error },
    #[error("the {stage} engine crashed: {detail}")]
    Crashed { stage: Stage, detail: String },
    #[error("the {stage} engine timed out and was killed: {detail}")]
    TimedOut { stage: Stage, detail: String },
    #[error("the {stage} engine broke the protocol: {detail}")]
    Protocol { stage: Stage, detail: String },
}

/// Why the engines' identities could not be read.
#[derive(Debug, thiserror::Error)]
pub enum IdentityError {
    #[error("could not run {python} -m vint_engines identity: {source}")]
    Spawn { python: String, source: std::io::Error },
    #[error("python -m vint_engines identity: {0}")]
    Failed(String),
}

/// Variables an engine process inherits from the worker, by exact name: the process basics and
/// the engines' own settings. Everything else is left out: the worker holds the coordinator's token
/// and the object store's credentials (`VINT_TOKEN`, `AWS_*`, `VINT_STORE`), and an engine, which
/// parses users' files, needs neither (the worker does all store and coordinator I/O).
const ENGINE_ENV: &[&str] = &[
    "PATH",
    "HOME",
    "USER",
    "LANG",
    "LANGUAGE",
    "TZ",
    "TMPDIR",
    "LD_LIBRARY_PATH",
    "VIRTUAL_ENV",
    "VINT_RENDER_DEVICE",
    "VINT_RENDER_THREADS",
];

/// Prefixes of the variables an engine inherits: locale, GPU selection and drivers (CUDA, NVIDIA,
/// the OpenGL/EGL choice of MuJoCo), and the thread counts of its numeric libraries.
const ENGINE_ENV_PREFIXES: &[&str] =
    &["LC_", "CUDA_", "NVIDIA_", "MUJOCO_", "PYOPENGL_", "EGL_", "OMP_", "MKL_", "OPENBLAS_", "XDG_"];

/// The variable an engine reads its memory limit from (MiB; unset for none).
const MEMORY_LIMIT_VAR: &str = "VINT_ENGINE_MEMORY_LIMIT_MIB";

/// A process of `program` for the engines in `engines_dir`, given only the part of `vars` (the
/// worker's environment) `ENGINE_ENV` and `ENGINE_ENV_PREFIXES` allow.
fn engine_process(
    program: &std::path::Path,
    engines_dir: &std::path::Path,
    vars: impl IntoIterator<Item = (std::ffi::OsString, std::ffi::OsString)>,
) -> Command {
    let allowed = vars.into_iter().filter(|(name, _)| {
        name.to_str().is_some_and(|n| ENGINE_ENV.contains(&n) || ENGINE_ENV_PREFIXES.iter().any(|p| n.starts_with(p)))
    });
    let mut command = Command::new(program);
    command.env_clear().envs(allowed).env("PYTHONPATH", engines_dir);
    command
}

/// Longest `python -m vint_engines identity` may take (it imports no engine library).
const IDENTITY_TIMEOUT: Duration = Duration::from_secs(60);

/// The identity of each Python stage's engine in `cmd`'s environment (`vint_engines/identity.py`:
/// the hash of the code the stage can import and of the pinned libraries' installed versions),
/// the part of a task's reuse key that says which code made its outputs.
pub async fn identities(cmd: &EngineCommand) -> Result<std::collections::HashMap<Stage, String>, IdentityError> {
    let run = engine_process(&cmd.python, &cmd.engines_dir, std::env::vars_os())
        .args(["-m", "vint_engines", "identity"])
        .stdin(Stdio::null())
        .kill_on_drop(true)
        .output();
    let output = tokio::time::timeout(IDENTITY_TIMEOUT, run)
        .await
        .map_err(|_| IdentityError::Failed(format!("no answer within {IDENTITY_TIMEOUT:?}")))?
        .map_err(|source| IdentityError::Spawn { python: cmd.python.display().to_string(), source })?;
    if !output.status.success() {
        return Err(IdentityError::Failed(format!(
            "{}: {}",
            output.status,
            String::from_utf8_lossy(&output.stderr).trim()
        )));
    }
    vint_core::reuse::parse_identities(&output.stdout).map_err(IdentityError::Failed)
}

/// How to start engines.
#[derive(Clone, Debug)]
pub struct EngineCommand {
    /// The Python interpreter of the engines' environment.
    pub python: PathBuf,
    /// Directory that holds the `vint_engines` package.
    pub engines_dir: PathBuf,
    /// Longest a single task may run before the engine is presumed hung.
    pub task_timeout: Duration,
    /// Longest an engine may take to import its libraries and say hello.
    pub start_timeout: Duration,
    /// When a warm engine is replaced by a fresh one.
    pub recycle: RecyclePolicy,
    /// Most memory (MiB) an engine process may allocate (`RLIMIT_DATA`, which the engine sets on
    /// itself at start from `VINT_ENGINE_MEMORY_LIMIT_MIB`): one task that asks for more fails
    /// with an error naming the limit instead of taking the node's memory; `None` for no limit.
    pub memory_limit_mib: Option<u64>,
}

/// Limits past which the worker replaces a warm engine with a fresh process, between tasks: a
/// long-lived Blender or MuJoCo process must not carry a slow leak into the ten-thousandth task.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RecyclePolicy {
    /// Tasks one engine process serves at most; `None` for no limit.
    pub max_tasks: Option<u32>,
    /// Resident set size (bytes) past which the engine is replaced after its current task; `None`
    /// for no limit. Read from `/proc`, so it applies on Linux only.
    pub max_rss_bytes: Option<u64>,
}

/// Why a warm engine is replaced by a fresh process before its next task (`RecyclePolicy`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Recycle {
    /// It served `limit` tasks (`max_tasks`).
    Tasks { served: u32, limit: u32 },
    /// Its resident memory passed the limit (`max_rss_bytes`).
    Memory { rss_bytes: u64, limit_bytes: u64 },
}

impl std::fmt::Display for Recycle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Recycle::Tasks { served, limit } => write!(f, "served {served} tasks (limit {limit})"),
            Recycle::Memory { rss_bytes, limit_bytes } => {
                write!(f, "resident memory {} MiB over the limit of {} MiB", rss_bytes >> 20, limit_bytes >> 20)
            }
        }
    }
}

/// One file a task reads.
#[derive(Clone, Debug, Serialize)]
pub struct EngineInput {
    pub name: String,
    pub task_key: String,
    pub path: PathBuf,
}

#[derive(Serialize)]
struct TaskMessage<'a> {
    #[serde(rename = "type")]
    kind: &'static str,
    task_id: &'a str,
    params: &'a Value,
    inputs: &'a [EngineInput],
    out_dir: &'a Path,
}

#[derive(Clone, Debug, Deserialize)]
pub struct EngineOutput {
    pub name: String,
    pub path: PathBuf,
    pub media_type: String,
}

/// What an engine answered for one task.
#[derive(Clone, Debug, Deserialize)]
pub struct EngineResult {
    pub ok: bool,
    #[serde(default)]
    pub outputs: Vec<EngineOutput>,
    /// The stage's result in its contract's type (`vint_core::contract`), when `ok`.
    #[serde(default)]
    pub result: Value,
    #[serde(default)]
    pub metrics: serde_json::Map<String, Value>,
    #[serde(default)]
    pub retryable: bool,
    #[serde(default)]
    pub error: String,
    #[serde(default)]
    pub task_id: String,
}

/// A running engine process.
pub struct Engine {
    stage: Stage,
    child: Child,
    stdin: ChildStdin,
    stdout: ChildStdout,
    /// The engine's self-description from its hello (name, version, library versions).
    pub identity: Value,
    task_timeout: Duration,
    recycle: RecyclePolicy,
    tasks_served: u32,
}

impl Engine {
    /// Starts the engine for `stage` and waits for its hello.
    pub async fn start(stage: Stage, cmd: &EngineCommand) -> Result<Engine, EngineError> {
        let mut command = engine_process(&cmd.python, &cmd.engines_dir, std::env::vars_os());
        if let Some(mib) = cmd.memory_limit_mib {
            command.env(MEMORY_LIMIT_VAR, mib.to_string());
        }
        let mut child = command
            .args(["-m", "vint_engines", "serve", "--stage", stage.as_str()])
            .env("PYTHONUNBUFFERED", "1")
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .kill_on_drop(true)
            .spawn()
            .map_err(|source| EngineError::Spawn { stage, python: cmd.python.display().to_string(), source })?;
        let crashed = |detail: &str| EngineError::Crashed { stage, detail: detail.to_string() };
        let stdin = child.stdin.take().ok_or_else(|| crashed("no stdin pipe"))?;
        let stdout = child.stdout.take().ok_or_else(|| crashed("no stdout pipe"))?;
        let mut engine = Engine {
            stage,
            child,
            stdin,
            stdout,
            identity: Value::Null,
            task_timeout: cmd.task_timeout,
            recycle: cmd.recycle,
            tasks_served: 0,
        };
        let hello = match tokio::time::timeout(cmd.start_timeout, engine.read_frame()).await {
            Ok(r) => r?,
            Err(_) => {
                return Err(engine.time_out(&format!("no hello within {:?}", cmd.start_timeout)).await);
            }
        };
        if hello.get("type").and_then(Value::as_str) != Some("hello") {
            return Err(EngineError::Protocol { stage, detail: format!("expected hello, got {hello}") });
        }
        engine.identity = hello.get("engine").cloned().unwrap_or(Value::Null);
        tracing::info!(stage = %stage, engine = %engine.identity, "engine ready");
        Ok(engine)
    }

    pub fn stage(&self) -> Stage {
        self.stage
    }

    /// Runs one task. An `Err` means the engine is unusable and must be dropped.
    pub async fn run(
        &mut self,
        task_id: &str,
        params: &Value,
        inputs: &[EngineInput],
        out_dir: &Path,
    ) -> Result<EngineResult, EngineError> {
        self.tasks_served = self.tasks_served.saturating_add(1);
        let msg = TaskMessage { kind: "task", task_id, params, inputs, out_dir };
        let body =
            serde_json::to_vec(&msg).map_err(|e| EngineError::Protocol { stage: self.stage, detail: e.to_string() })?;
        self.write_frame(&body).await?;
        let reply = match tokio::time::timeout(self.task_timeout, self.read_frame()).await {
            Ok(r) => r?,
            Err(_) => {
                return Err(self.time_out(&format!("task {task_id} ran past {:?}", self.task_timeout)).await);
            }
        };
        if reply.get("type").and_then(Value::as_str) != Some("result") {
            return Err(EngineError::Protocol { stage: self.stage, detail: format!("expected result, got {reply}") });
        }
        let result: EngineResult = serde_json::from_value(reply)
            .map_err(|e| EngineError::Protocol { stage: self.stage, detail: e.to_string() })?;
        if result.task_id != task_id {
            return Err(EngineError::Protocol {
                stage: self.stage,
                detail: format!("result for task {:?} while running {task_id:?}", result.task_id),
            });
        }
        if result.ok {
            // A reply that breaks the stage's contract is the engine's bug, not the task's fault.
            vint_core::contract::check_result(self.stage, &result.result)
                .map_err(|e| EngineError::Protocol { stage: self.stage, detail: e.to_string() })?;
            if let Some(o) = result.outputs.iter().find(|o| !o.path.starts_with(out_dir)) {
                return Err(EngineError::Protocol {
                    stage: self.stage,
                    detail: format!("output {} lies outside its out_dir {}", o.path.display(), out_dir.display()),
                });
            }
        }
        Ok(result)
    }

    /// Tasks sent to this engine process so far.
    pub fn tasks_served(&self) -> u32 {
        self.tasks_served
    }

    /// The engine process's resident set size in bytes (Linux; `None` elsewhere or once it exited).
    pub fn rss_bytes(&self) -> Option<u64> {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.pid()?)).ok()?;
        parse_vm_rss(&status)
    }

    /// Why this engine should be replaced before its next task, if it should.
    pub fn recycle_reason(&self) -> Option<Recycle> {
        if let Some(limit) = self.recycle.max_tasks.filter(|&max| self.tasks_served >= max) {
            return Some(Recycle::Tasks { served: self.tasks_served, limit });
        }
        let limit_bytes = self.recycle.max_rss_bytes?;
        let rss_bytes = self.rss_bytes().filter(|&rss| rss > limit_bytes)?;
        Some(Recycle::Memory { rss_bytes, limit_bytes })
    }

    /// Asks the engine to exit and waits briefly; kills it otherwise.
    pub async fn shutdown(mut self) {
        let _ = self.write_frame(br#"{"type":"shutdown"}"#).await;
        if tokio::time::timeout(Duration::from_secs(5), self.child.wait()).await.is_err() {
            let _ = self.child.kill().await;
        }
    }

    /// Kills the engine now, mid-task or not, and waits until it has exited: dropping it only sends
    /// the signal, and a large engine takes a moment to die, past a worker that exits at once.
    pub async fn kill(mut self) {
        let _ = self.child.kill().await;
    }

    /// Process id, for tests that need to kill an engine from outside.
    pub fn pid(&self) -> Option<u32> {
        self.child.id()
    }

    /// Kills an engine that overran a deadline.
    async fn time_out(&mut self, why: &str) -> EngineError {
        let _ = self.child.kill().await;
        EngineError::TimedOut { stage: self.stage, detail: why.to_string() }
    }

    async fn write_frame(&mut self, body: &[u8]) -> Result<(), EngineError> {
        let len = u32::try_from(body.len()).ok().filter(|&n| n <= MAX_FRAME_BYTES).ok_or_else(|| {
            EngineError::Protocol { stage: self.stage, detail: format!("frame of {} bytes is too large", body.len()) }
        })?;
        let write = async {
            self.stdin.write_all(&len.to_be_bytes()).await?;
            self.stdin.write_all(body).await?;
            self.stdin.flush().await
        };
        if let Err(e) = write.await {
            let detail = self.exit_detail(&e.to_string()).await;
            return Err(EngineError::Crashed { stage: self.stage, detail });
        }
        Ok(())
    }

    async fn read_frame(&mut self) -> Result<Value, EngineError> {
        let mut len = [0u8; 4];
        if let Err(e) = self.stdout.read_exact(&mut len).await {
            let detail = self.exit_detail(&e.to_string()).await;
            return Err(EngineError::Crashed { stage: self.stage, detail });
        }
        let len = u32::from_be_bytes(len);
        if len > MAX_FRAME_BYTES {
            return Err(EngineError::Protocol { stage: self.stage, detail: format!("frame of {len} bytes") });
        }
        let mut body = vec![0u8; len as usize];
        if let Err(e) = self.stdout.read_exact(&mut body).await {
            let detail = self.exit_detail(&e.to_string()).await;
            return Err(EngineError::Crashed { stage: self.stage, detail });
        }
        serde_json::from_slice(&body).map_err(|e| EngineError::Protocol { stage: self.stage, detail: e.to_string() })
    }

    /// Describes how the engine ended, after an I/O error on its pipes.
    async fn exit_detail(&mut self, io_error: &str) -> String {
        match tokio::time::timeout(Duration::from_secs(2), self.child.wait()).await {
            Ok(Ok(status)) => format!("engine exited ({status}) [{io_error}]"),
            _ => {
                let _ = self.child.kill().await;
                format!("engine pipe failed [{io_error}]; killed")
            }
        }
    }
}

/// The `VmRSS` line of a `/proc/PID/status` text, in bytes.
fn parse_vm_rss(status: &str) -> Option<u64> {
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    let kib: u64 = line.trim_start_matches("VmRSS:").trim().trim_end_matches("kB").trim().parse().ok()?;
    Some(kib * 1024)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An engine parses users' files: it must not hold the worker's secrets.
    #[tokio::test]
    async fn an_engine_process_gets_the_allowed_variables_and_no_secret() {
        let vars = [
            ("PATH", "/usr/bin:/bin"),
            ("CUDA_VISIBLE_DEVICES", "0"),
            ("VINT_RENDER_DEVICE", "cpu"),
            ("VINT_TOKEN", "s3cret"),
            ("AWS_SECRET_ACCESS_KEY", "s3cret"),
            ("VINT_STORE", "s3://bucket"),
            ("VINT_DATABASE_URL", "postgres://u:s3cret@h/db"),
        ]
        .map(|(k, v)| (k.into(), v.into()));
        let out = engine_process(std::path::Path::new("/usr/bin/env"), std::path::Path::new("/engines"), vars)
            .output()
            .await
            .unwrap();
        assert!(out.status.success());
        let mut seen: Vec<String> = String::from_utf8(out.stdout).unwrap().lines().map(str::to_string).collect();
        seen.sort();
        assert_eq!(
            seen,
            ["CUDA_VISIBLE_DEVICES=0", "PATH=/usr/bin:/bin", "PYTHONPATH=/engines", "VINT_RENDER_DEVICE=cpu"]
        );
    }

    #[test]
    fn vm_rss_is_read_in_bytes() {
        let status = "Name:\tpython\nVmPeak:\t  900 kB\nVmRSS:\t  123456 kB\nThreads:\t4\n";
        assert_eq!(parse_vm_rss(status), Some(123_456 * 1024));
        assert_eq!(parse_vm_rss("Name:\tx\n"), None);
    }
}
