//! The engine host against a real engine (the OpenCV noise engine: the quickest to start).

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde_json::json;
use vint_core::Stage;
use vint_runtime::engine::{Engine, EngineCommand, EngineError, EngineInput, RecyclePolicy};

fn command() -> EngineCommand {
    let vint_engine_env::EngineEnv { engines_dir, python } = vint_engine_env::EngineEnv::from_env();
    assert!(python.exists(), "engine Python {} is missing: run scripts/setup-python.sh", python.display());
    EngineCommand {
        python,
        engines_dir,
        task_timeout: Duration::from_secs(60),
        start_timeout: Duration::from_secs(60),
        recycle: RecyclePolicy::default(),
        memory_limit_mib: None,
    }
}

/// A float32 `.npy` file of `h`×`w` metres, constant depth.
fn write_depth(path: &Path, w: usize, h: usize, depth: f32) {
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({h}, {w}), }}");
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    for _ in 0..w * h {
        bytes.extend_from_slice(&depth.to_le_bytes());
    }
    std::fs::write(path, bytes).unwrap();
}

fn noise_task(dir: &Path) -> (serde_json::Value, Vec<EngineInput>, PathBuf) {
    let depth = dir.join("v00_depth.npy");
    write_depth(&depth, 32, 24, 0.6);
    let out = dir.join("out");
    std::fs::create_dir_all(&out).unwrap();
    let camera = dir.join("v00_camera.json");
    let record = json!({"K": [[30.0, 0.0, 15.5], [0.0, 30.0, 11.5], [0.0, 0.0, 1.0]], "width": 32, "height": 24});
    std::fs::write(&camera, record.to_string()).unwrap();
    // Materials off: the engine then needs no segmentation.
    let params =
        json!({"noise": {"mode": "wfov_2x2binned", "materials": false}, "views": [{"view_index": 0, "seed": 42}]});
    let inputs = vec![
        EngineInput { name: "v00_depth.npy".into(), task_key: "render/x".into(), path: depth },
        EngineInput { name: "v00_camera.json".into(), task_key: "render/x".into(), path: camera },
    ];
    (params, inputs, out)
}

#[tokio::test]
async fn one_engine_process_serves_many_tasks() {
    let dir = tempfile::tempdir().unwrap();
    let mut engine = Engine::start(Stage::Noise, &command()).await.unwrap();
    assert_eq!(engine.identity["name"], "vint-noise");
    let pid = engine.pid();
    let (params, inputs, out) = noise_task(dir.path());
    let mut hashes = Vec::new();
    for i in 0..3 {
        let r = engine.run(&format!("t{i}"), &params, &inputs, &out).await.unwrap();
        assert!(r.ok, "{}", r.error);
        assert_eq!(r.outputs.len(), 1);
        hashes.push(std::fs::read(&r.outputs[0].path).unwrap());
    }
    assert_eq!(engine.pid(), pid, "the same process served every task");
    assert!(hashes.windows(2).all(|w| w[0] == w[1]), "same seed, same noisy depth");
    engine.shutdown().await;
}

#[tokio::test]
async fn impossible_parameters_are_a_permanent_task_failure_not_a_crash() {
    let dir = tempfile::tempdir().unwrap();
    let mut engine = Engine::start(Stage::Noise, &command()).await.unwrap();
    let (_, inputs, out) = noise_task(dir.path());
    let r = engine.run("bad", &json!({"noise": {"sigma_scale": "lots"}, "views": []}), &inputs, &out).await.unwrap();
    assert!(!r.ok);
    assert!(!r.retryable, "bad parameters will fail again: {}", r.error);
    // The engine survives a bad task.
    let (params, inputs, out) = noise_task(dir.path());
    assert!(engine.run("good", &params, &inputs, &out).await.unwrap().ok);
}

#[tokio::test]
async fn a_killed_engine_is_reported_as_crashed() {
    let dir = tempfile::tempdir().unwrap();
    let mut engine = Engine::start(Stage::Noise, &command()).await.unwrap();
    let pid = engine.pid().unwrap() as i32;
    nix::sys::signal::kill(nix::unistd::Pid::from_raw(pid), nix::sys::signal::Signal::SIGKILL).unwrap();
    let (params, inputs, out) = noise_task(dir.path());
    let err = engine.run("t", &params, &inputs, &out).await.unwrap_err();
    assert!(matches!(err, EngineError::Crashed { stage: Stage::Noise, .. }), "{err}");
}

#[tokio::test]
async fn a_missing_interpreter_is_a_clear_spawn_error() {
    let mut cmd = command();
    cmd.python = PathBuf::from("/nonexistent/python3.13");
    let err = Engine::start(Stage::Grasp, &cmd).await.err().expect("must fail");
    assert!(matches!(err, EngineError::Spawn { .. }));
    assert!(err.to_string().contains("/nonexistent/python3.13"));
}

#[tokio::test]
async fn an_engine_past_its_limits_asks_to_be_recycled() {
    let dir = tempfile::tempdir().unwrap();
    let mut cmd = command();
    cmd.recycle = RecyclePolicy { max_tasks: Some(2), max_rss_bytes: None };
    let mut engine = Engine::start(Stage::Noise, &cmd).await.unwrap();
    let rss = engine.rss_bytes().expect("resident memory of a live engine");
    assert!(rss > 10 << 20, "a Python engine with numpy and OpenCV holds more than 10 MiB, got {rss}");
    let (params, inputs, out) = noise_task(dir.path());
    engine.run("t0", &params, &inputs, &out).await.unwrap();
    assert_eq!(engine.recycle_reason(), None);
    engine.run("t1", &params, &inputs, &out).await.unwrap();
    assert!(engine.recycle_reason().unwrap().to_string().contains("served 2 tasks"));
    engine.shutdown().await;

    cmd.recycle = RecyclePolicy { max_tasks: None, max_rss_bytes: Some(1 << 20) };
    let engine = Engine::start(Stage::Noise, &cmd).await.unwrap();
    assert!(engine.recycle_reason().unwrap().to_string().contains("resident memory"));
    engine.shutdown().await;
}

/// Test double: a `vint_engines` package whose engine says hello and then answers every task with
/// a result of the wrong shape for the noise stage (`views` must be a count).
const ENGINE_BREAKING_ITS_CONTRACT: &str = r#"
import json, struct, sys

def send(message):
    body = json.dumps(message).encode()
    sys.stdout.buffer.write(struct.pack(">I", len(body)) + body)
    sys.stdout.buffer.flush()

send({"type": "hello", "stage": "noise", "engine": {"name": "engine-breaking-its-contract"}})
while True:
    header = sys.stdin.buffer.read(4)
    if len(header) < 4:
        break
    task = json.loads(sys.stdin.buffer.read(struct.unpack(">I", header)[0]))
    if task.get("type") != "task":
        break
    send({"type": "result", "task_id": task["task_id"], "ok": True, "outputs": [], "result": {"views": "all"}})
"#;

/// The engines directory of a test double: a `vint_engines` package under `dir/name` whose
/// `python -m vint_engines` runs `main`.
fn double_engines(dir: &Path, name: &str, main: &str) -> PathBuf {
    let engines_dir = dir.join(name);
    let package = engines_dir.join("vint_engines");
    std::fs::create_dir_all(&package).unwrap();
    std::fs::write(package.join("__init__.py"), "").unwrap();
    std::fs::write(package.join("__main__.py"), main).unwrap();
    engines_dir
}

#[tokio::test]
async fn a_reply_that_breaks_the_stage_contract_is_a_protocol_error() {
    let dir = tempfile::tempdir().unwrap();
    let cmd =
        EngineCommand { engines_dir: double_engines(dir.path(), "double", ENGINE_BREAKING_ITS_CONTRACT), ..command() };
    let mut engine = Engine::start(Stage::Noise, &cmd).await.unwrap();
    let (params, inputs, out) = noise_task(dir.path());
    match engine.run("t-1", &params, &inputs, &out).await {
        Err(EngineError::Protocol { stage, detail }) => {
            assert_eq!(stage, Stage::Noise);
            assert!(detail.contains("noise result does not follow the contract"), "{detail}");
        }
        other => panic!("expected a protocol error, got {other:?}"),
    }
}

/// Test double: a `vint_engines` package whose engine says hello, reads its first task and then
/// hangs (never answers), as a deadlocked renderer would.
const ENGINE_THAT_HANGS: &str = r#"
import json, struct, sys, time

body = json.dumps({"type": "hello", "stage": "noise", "engine": {"name": "engine-that-hangs"}}).encode()
sys.stdout.buffer.write(struct.pack(">I", len(body)) + body)
sys.stdout.buffer.flush()
header = sys.stdin.buffer.read(4)
sys.stdin.buffer.read(struct.unpack(">I", header)[0])
while True:
    time.sleep(3600)
"#;

#[tokio::test]
async fn a_hung_engine_is_killed_at_its_task_timeout_and_reported_as_timed_out() {
    let dir = tempfile::tempdir().unwrap();
    let cmd = EngineCommand {
        engines_dir: double_engines(dir.path(), "hangs", ENGINE_THAT_HANGS),
        task_timeout: Duration::from_secs(1),
        ..command()
    };
    let mut engine = Engine::start(Stage::Noise, &cmd).await.unwrap();
    let pid = engine.pid().expect("a running engine has a pid");
    let (params, inputs, out) = noise_task(dir.path());
    let started = std::time::Instant::now();
    match engine.run("t-1", &params, &inputs, &out).await {
        Err(EngineError::TimedOut { stage, detail }) => {
            assert_eq!(stage, Stage::Noise);
            assert!(detail.contains("t-1"), "{detail}");
        }
        other => panic!("expected a timeout, got {other:?}"),
    }
    assert!(started.elapsed() < Duration::from_secs(30), "the timeout did not end the wait");
    // The hung process is gone (killed and reaped), not left running beside its replacement.
    let gone = std::time::Instant::now() + Duration::from_secs(10);
    while std::path::Path::new(&format!("/proc/{pid}")).exists() {
        assert!(std::time::Instant::now() < gone, "the hung engine {pid} still runs");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}
