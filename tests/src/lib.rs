//! Test harness: locate the built binaries and the engines' Python, make Postgres databases,
//! start coordinators and workers as separate processes, and check exported datasets.
//!
//! Nothing here is a test double: the processes are the product's own binaries.

use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use sha2::{Digest, Sha256};

pub fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..").canonicalize().expect("repo root")
}

/// A workspace binary built by `cargo build --workspace --bins` (scripts/test.sh does this).
pub fn bin(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    let dir = exe.parent().and_then(Path::parent).expect("target profile directory");
    let path = dir.join(name);
    assert!(
        path.exists(),
        "{} is missing: run `cargo build --workspace --bins` first (scripts/test.sh does)",
        path.display()
    );
    path
}

/// The engines' Python: `VINT_PYTHON` or the checkout's `.venv`. Missing engines fail the tests.
pub fn python() -> PathBuf {
    let p = std::env::var("VINT_PYTHON").map(PathBuf::from).unwrap_or_else(|_| repo_root().join(".venv/bin/python"));
    assert!(p.exists(), "engine Python {} is missing: run scripts/setup-python.sh", p.display());
    p
}

pub fn tiny_spec() -> PathBuf {
    repo_root().join("examples/tiny.toml")
}

/// `vintctl run examples/tiny.toml` into `dir/out` with state in `dir/state`, summary as JSON.
pub fn run_tiny(dir: &Path, workers: u32) -> Output {
    run_tiny_with_env(dir, workers, &[])
}

/// `run_tiny` with extra environment for vintctl and the workers it starts.
pub fn run_tiny_with_env(dir: &Path, workers: u32, env: &[(String, String)]) -> Output {
    let out = dir.join("out");
    let state = dir.join("state");
    let spec = tiny_spec();
    let workers = workers.to_string();
    let args =
        ["run", path_str(&spec), "--out", path_str(&out), "--state", path_str(&state), "--workers", &workers, "--json"];
    vintctl_with_env(&args, env)
}

fn path_str(p: &Path) -> &str {
    p.to_str().expect("test paths are UTF-8")
}

pub fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0").expect("bind").local_addr().expect("addr").port()
}

/// A fresh Postgres database: `VINT_TEST_POSTGRES_URL` (an admin URL) with a new database.
///
/// Test databases are named `vint_test_<pid>_<tag>_<nanos>_<n>` (here and in
/// services/store/tests/common/mod.rs): `scripts/test.sh` reads the pid after `vint_test_` to drop
/// the databases of test processes that no longer run. `tag` is lowercase letters, digits and `_`.
pub async fn postgres_database(tag: &str) -> String {
    use std::sync::atomic::{AtomicU64, Ordering};
    static N: AtomicU64 = AtomicU64::new(0);
    let admin = postgres_admin_url();
    sqlx::any::install_default_drivers();
    let mut conn = <sqlx::AnyConnection as sqlx::Connection>::connect(&admin).await.unwrap_or_else(|e| {
        panic!("Postgres is required for these tests ({}): {e}", vint_telemetry::redact_url(&admin))
    });
    let n = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap().as_nanos() % 1_000_000_000;
    let db = format!("vint_test_{}_{tag}_{n}_{}", std::process::id(), N.fetch_add(1, Ordering::Relaxed));
    sqlx::Executor::execute(&mut conn, sqlx::AssertSqlSafe(format!("CREATE DATABASE {db}"))).await.expect("create db");
    let base = admin.rsplit_once('/').map(|(b, _)| b.to_string()).expect("admin URL has a database");
    format!("{base}/{db}")
}

/// The admin URL of the tests' Postgres: `VINT_TEST_POSTGRES_URL`, or the local server.
pub fn postgres_admin_url() -> String {
    std::env::var("VINT_TEST_POSTGRES_URL")
        .unwrap_or_else(|_| "postgres://postgres@127.0.0.1:5432/postgres".to_string())
}

/// A child process killed when dropped.
pub struct Proc {
    pub child: Child,
    pub name: String,
}

impl Proc {
    pub fn pid(&self) -> i32 {
        self.child.id() as i32
    }

    pub fn sigkill(&mut self) {
        let _ = nix::sys::signal::kill(nix::unistd::Pid::from_raw(self.pid()), nix::sys::signal::Signal::SIGKILL);
        let _ = self.child.wait();
    }

    pub fn sigterm_and_wait(&mut self) {
        self.sigterm_and_wait_for(Duration::from_secs(15));
    }

    /// Sends SIGTERM and waits up to `within` for the process to exit: its exit status, or `None`
    /// if it was still running (then it is SIGKILLed).
    pub fn sigterm_and_wait_for(&mut self, within: Duration) -> Option<std::process::ExitStatus> {
        let _ = nix::sys::signal::kill(nix::unistd::Pid::from_raw(self.pid()), nix::sys::signal::Signal::SIGTERM);
        let deadline = Instant::now() + within;
        while Instant::now() < deadline {
            if let Ok(Some(status)) = self.child.try_wait() {
                return Some(status);
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        self.sigkill();
        None
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn log_file(dir: &Path, name: &str) -> Stdio {
    std::fs::create_dir_all(dir).expect("log dir");
    Stdio::from(std::fs::File::create(dir.join(format!("{name}.log"))).expect("log file"))
}

/// Starts `vint-coordinator` on `port` and waits until it accepts connections.
pub fn start_coordinator(database: &str, port: u16, logs: &Path, name: &str) -> Proc {
    start_coordinator_with_store(database, port, logs, name, None)
}

/// `start_coordinator`, with an artifact store for the files a submission carries.
pub fn start_coordinator_with_store(database: &str, port: u16, logs: &Path, name: &str, store: Option<&str>) -> Proc {
    let store_args = store.map(|s| vec!["--store", s]).unwrap_or_default();
    start_coordinator_with_args(database, port, logs, name, &store_args)
}

/// `start_coordinator`, with more arguments for `vint-coordinator`.
pub fn start_coordinator_with_args(database: &str, port: u16, logs: &Path, name: &str, args: &[&str]) -> Proc {
    let mut cmd = Command::new(bin("vint-coordinator"));
    cmd.args(["--database", database, "--listen", &format!("127.0.0.1:{port}"), "--backoff-ms", "200"]);
    cmd.args(args);
    let child = cmd.stdout(Stdio::null()).stderr(log_file(logs, name)).spawn().expect("start coordinator");
    let deadline = Instant::now() + Duration::from_secs(30);
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(Instant::now() < deadline, "coordinator did not start; see {}", logs.display());
        std::thread::sleep(Duration::from_millis(50));
    }
    Proc { child, name: name.to_string() }
}

/// Starts `vint-worker` with a short lease so that a dead worker's task returns quickly.
pub fn start_worker(
    coordinator: &str,
    store: &str,
    id: &str,
    logs: &Path,
    scratch: &Path,
    env: &[(String, String)],
) -> Proc {
    start_worker_with_lease(coordinator, store, id, logs, scratch, env, 3_000)
}

/// `start_worker` asking for leases of `lease_ms`.
pub fn start_worker_with_lease(
    coordinator: &str,
    store: &str,
    id: &str,
    logs: &Path,
    scratch: &Path,
    env: &[(String, String)],
    lease_ms: u32,
) -> Proc {
    let child = Command::new(bin("vint-worker"))
        .envs(env.iter().map(|(k, v)| (k, v)))
        .args(["--coordinator", coordinator, "--store", store, "--worker-id", id, "--lease-ms", &lease_ms.to_string()])
        .arg("--python")
        .arg(python())
        .arg("--scratch")
        .arg(scratch.join(id))
        .stdout(Stdio::null())
        .stderr(log_file(logs, id))
        .spawn()
        .expect("start worker");
    Proc { child, name: id.to_string() }
}

/// An HTTP/1.0 GET of `path` on 127.0.0.1:`port`: the status, the content type and the body.
/// `None` while nothing accepts connections there.
pub fn http_get(port: u16, path: &str) -> Option<(u16, String, String)> {
    http_request(port, path, "")
}

/// `GET path` on 127.0.0.1:`port` with an `Authorization` header: (status, body).
pub fn http_get_authorized(port: u16, path: &str, authorization: &str) -> Option<(u16, String)> {
    let (status, _, body) = http_request(port, path, &format!("Authorization: {authorization}\r\n"))?;
    Some((status, body))
}

/// An HTTP/1.0 GET with `headers` (each line ending in CRLF): status, content type, body.
fn http_request(port: u16, path: &str, headers: &str) -> Option<(u16, String, String)> {
    use std::io::{Read, Write};
    let mut stream = std::net::TcpStream::connect(("127.0.0.1", port)).ok()?;
    stream.set_read_timeout(Some(Duration::from_secs(10))).ok()?;
    stream.write_all(format!("GET {path} HTTP/1.0\r\nHost: 127.0.0.1\r\n{headers}\r\n").as_bytes()).ok()?;
    let mut raw = String::new();
    stream.read_to_string(&mut raw).ok()?;
    let (head, body) = raw.split_once("\r\n\r\n")?;
    let status = head.split(' ').nth(1)?.parse().ok()?;
    let content_type = head
        .lines()
        .find_map(|l| l.split_once(':').filter(|(k, _)| k.eq_ignore_ascii_case("content-type")).map(|(_, v)| v.trim()))
        .unwrap_or_default()
        .to_string();
    Some((status, content_type, body.to_string()))
}

/// Headless Chromium (`VINT_CHROMIUM`, else `chromium` on PATH: scripts/test.sh installs Debian's
/// package). A test that needs it fails without it.
pub fn chromium() -> PathBuf {
    if let Some(path) = std::env::var_os("VINT_CHROMIUM") {
        return PathBuf::from(path);
    }
    let found = std::env::var_os("PATH")
        .into_iter()
        .flat_map(|p| std::env::split_paths(&p).collect::<Vec<_>>())
        .map(|dir| dir.join("chromium"))
        .find(|p| p.is_file());
    found.expect("chromium not found: scripts/test.sh installs it (apt-get install chromium), or set VINT_CHROMIUM")
}

/// Runs headless Chromium on `url` with `args` (e.g. `--dump-dom`), letting the page's scripts run
/// for up to `budget_ms` of virtual time; returns stdout.
pub fn chromium_run(url: &str, args: &[&str], budget_ms: u32) -> String {
    let profile = tempfile::tempdir().unwrap();
    let o = Command::new(chromium())
        .args(["--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--no-first-run"])
        .arg(format!("--user-data-dir={}", profile.path().display()))
        .arg(format!("--virtual-time-budget={budget_ms}"))
        .args(args)
        .arg(url)
        .output()
        .expect("start chromium");
    assert!(o.status.success(), "chromium {args:?} {url}: {}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// Runs vintctl to completion.
pub fn vintctl(args: &[&str]) -> Output {
    vintctl_with_env(args, &[])
}

pub fn vintctl_with_env(args: &[&str], env: &[(String, String)]) -> Output {
    Command::new(bin("vintctl"))
        .args(args)
        .envs(env.iter().map(|(k, v)| (k, v)))
        .env("VINT_PYTHON", python())
        .output()
        .expect("run vintctl")
}

pub fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Largest JSON a sample may carry: its view, not its grasp's shared record (issue 8).
pub const MAX_SAMPLE_JSON_BYTES: usize = 16 * 1024;

/// Checks every file of an exported dataset against manifest.jsonl, and that every sample's
/// `meta.json` is at most `MAX_SAMPLE_JSON_BYTES` and refers to a grasp record of the dataset by
/// its SHA-256; returns the manifest's sample lines.
pub fn verify_dataset(dir: &Path) -> Vec<serde_json::Value> {
    let manifest = std::fs::read_to_string(dir.join("manifest.jsonl")).expect("manifest.jsonl");
    let lines: Vec<serde_json::Value> =
        manifest.lines().map(|l| serde_json::from_str(l).expect("manifest line")).collect();
    let mut records = std::collections::BTreeMap::new();
    for line in &lines {
        // A sample's or grasp's files are in its directory, a model's in models/, dataset.json at the root.
        let (id, sub) = match (line["sample_id"].as_str(), line["grasp_id"].as_str(), line["model"].as_str()) {
            (Some(id), _, _) | (_, Some(id), _) => (id, id),
            (_, _, Some(object)) => (object, "models"),
            _ => (line["dataset"].as_str().expect("a sample_id, grasp_id, model or dataset line"), ""),
        };
        for (name, f) in line["files"].as_object().expect("files") {
            let bytes = std::fs::read(dir.join(sub).join(name)).unwrap_or_else(|e| panic!("{id}/{name}: {e}"));
            assert_eq!(hex::encode(Sha256::digest(&bytes)), f["sha256"].as_str().unwrap(), "{id}/{name} hash");
            assert_eq!(bytes.len() as u64, f["size"].as_u64().unwrap(), "{id}/{name} size");
        }
        if line["grasp_id"].is_string() {
            records.insert(
                id.to_string(),
                line["files"]["grasp.json"]["sha256"].as_str().expect("grasp.json").to_string(),
            );
        }
    }
    let samples: Vec<serde_json::Value> = lines.into_iter().filter(|l| l["sample_id"].is_string()).collect();
    for line in &samples {
        let sample = line["sample_id"].as_str().unwrap_or_default();
        let json_bytes: u64 = line["files"]
            .as_object()
            .into_iter()
            .flatten()
            .filter(|(name, _)| name.ends_with(".json"))
            .map(|(_, f)| f["size"].as_u64().unwrap_or(u64::MAX))
            .sum();
        assert!(json_bytes as usize <= MAX_SAMPLE_JSON_BYTES, "{sample}: {json_bytes} bytes of JSON");
        let meta: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.join(sample).join("meta.json")).expect("meta.json")).unwrap();
        let grasp = meta["grasp_id"].as_str().expect("grasp_id");
        assert!(sample.starts_with(&format!("{grasp}.v")), "{sample} is not a view of {grasp}");
        assert_eq!(meta["grasp"]["record"], format!("../{grasp}/grasp.json"), "{sample}");
        let model = meta["object"]["model"]["file"].as_str().expect("the object's model file");
        assert!(dir.join(sample).join(model).is_file(), "{sample}: its model {model} is in the dataset");
        assert_eq!(
            meta["grasp"]["sha256"].as_str(),
            records.get(grasp).map(String::as_str),
            "{sample}: its grasp record"
        );
    }
    samples
}

/// A sample's grasp record, as `meta.json` refers to it.
pub fn grasp_record(dir: &Path, sample: &str) -> serde_json::Value {
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join(sample).join("meta.json")).expect("meta.json")).unwrap();
    let record = dir.join(sample).join(meta["grasp"]["record"].as_str().expect("grasp.record"));
    serde_json::from_slice(&std::fs::read(&record).unwrap_or_else(|e| panic!("{}: {e}", record.display()))).unwrap()
}

pub fn manifest_sha256(dir: &Path) -> String {
    hex::encode(Sha256::digest(std::fs::read(dir.join("manifest.jsonl")).expect("manifest.jsonl")))
}

/// Polls `cond` every 20 ms until it holds or `timeout` passes.
/// Milliseconds since the Unix epoch: the clock the coordinator stamps leases with.
pub fn now_ms() -> i64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_millis() as i64)
}

pub async fn wait_for<F, Fut>(timeout: Duration, what: &str, mut cond: F)
where
    F: FnMut() -> Fut,
    Fut: std::future::Future<Output = bool>,
{
    let deadline = Instant::now() + timeout;
    while !cond().await {
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// Child process ids of `pid` (Linux `/proc`).
pub fn children_of(pid: i32) -> Vec<i32> {
    let mut out = Vec::new();
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else {
        return out;
    };
    for task in tasks.flatten() {
        if let Ok(text) = std::fs::read_to_string(task.path().join("children")) {
            out.extend(text.split_whitespace().filter_map(|p| p.parse::<i32>().ok()));
        }
    }
    out
}

/// An S3-compatible server for tests: `moto_server` from the engines' venv on a free port, with a
/// bucket `vint`. Returns the process and the `AWS_*` environment that points clients at it.
pub fn start_s3(logs: &Path) -> (Proc, Vec<(String, String)>) {
    let moto = python().with_file_name("moto_server");
    assert!(moto.exists(), "{} is missing: run scripts/setup-python.sh --dev (dev tools)", moto.display());
    let port = free_port();
    let child = Command::new(&moto)
        .args(["-H", "127.0.0.1", "-p", &port.to_string()])
        .stdout(Stdio::null())
        .stderr(log_file(logs, "s3"))
        .spawn()
        .expect("start moto_server");
    let proc = Proc { child, name: "s3".into() };
    let endpoint = format!("http://127.0.0.1:{port}");
    let deadline = Instant::now() + Duration::from_secs(30);
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(Instant::now() < deadline, "moto_server did not start");
        std::thread::sleep(Duration::from_millis(50));
    }
    let env: Vec<(String, String)> = [
        ("AWS_ENDPOINT_URL", endpoint.as_str()),
        ("AWS_ALLOW_HTTP", "true"),
        ("AWS_ACCESS_KEY_ID", "vint-test"),
        ("AWS_SECRET_ACCESS_KEY", "vint-test"),
        ("AWS_REGION", "us-east-1"),
    ]
    .iter()
    .map(|(k, v)| (k.to_string(), v.to_string()))
    .collect();
    let made = Command::new(python())
        .args(["-c", "import boto3; boto3.client('s3').create_bucket(Bucket='vint')"])
        .envs(env.iter().map(|(k, v)| (k, v)))
        .output()
        .expect("create bucket");
    assert!(made.status.success(), "creating the test bucket: {}", String::from_utf8_lossy(&made.stderr));
    (proc, env)
}

/// How widely the object's orientation in camera space spreads over a dataset's samples, computed
/// from each sample's camera (`R_w2c`) and the object's world pose (its quaternion) — not from the
/// renderer's own `R_m2c`. The object's z axis in the camera frame is binned two ways: its
/// direction in the image (12 sectors of 30°) and its octant of the sphere (8 sign patterns).
#[derive(Debug)]
pub struct OrientationCoverage {
    pub samples: usize,
    /// Samples per 30° image sector of the projected z axis, counter-clockwise from image right.
    pub image_sectors: [usize; 12],
    /// Samples per octant of the camera-frame z axis (bit 0: x < 0, bit 1: y < 0, bit 2: z < 0).
    pub octants: [usize; 8],
}

impl OrientationCoverage {
    pub fn of(samples: &[serde_json::Value], dir: &Path) -> OrientationCoverage {
        let mut out = OrientationCoverage { samples: 0, image_sectors: [0; 12], octants: [0; 8] };
        for line in samples {
            let sample = line["sample_id"].as_str().expect("sample_id");
            let meta: serde_json::Value =
                serde_json::from_slice(&std::fs::read(dir.join(sample).join("meta.json")).expect("meta.json")).unwrap();
            let number = |v: &serde_json::Value| v.as_f64().expect("a number");
            let r: Vec<Vec<f64>> = meta["camera"]["R_w2c"]
                .as_array()
                .expect("R_w2c")
                .iter()
                .map(|row| row.as_array().expect("a row").iter().map(number).collect())
                .collect();
            let q: Vec<f64> = meta["poses"]["object"]["q"].as_array().expect("q").iter().map(number).collect();
            let (w, x, y, z) = (q[0], q[1], q[2], q[3]);
            // The object's z axis in the world: the third column of its rotation matrix.
            let axis = [2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)];
            let c: Vec<f64> = (0..3).map(|i| (0..3).map(|j| r[i][j] * axis[j]).sum()).collect();
            let angle = (-c[1]).atan2(c[0]).rem_euclid(std::f64::consts::TAU); // image y points down
            out.image_sectors[((angle / (std::f64::consts::TAU / 12.0)) as usize).min(11)] += 1;
            out.octants[usize::from(c[0] < 0.0) | usize::from(c[1] < 0.0) << 1 | usize::from(c[2] < 0.0) << 2] += 1;
            out.samples += 1;
        }
        out
    }

    pub fn sectors_hit(&self) -> usize {
        self.image_sectors.iter().filter(|&&n| n > 0).count()
    }

    pub fn octants_hit(&self) -> usize {
        self.octants.iter().filter(|&&n| n > 0).count()
    }
}
