//! The coordinator as a cluster operates it: it stops on SIGTERM within its grace period and exits
//! 0, migrations run as a step of their own (`--migrate-only`, `--no-migrate`), no database
//! password ever reaches its output, and the standard gRPC health service of its APIs follows the
//! database.
//! (A worker's SIGTERM, mid-task, is in `cluster.rs`.)

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use tonic_health::pb::HealthCheckRequest;
use tonic_health::pb::health_check_response::ServingStatus;
use tonic_health::pb::health_client::HealthClient;
use vint_tests::*;

fn coordinator(args: &[&str]) -> std::process::Output {
    Command::new(bin("vint-coordinator")).args(args).stdin(Stdio::null()).output().expect("run vint-coordinator")
}

#[tokio::test(flavor = "multi_thread")]
async fn the_coordinator_stops_on_sigterm_within_its_grace_even_with_a_watch_open_and_exits_0() {
    let dir = tempfile::tempdir().unwrap();
    let database = format!("sqlite://{}", dir.path().join("vint.db").display());
    let port = free_port();
    let url = format!("http://127.0.0.1:{port}");

    // Idle: it stops at once.
    let mut idle = start_coordinator(&database, port, &dir.path().join("logs"), "idle");
    let asked = Instant::now();
    let status = idle.sigterm_and_wait_for(Duration::from_secs(5)).expect("no exit within 5 s of SIGTERM");
    assert!(status.success(), "exited {status}");
    assert!(asked.elapsed() < Duration::from_secs(2), "an idle coordinator took {:?}", asked.elapsed());

    // With a job's watch streaming (an RPC that never finishes by itself): within the grace (10 s).
    let mut busy = start_coordinator(&database, port, &dir.path().join("logs"), "busy");
    let o = vintctl(&["submit", tiny_spec().to_str().unwrap(), "--coordinator", &url]);
    assert!(o.status.success(), "submit: {}", stderr(&o));
    let job = stdout(&o).trim().to_string();
    let mut watch = Command::new(bin("vintctl"))
        .args(["watch", &job, "--coordinator", &url, "--json"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start vintctl watch");
    std::thread::sleep(Duration::from_millis(500));
    assert!(watch.try_wait().unwrap().is_none(), "the watch is streaming");
    let asked = Instant::now();
    let status = busy.sigterm_and_wait_for(Duration::from_secs(15)).expect("no exit within 15 s of SIGTERM");
    assert!(status.success(), "exited {status}");
    assert!(asked.elapsed() < Duration::from_secs(12), "took {:?} with a watch open", asked.elapsed());
    let _ = watch.kill();
    let _ = watch.wait();
}

#[tokio::test(flavor = "multi_thread")]
async fn migrations_run_as_their_own_step_and_a_replica_without_them_refuses_to_start() {
    let database = postgres_database("migrate").await;

    let refused = coordinator(&["--database", &database, "--no-migrate"]);
    assert_eq!(refused.status.code(), Some(2), "{}", stderr(&refused));
    let err = stderr(&refused);
    assert!(err.contains("schema is behind") && err.contains("--migrate-only"), "{err}");

    let both = coordinator(&["--database", &database, "--no-migrate", "--migrate-only"]);
    assert_eq!(both.status.code(), Some(2), "the flags exclude each other: {}", stderr(&both));

    let migrated = coordinator(&["--database", &database, "--migrate-only"]);
    assert!(migrated.status.success(), "{}", stderr(&migrated));
    assert!(stdout(&migrated).starts_with("migrated "), "{}", stdout(&migrated));
    let again = coordinator(&["--database", &database, "--migrate-only"]);
    assert!(again.status.success(), "migrating twice is a no-op: {}", stderr(&again));

    // Now the replica starts, and serves.
    let port = free_port();
    let mut cmd = Command::new(bin("vint-coordinator"));
    cmd.args(["--database", &database, "--listen", &format!("127.0.0.1:{port}"), "--no-migrate"]);
    let child = cmd.stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
    let mut replica = Proc { child, name: "replica".into() };
    let deadline = Instant::now() + Duration::from_secs(30);
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(replica.child.try_wait().unwrap().is_none(), "the replica exited");
        assert!(Instant::now() < deadline, "the replica did not start");
        std::thread::sleep(Duration::from_millis(50));
    }
    let o = vintctl(&["submit", tiny_spec().to_str().unwrap(), "--coordinator", &format!("http://127.0.0.1:{port}")]);
    assert!(o.status.success(), "submit to the replica: {}", stderr(&o));
    assert!(replica.sigterm_and_wait_for(Duration::from_secs(15)).is_some_and(|s| s.success()));
}

/// `postgres://USER:PASSWORD@<the test server>/DB`, for a role that does not exist.
fn url_with_password(password: &str) -> String {
    let admin = std::env::var("VINT_TEST_POSTGRES_URL")
        .unwrap_or_else(|_| "postgres://postgres@127.0.0.1:5432/postgres".to_string());
    let rest = admin.split_once("://").map(|(_, rest)| rest).unwrap_or(&admin);
    let server = rest.rsplit_once('@').map(|(_, server)| server).unwrap_or(rest);
    let server = server.split(['?', '/']).next().unwrap_or(server);
    format!("postgres://vint_no_such_role:{password}@{server}/postgres?password={password}&application_name=vint")
}

#[test]
fn the_coordinator_never_prints_the_database_password() {
    let url = url_with_password("hunter2");
    let o = coordinator(&["--database", &url, "--listen", "127.0.0.1:0"]);
    assert!(!o.status.success(), "connected as a role that does not exist");
    let (out, err) = (stdout(&o), stderr(&o));
    assert!(!out.contains("hunter2") && !err.contains("hunter2"), "the password was printed:\n{out}\n{err}");
    let redacted = vint_telemetry::redact_url(&url);
    assert!(err.contains(&format!("opening database {redacted}")), "the error names the database: {err}");
    assert!(redacted.contains("vint_no_such_role:***@") && redacted.contains("password=***"), "{redacted}");
}

/// Clap prints a flag's environment value in `--help` unless told not to: the database URL (its
/// password), the tokens file and the store (an S3 URL may carry credentials) are hidden in every
/// binary that takes them.
#[test]
fn help_never_prints_a_secret_from_the_environment() {
    let url = url_with_password("hunter2");
    for (binary, args) in
        [("vint-coordinator", &["--help"][..]), ("vint-worker", &["--help"]), ("vintctl", &["export", "--help"])]
    {
        let o = Command::new(bin(binary))
            .args(args)
            .env("VINT_DATABASE_URL", &url)
            .env("VINT_STORE", "s3://bucket?secret=hunter2")
            .env("VINT_AUTH_TOKENS", "/secrets/hunter2")
            .env("VINT_TOKEN", "hunter2")
            .stdin(Stdio::null())
            .output()
            .expect("run --help");
        assert!(o.status.success(), "{binary} {args:?}: {}", stderr(&o));
        let (out, err) = (stdout(&o), stderr(&o));
        assert!(out.contains("--"), "{binary} {args:?} printed no help: {out}");
        assert!(
            !out.contains("hunter2") && !err.contains("hunter2"),
            "{binary} {args:?} printed a secret:\n{out}{err}"
        );
    }
}

async fn health(url: &str, service: &str) -> Result<ServingStatus, tonic::Status> {
    let unavailable = |e: tonic::transport::Error| tonic::Status::unavailable(e.to_string());
    let channel = tonic::transport::Endpoint::from_shared(url.to_string()).map_err(unavailable)?;
    let mut client = HealthClient::new(channel.connect().await.map_err(unavailable)?);
    let answer = client.check(HealthCheckRequest { service: service.into() }).await?.into_inner();
    Ok(ServingStatus::try_from(answer.status).unwrap_or(ServingStatus::Unknown))
}

#[tokio::test(flavor = "multi_thread")]
async fn grpc_health_is_serving_while_the_database_answers_and_not_serving_when_it_does_not() {
    let database = postgres_database("health").await;
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let address = format!("http://127.0.0.1:{port}");
    let url = address.as_str();
    let _coordinator = start_coordinator(&database, port, &dir.path().join("logs"), "coordinator");
    let services = ["", "vint.v1.JobService", "vint.v1.WorkService"];
    for service in services {
        wait_for(Duration::from_secs(10), &format!("{service:?} SERVING"), || async move {
            health(url, service).await.is_ok_and(|s| s == ServingStatus::Serving)
        })
        .await;
    }
    let unknown = health(url, "vint.v1.NoSuchService").await.unwrap_err();
    assert_eq!(unknown.code(), tonic::Code::NotFound);

    // The database goes away (dropped, its connections terminated): within a check or two
    // (every 5 s), both APIs read NOT_SERVING; the process itself ("") still serves.
    let admin = std::env::var("VINT_TEST_POSTGRES_URL")
        .unwrap_or_else(|_| "postgres://postgres@127.0.0.1:5432/postgres".to_string());
    let mut conn = <sqlx::AnyConnection as sqlx::Connection>::connect(&admin).await.unwrap();
    let name = database.rsplit('/').next().unwrap();
    sqlx::Executor::execute(&mut conn, sqlx::AssertSqlSafe(format!("DROP DATABASE {name} WITH (FORCE)")))
        .await
        .unwrap();
    for service in &services[1..] {
        wait_for(Duration::from_secs(20), &format!("{service:?} NOT_SERVING"), || async move {
            health(url, service).await.is_ok_and(|s| s == ServingStatus::NotServing)
        })
        .await;
    }
    assert_eq!(health(url, "").await.unwrap(), ServingStatus::Serving, "liveness does not follow the database");
}
