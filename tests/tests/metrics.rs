//! The coordinator's and a worker's HTTP side as Prometheus and a probe see them: `/metrics`
//! parses as Prometheus text — read by Prometheus's own Python parsers
//! (`tests/python/check_metrics.py`), not by the code that writes it —, its counters agree with
//! the store, the queue gauges follow the queue, and `/healthz` answers for what it checks.
//!
//! The worker runs in timing-only mode: the metrics are the same for real engines, and the job
//! takes seconds.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use vint_store::{RetryPolicy, Store};
use vint_tests::*;

/// One pair, 4 accepted grasps of at most 8 trials, 2 views, noisy depth: every stage runs.
const SPEC: &str = r#"
hands = ["trx3"]
objects = ["mug"]
[dataset]
name = "metrics"
seed = 5
[grasp]
accepted_per_pair = 4
trials_per_pair = 8
chunk_size = 4
[render]
resolution = [64, 48]
views_per_environment = 2
[outputs]
modalities = ["rgb", "depth", "depth_noisy"]
"#;

/// The samples of one `/metrics` scrape, as Prometheus's parser read them.
struct Exposition(Vec<serde_json::Value>);

impl Exposition {
    /// Scrapes `/metrics` on `port` and parses it with `tests/python/check_metrics.py`.
    fn scrape(port: u16, dir: &Path) -> Exposition {
        let (status, content_type, body) = http_get(port, "/metrics").expect("nothing serves /metrics");
        assert_eq!(status, 200, "{body}");
        assert!(content_type.starts_with("application/openmetrics-text; version=1.0.0"), "{content_type}");
        let file = dir.join(format!("metrics-{port}.txt"));
        std::fs::write(&file, &body).unwrap();
        let o = Command::new(python())
            .arg(repo_root().join("tests/python/check_metrics.py"))
            .arg(&file)
            .output()
            .expect("run check_metrics.py");
        assert!(o.status.success(), "/metrics on port {port} is not Prometheus text: {}\n{body}", stderr(&o));
        Exposition(serde_json::from_slice(&o.stdout).expect("check_metrics.py prints JSON"))
    }

    /// Sum of the samples named `name` whose labels include `labels`.
    fn sum(&self, name: &str, labels: &[(&str, &str)]) -> f64 {
        self.0
            .iter()
            .filter(|s| s["name"] == name && labels.iter().all(|(k, v)| s["labels"][k] == *v))
            .map(|s| s["value"].as_f64().expect("a number"))
            .sum()
    }

    /// Labels of the samples named `name`.
    fn series(&self, name: &str) -> Vec<&serde_json::Value> {
        self.0.iter().filter(|s| s["name"] == name).map(|s| &s["labels"]).collect()
    }
}

/// Scrapes every half second until `cond` holds; fails after 20 s.
async fn scrape_until(port: u16, dir: &Path, what: &str, cond: impl Fn(&Exposition) -> bool) -> Exposition {
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let e = Exposition::scrape(port, dir);
        if cond(&e) {
            return e;
        }
        assert!(Instant::now() < deadline, "timed out waiting for {what}: {:#?}", e.0);
        tokio::time::sleep(Duration::from_millis(500)).await;
    }
}

#[tokio::test(flavor = "multi_thread")]
async fn metrics_parse_as_prometheus_text_and_count_what_the_store_holds() {
    let dir = tempfile::tempdir().unwrap();
    let spec = dir.path().join("spec.toml");
    std::fs::write(&spec, SPEC).unwrap();
    let database = postgres_database("metrics").await;
    let store_url = format!("file://{}", dir.path().join("objects").display());
    let logs = dir.path().join("logs");
    let (port, http, worker_http) = (free_port(), free_port(), free_port());
    let coordinator = format!("http://127.0.0.1:{port}");
    let http_listen = format!("127.0.0.1:{http}");
    let _coordinator =
        start_coordinator_with_args(&database, port, &logs, "coordinator", &["--http-listen", &http_listen]);
    wait_for(Duration::from_secs(10), "the coordinator's /healthz", || async {
        http_get(http, "/healthz").is_some_and(|(status, _, body)| status == 200 && body == "ok\n")
    })
    .await;

    let o = vintctl(&["submit", spec.to_str().unwrap(), "--timing-only", "--coordinator", &coordinator]);
    assert!(o.status.success(), "submit: {}", stderr(&o));
    let job = stdout(&o).trim().to_string();
    let store = Store::open(&database, RetryPolicy::default()).await.unwrap();
    let grasps = store.tasks_of_job(&job).await.unwrap().len() as f64;
    assert!(grasps >= 1.0, "a job starts with its grasp chunks");

    // Before any worker: the submitted grasp chunks are queued, and the gauge says so.
    let queued = |e: &Exposition| e.sum("vint_queue_tasks", &[("stage", "grasp"), ("state", "queued")]);
    let before = scrape_until(http, dir.path(), "the queue gauge to count the grasp chunks", |e| {
        queued(e) == grasps && e.sum("vint_jobs", &[("state", "running")]) == 1.0
    })
    .await;
    // Every stage and live state has its series, so an autoscaler reads 0 rather than nothing.
    assert_eq!(before.series("vint_queue_tasks").len(), 4 * 3);
    assert_eq!(before.sum("vint_jobs_submitted_total", &[]), 1.0);

    let worker = Command::new(bin("vint-worker"))
        .args(["--coordinator", &coordinator, "--store", &store_url, "--worker-id", "timing"])
        .args(["--engine-mode", "timing-only", "--batch", "4", "--concurrency", "1"])
        .args(["--metrics-listen", &format!("127.0.0.1:{worker_http}")])
        .stdout(Stdio::null())
        .stderr(Stdio::from(std::fs::File::create(dir.path().join("worker.log")).unwrap()))
        .spawn()
        .expect("start worker");
    let _worker = Proc { child: worker, name: "timing".into() };
    let o = vintctl(&["watch", &job, "--coordinator", &coordinator, "--json"]);
    assert!(o.status.success(), "job did not succeed: {}\n{}", stdout(&o), stderr(&o));

    let mut by_stage: BTreeMap<String, f64> = BTreeMap::new();
    for t in store.tasks_of_job(&job).await.unwrap() {
        assert_eq!(t.attempt, 1, "{t:?}");
        *by_stage.entry(t.stage.as_str().to_string()).or_default() += 1.0;
    }
    assert_eq!(by_stage.len(), 4, "every stage ran: {by_stage:?}");

    // The coordinator: the queue drains to 0, and it leased and completed each task once.
    let after = scrape_until(http, dir.path(), "the queue to drain", |e| {
        e.sum("vint_queue_tasks", &[]) == 0.0 && e.sum("vint_jobs", &[("state", "succeeded")]) == 1.0
    })
    .await;
    for (stage, n) in &by_stage {
        let stage = [("stage", stage.as_str())];
        assert_eq!(after.sum("vint_tasks_leased_total", &stage), *n, "{stage:?}");
        assert_eq!(after.sum("vint_tasks_completed_total", &stage), *n, "{stage:?}");
    }
    assert_eq!(after.sum("vint_tasks_failed_total", &[]), 0.0);
    assert_eq!(after.sum("vint_completions_refused_total", &[]), 0.0);
    assert!(after.sum("vint_rpc_duration_seconds_count", &[("rpc", "lease_tasks")]) >= 4.0);
    let completions = after.sum("vint_rpc_duration_seconds_count", &[("rpc", "complete_tasks")]);
    assert!(completions >= 4.0, "a batch call per stage at least: {completions}");
    assert_eq!(
        after.sum("vint_rpc_duration_seconds_bucket", &[("rpc", "complete_tasks"), ("le", "+Inf")]),
        completions
    );

    // The worker: each task completed once, by stage, and it uploaded bytes.
    let worker_metrics = Exposition::scrape(worker_http, dir.path());
    for (stage, n) in &by_stage {
        let labels = [("stage", stage.as_str()), ("outcome", "completed")];
        assert_eq!(worker_metrics.sum("vint_worker_tasks_total", &labels), *n, "{stage}");
    }
    assert_eq!(worker_metrics.sum("vint_worker_tasks_total", &[]), by_stage.values().sum::<f64>());
    assert!(worker_metrics.sum("vint_worker_uploaded_bytes_total", &[]) > 0.0);
    assert_eq!(http_get(worker_http, "/healthz").map(|(status, _, _)| status), Some(200));

    // deploy/grafana/vint.json: every metric its PromQL names is exported by the coordinator or a
    // worker, and every SQL query it runs answers on this job's database.
    let grafana: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(repo_root().join("deploy/grafana/vint.json")).unwrap()).unwrap();
    let targets: Vec<&serde_json::Value> = grafana["panels"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|p| p["targets"].as_array().into_iter().flatten())
        .collect();
    // A family is exported if either exposition declares it (`# TYPE`), whether or not it has a
    // sample yet: the timing-only worker runs no engine, so its engine histograms stay empty.
    let mut exported: BTreeSet<String> = BTreeSet::new();
    for port in [http, worker_http] {
        let text = std::fs::read_to_string(dir.path().join(format!("metrics-{port}.txt"))).unwrap();
        exported.extend(text.lines().filter_map(|l| l.strip_prefix("# TYPE ")?.split(' ').next().map(String::from)));
    }
    let (mut exprs, mut queries) = (0, 0);
    let variables = grafana["templating"]["list"].as_array().unwrap().iter();
    let variable_queries =
        variables.filter(|v| v["type"] == "query").map(|v| serde_json::json!({"rawSql": v["query"]}));
    let variable_queries: Vec<serde_json::Value> = variable_queries.collect();
    for target in targets.iter().copied().chain(&variable_queries) {
        if let Some(expr) = target["expr"].as_str() {
            exprs += 1;
            for name in metric_names(expr) {
                let family = ["_bucket", "_count", "_sum", "_total"]
                    .iter()
                    .find_map(|suffix| name.strip_suffix(suffix).filter(|f| exported.contains(*f)))
                    .unwrap_or(&name);
                assert!(exported.contains(family), "the Grafana query {expr:?} names {name}, which nothing exports");
            }
        }
        if let Some(sql) = target["rawSql"].as_str() {
            queries += 1;
            // Counted in a subquery: it runs in full, and sqlx's Any driver need not decode
            // Grafana's timestamp columns.
            let sql = format!("SELECT COUNT(*) FROM ({}) AS panel", sql.replace("$job", &job));
            let mut conn = <sqlx::AnyConnection as sqlx::Connection>::connect(&database).await.unwrap();
            let rows = sqlx::Executor::fetch_all(&mut conn, sqlx::AssertSqlSafe(sql.clone())).await;
            assert!(rows.is_ok(), "the Grafana query {sql:?} fails: {:?}", rows.err());
        }
    }
    assert!(exprs >= 9 && queries >= 10, "{exprs} PromQL and {queries} SQL queries");

    // Health is the database's: gone, the coordinator answers 503 and says so, without the
    // database's own words (they name it; the log has them).
    store.close().await;
    let admin = postgres_admin_url();
    let name = database.rsplit('/').next().unwrap();
    sqlx::any::install_default_drivers();
    let mut conn = <sqlx::AnyConnection as sqlx::Connection>::connect(&admin).await.unwrap();
    sqlx::Executor::execute(&mut conn, sqlx::AssertSqlSafe(format!("DROP DATABASE {name} WITH (FORCE)")))
        .await
        .unwrap();
    wait_for(Duration::from_secs(10), "/healthz to answer 503", || async {
        http_get(http, "/healthz").is_some_and(|(status, _, body)| status == 503 && body.contains("database"))
    })
    .await;
    let (_, _, body) = http_get(http, "/healthz").unwrap();
    assert!(!body.contains(name), "/healthz repeats the database's error: {body}");
}

/// The `vint_*` metric names a PromQL expression reads.
fn metric_names(expr: &str) -> Vec<String> {
    let mut names = Vec::new();
    let mut rest = expr;
    while let Some(at) = rest.find("vint_") {
        let name: String = rest[at..].chars().take_while(|c| c.is_ascii_alphanumeric() || *c == '_').collect();
        rest = &rest[at + name.len()..];
        names.push(name);
    }
    names
}
