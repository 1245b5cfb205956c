//! The dashboard views on a finished tiny job (`vintctl run examples/tiny.toml`, SQLite): each
//! view's numbers against an independent count over the store's tasks, attempts and artifacts
//! (and, for touch, the grasp tasks' own `touch.json`), then `vintctl dashboard --json` through a
//! coordinator over the same database against the store's rows. One run serves every assertion.

use std::collections::{BTreeMap, BTreeSet};

use serde_json::{Value, json};
use vint_artifacts::ArtifactStore;
use vint_core::contract::grasp::{GraspResult, TOUCH_FILE};
use vint_core::plan::GraspChunk;
use vint_core::{AttemptOutcome, Stage, TaskState};
use vint_store::{AttemptRecord, DashboardView, RetryPolicy, Store, TaskRecord};
use vint_tests::*;

/// A view's rows for `job`, as JSON objects keyed by column.
async fn view(store: &Store, view: DashboardView, job: Option<&str>) -> Vec<Value> {
    store.dashboard(view, job, 0).await.unwrap().objects().into_iter().map(Value::Object).collect()
}

/// The rows of `rows` keyed by the values of `key` columns.
fn keyed(rows: &[Value], key: &[&str]) -> BTreeMap<Vec<String>, Value> {
    rows.iter().map(|r| (key.iter().map(|k| r[*k].to_string()).collect(), r.clone())).collect()
}

/// Equal JSON, but for sums of reals, which may differ in their last bit between two reads of the
/// same rows (SQLite sums in the order it reads them).
fn same(a: &Value, b: &Value) -> bool {
    match (a, b) {
        (Value::Array(a), Value::Array(b)) => a.len() == b.len() && a.iter().zip(b).all(|(a, b)| same(a, b)),
        (Value::Object(a), Value::Object(b)) => {
            a.len() == b.len() && a.iter().all(|(k, v)| b.get(k).is_some_and(|w| same(v, w)))
        }
        (Value::Number(x), Value::Number(y)) if x.is_f64() || y.is_f64() => {
            let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
            (x - y).abs() <= 1e-9 * x.abs().max(y.abs())
        }
        _ => a == b,
    }
}

fn s(v: impl ToString) -> String {
    json!(v.to_string()).to_string()
}

#[tokio::test(flavor = "multi_thread")]
async fn dashboard_views_agree_with_the_task_table_on_a_finished_tiny_job() {
    let tmp = tempfile::tempdir().unwrap();
    let run = run_tiny(tmp.path(), 2);
    assert!(run.status.success(), "{}", stderr(&run));
    let state = tmp.path().join("state");
    let url = format!("sqlite://{}", state.join("vint.db").display());
    let store = Store::open(&url, RetryPolicy::default()).await.unwrap();
    let job = store.list_jobs(1).await.unwrap().remove(0).id;
    let tasks = store.tasks_of_job(&job).await.unwrap();
    let mut attempts: Vec<(&TaskRecord, AttemptRecord)> = Vec::new();
    for t in &tasks {
        attempts.extend(store.attempts(&t.id).await.unwrap().into_iter().map(|a| (t, a)));
    }
    let j = Some(job.as_str());

    // job_progress: tasks per stage and state.
    let mut states: BTreeMap<(Stage, TaskState), i64> = BTreeMap::new();
    for t in &tasks {
        *states.entry((t.stage, t.state)).or_default() += 1;
    }
    let progress = view(&store, DashboardView::JobProgress, j).await;
    let stages: BTreeSet<Stage> = tasks.iter().map(|t| t.stage).collect();
    assert_eq!(progress.len(), stages.len(), "{progress:?}");
    for row in &progress {
        let stage: Stage = row["stage"].as_str().unwrap().parse().unwrap();
        let count = |state: TaskState| states.get(&(stage, state)).copied().unwrap_or(0);
        let total: i64 = states.iter().filter(|((st, _), _)| *st == stage).map(|(_, n)| n).sum();
        assert_eq!(row["tasks"], json!(total), "{row}");
        for state in [TaskState::Waiting, TaskState::Queued, TaskState::Running, TaskState::Succeeded] {
            assert_eq!(row[state.as_str()], json!(count(state)), "{stage} {state:?}: {row}");
        }
        assert_eq!(row["succeeded"], row["tasks"], "a finished tiny job succeeded everywhere: {row}");
    }

    // throughput: attempts ended per stage and minute.
    let mut minutes: BTreeMap<Vec<String>, (i64, i64)> = BTreeMap::new();
    for (t, a) in &attempts {
        let ended = a.ended_ms.expect("a finished job's attempts ended");
        let counts = minutes.entry(vec![s(t.stage.as_str()), (ended - ended % 60_000).to_string()]).or_default();
        if a.outcome == Some(AttemptOutcome::Succeeded) {
            counts.0 += 1;
        } else {
            counts.1 += 1;
        }
    }
    let throughput = keyed(&view(&store, DashboardView::Throughput, j).await, &["stage", "minute_ms"]);
    let shown: BTreeMap<Vec<String>, (i64, i64)> = throughput
        .iter()
        .map(|(k, r)| (k.clone(), (r["succeeded"].as_i64().unwrap(), r["failed"].as_i64().unwrap())))
        .collect();
    assert_eq!(shown, minutes);
    assert!(throughput.values().all(|r| r["engine_s"].as_f64().unwrap() > 0.0), "{throughput:?}");

    // failures: attempts that did not succeed, by stage, outcome and reason.
    let mut failed: BTreeMap<Vec<String>, (i64, BTreeSet<&str>)> = BTreeMap::new();
    for (t, a) in attempts.iter().filter(|(_, a)| a.outcome != Some(AttemptOutcome::Succeeded)) {
        let reason: String = a.error.clone().unwrap_or_default().chars().take(200).collect();
        let outcome = a.outcome.map(|o| o.as_str()).unwrap_or_default();
        let entry = failed.entry(vec![s(t.stage.as_str()), s(outcome), s(reason)]).or_default();
        entry.0 += 1;
        entry.1.insert(&t.key);
    }
    let failures = keyed(&view(&store, DashboardView::Failures, j).await, &["stage", "outcome", "reason"]);
    assert_eq!(failures.keys().collect::<Vec<_>>(), failed.keys().collect::<Vec<_>>());
    for (k, (n, keys)) in &failed {
        let row = &failures[k];
        assert_eq!(row["attempts"], json!(n));
        assert_eq!(row["tasks"], json!(keys.len()));
        assert_eq!(row["first_task_key"], json!(keys.first().unwrap()));
        assert_eq!(row["last_task_key"], json!(keys.last().unwrap()));
    }

    // workers: every worker that ran an attempt, seen by the time it leased it, holding nothing now.
    let workers = keyed(&view(&store, DashboardView::Workers, None).await, &["worker_id"]);
    let mut leased: BTreeMap<&str, (i64, i64, BTreeSet<Stage>)> = BTreeMap::new();
    for (t, a) in &attempts {
        let w = leased.entry(&a.worker_id).or_insert((i64::MAX, i64::MIN, BTreeSet::new()));
        w.0 = w.0.min(a.started_ms);
        w.1 = w.1.max(a.started_ms);
        w.2.insert(t.stage);
    }
    for (worker, (first, last, stages)) in &leased {
        let row = &workers[&vec![s(worker)]];
        assert!(row["first_seen_ms"].as_i64().unwrap() <= *first, "{row}");
        // A lease request writes the row at most once a second.
        assert!(row["last_seen_ms"].as_i64().unwrap() + 1_000 >= *last, "{row}");
        assert_eq!(row["running_tasks"], json!(0), "{row}");
        let asked: BTreeSet<&str> = row["stages"].as_str().unwrap().split(',').collect();
        assert!(stages.iter().all(|st| asked.contains(st.as_str())), "{row} leased {stages:?}");
    }

    // grasp_acceptance and grasp_rejections: the grasp chunks' results, per (object, hand).
    let artifacts = ArtifactStore::open(&format!("file://{}", state.join("objects").display())).unwrap();
    let mut pairs: BTreeMap<Vec<String>, (i64, i64, i64)> = BTreeMap::new();
    let mut reasons: BTreeMap<Vec<String>, i64> = BTreeMap::new();
    let mut touch: BTreeMap<(String, String), Vec<i64>> = BTreeMap::new();
    let mut accepted_by_hand: BTreeMap<String, i64> = BTreeMap::new();
    for t in tasks.iter().filter(|t| t.stage == Stage::Grasp) {
        let chunk = GraspChunk::from_key(&t.key).unwrap();
        let result: GraspResult = serde_json::from_str(t.result_json.as_deref().unwrap()).unwrap();
        let pair = pairs.entry(vec![s(&chunk.object), s(&chunk.hand)]).or_default();
        let rejected: u32 = result.rejected.values().sum();
        *pair = (pair.0 + 1, pair.1 + result.accepted.len() as i64, pair.2 + i64::from(rejected));
        for (reason, n) in &result.rejected {
            *reasons.entry(vec![s(&chunk.object), s(&chunk.hand), s(reason)]).or_default() += i64::from(*n);
        }
        // Active taxels per accepted grasp and region, from the chunk's touch.json itself.
        let file = store.artifacts_of_task(&t.id).await.unwrap().into_iter().find(|a| a.name == TOUCH_FILE).unwrap();
        let doc: Value = serde_json::from_slice(&artifacts.get(&file.sha256).await.unwrap()).unwrap();
        let regions = vint_core::catalog::hand(&chunk.hand).unwrap().taxels_per_region.keys();
        for trial in doc["trials"].as_array().unwrap() {
            if !result.accepted.contains(&(trial["grasp_index"].as_u64().unwrap() as u32)) {
                continue;
            }
            *accepted_by_hand.entry(chunk.hand.clone()).or_default() += 1;
            for region in regions.clone() {
                let active = trial["active"].as_array().unwrap().iter().filter(|a| a["region"] == json!(region));
                touch.entry((chunk.hand.clone(), region.clone())).or_default().push(active.count() as i64);
            }
        }
    }
    let acceptance = keyed(&view(&store, DashboardView::GraspAcceptance, j).await, &["object", "hand"]);
    assert_eq!(acceptance.keys().collect::<Vec<_>>(), pairs.keys().collect::<Vec<_>>());
    for (k, (chunks, accepted, rejected)) in &pairs {
        let row = &acceptance[k];
        assert_eq!(
            (row["tasks"].clone(), row["accepted"].clone(), row["rejected"].clone(), row["trials"].clone()),
            (json!(chunks), json!(accepted), json!(rejected), json!(accepted + rejected)),
            "{k:?}"
        );
        let share = *accepted as f64 / (accepted + rejected) as f64;
        assert!((row["acceptance"].as_f64().unwrap() - share).abs() < 1e-12, "{row}");
    }
    let rejections = keyed(&view(&store, DashboardView::GraspRejections, j).await, &["object", "hand", "reason"]);
    let shown: BTreeMap<Vec<String>, i64> =
        rejections.iter().map(|(k, r)| (k.clone(), r["trials"].as_i64().unwrap())).collect();
    assert_eq!(shown, reasons);

    // active_taxels: per hand and region, against touch.json.
    let taxels = keyed(&view(&store, DashboardView::ActiveTaxels, j).await, &["hand", "region"]);
    assert_eq!(taxels.len(), touch.len(), "{taxels:?}");
    assert!(touch.values().any(|counts| counts.iter().any(|&n| n > 0)), "tiny's grasps touch: {touch:?}");
    for ((hand, region), counts) in &touch {
        let row = &taxels[&vec![s(hand), s(region)]];
        let sum: i64 = counts.iter().sum();
        assert_eq!(row["grasps"], json!(accepted_by_hand[hand]), "{row}");
        assert_eq!(row["active_taxels"], json!(sum), "{row}");
        assert_eq!(row["min_per_grasp"], json!(counts.iter().min().unwrap()), "{row}");
        assert_eq!(row["max_per_grasp"], json!(counts.iter().max().unwrap()), "{row}");
        assert!((row["mean_per_grasp"].as_f64().unwrap() - sum as f64 / counts.len() as f64).abs() < 1e-9);
    }

    // render_seconds: renders and views per resolution, samples and device.
    let mut renders: BTreeMap<Vec<String>, (i64, i64)> = BTreeMap::new();
    for t in tasks.iter().filter(|t| t.stage == Stage::Render) {
        let params: Value = serde_json::from_str(&t.params_json).unwrap();
        let result: Value = serde_json::from_str(t.result_json.as_deref().unwrap()).unwrap();
        let r = &params["render"];
        let key = vec![
            r["width"].to_string(),
            r["height"].to_string(),
            r["samples"].to_string(),
            result["device"].to_string(),
        ];
        let entry = renders.entry(key).or_default();
        *entry = (entry.0 + 1, entry.1 + result["views"].as_i64().unwrap());
    }
    let render = keyed(&view(&store, DashboardView::RenderSeconds, j).await, &["width", "height", "samples", "device"]);
    let shown: BTreeMap<Vec<String>, (i64, i64)> = render
        .iter()
        .map(|(k, r)| (k.clone(), (r["renders"].as_i64().unwrap(), r["views"].as_i64().unwrap())))
        .collect();
    assert_eq!(shown, renders);
    for row in render.values() {
        let (engine_s, per_view) = (row["engine_s"].as_f64().unwrap(), row["seconds_per_view"].as_f64().unwrap());
        assert!(engine_s > 0.0 && (per_view * row["views"].as_f64().unwrap() - engine_s).abs() < 1e-6, "{row}");
    }

    // bytes_written: artifacts per stage.
    let mut bytes: BTreeMap<Vec<String>, (i64, i64)> = BTreeMap::new();
    for t in &tasks {
        for a in store.artifacts_of_task(&t.id).await.unwrap() {
            let entry = bytes.entry(vec![s(t.stage.as_str())]).or_default();
            *entry = (entry.0 + 1, entry.1 + a.size as i64);
        }
    }
    let written = keyed(&view(&store, DashboardView::BytesWritten, j).await, &["stage"]);
    let shown: BTreeMap<Vec<String>, (i64, i64)> = written
        .iter()
        .map(|(k, r)| (k.clone(), (r["files"].as_i64().unwrap(), r["bytes"].as_i64().unwrap())))
        .collect();
    assert_eq!(shown, bytes);

    // occlusion: the exported samples' own camera records, binned in tenths (bin 9 holds 1).
    let mut bins: BTreeMap<(String, i64), i64> = BTreeMap::new();
    let out = tmp.path().join("out");
    for line in verify_dataset(&out) {
        let sample = line["sample_id"].as_str().unwrap();
        let meta: Value = serde_json::from_slice(&std::fs::read(out.join(sample).join("meta.json")).unwrap()).unwrap();
        let occlusion = meta["visibility"]["occlusion"].as_f64().unwrap();
        let bin = ((occlusion * 10.0).floor() as i64).min(9);
        *bins.entry((meta["object"]["name"].as_str().unwrap().to_string(), bin)).or_default() += 1;
    }
    let shown: BTreeMap<(String, i64), i64> = view(&store, DashboardView::Occlusion, j)
        .await
        .iter()
        .map(|r| {
            ((r["object"].as_str().unwrap().to_string(), r["bin"].as_i64().unwrap()), r["views"].as_i64().unwrap())
        })
        .collect();
    assert!(!bins.is_empty(), "the tiny run exported no samples");
    assert_eq!(shown, bins, "views per object and occlusion tenth");

    // vintctl dashboard, through a coordinator over the same database, prints the store's rows.
    let (port, http) = (free_port(), free_port());
    let http_listen = format!("127.0.0.1:{http}");
    let _coordinator = start_coordinator_with_args(
        &url,
        port,
        &tmp.path().join("logs"),
        "coordinator",
        &["--http-listen", &http_listen],
    );
    let address = format!("http://127.0.0.1:{port}");
    for v in DashboardView::ALL {
        let job_args: &[&str] = if v.per_job() { &["--job", &job] } else { &[] };
        let args = [&["--coordinator", address.as_str(), "dashboard", v.name(), "--json"][..], job_args].concat();
        let o = vintctl(&args);
        assert!(o.status.success(), "{v}: {}", stderr(&o));
        let printed: Value = serde_json::from_str(&stdout(&o)).unwrap();
        let expected = Value::Array(view(&store, v, v.per_job().then_some(job.as_str())).await);
        assert!(same(&printed, &expected), "{v}: vintctl printed {printed}, the store has {expected}");
    }
    let text = vintctl(&["--coordinator", &address, "dashboard", "job_progress", "--job", &job]);
    assert!(text.status.success() && stdout(&text).starts_with("JOB_ID"), "{}", stdout(&text));
    for bad in [
        &["dashboard", "progress"][..],
        &["dashboard", "workers", "--job", &job],
        &["dashboard", "failures", "--job", "nope"],
    ] {
        let o = vintctl(&[&["--coordinator", address.as_str()][..], bad].concat());
        assert_eq!(o.status.code(), Some(2), "{bad:?}: {}", stderr(&o));
    }

    // The web dashboard in headless Chromium shows the views' numbers (docs/dashboard.md).
    let page = format!("http://127.0.0.1:{http}/dashboard?job={job}&refresh=0");
    let dom = chromium_run(&page, &["--dump-dom"], 10_000);
    assert!(dom.contains("data-ready=\"1\""), "the page never finished loading: {dom}");
    let tables = page_tables(&dom);
    for name in [
        "job_progress",
        "failures",
        "workers",
        "bytes_written",
        "grasp_acceptance",
        "grasp_rejections",
        "active_taxels",
        "occlusion",
        "render_seconds",
    ] {
        let v: DashboardView = name.parse().unwrap();
        let table = store.dashboard(v, v.per_job().then_some(job.as_str()), 0).await.unwrap();
        let shown = tables.get(name).map(Vec::as_slice).unwrap_or_default();
        assert_eq!(shown.len(), table.rows.len(), "{name}: the page shows {shown:?}");
        for (row, cells) in table.rows.iter().zip(shown) {
            for (column, value) in table.columns.iter().zip(row) {
                let Some((data, text)) = cells.get(column) else {
                    assert_eq!(column, "job_id", "{name}: the page leaves out {column}");
                    continue;
                };
                let at = format!("{name}.{column}");
                match value {
                    Value::Null => assert_eq!((data.as_str(), text.as_str()), ("null", ""), "{at}"),
                    Value::String(v) => assert_eq!((data, text), (v, v), "{at}"),
                    Value::Number(n) => {
                        let v = n.as_f64().unwrap();
                        assert_eq!(data.parse::<f64>().unwrap(), v, "{at}: data-value");
                        if column.ends_with("_ms") {
                            assert!(text.ends_with('Z') && text.len() == 20, "{at}: a UTC time, not {text:?}");
                        } else if n.is_f64() {
                            assert!((text.parse::<f64>().unwrap() - v).abs() <= 0.0005 + 1e-9, "{at}: {text} vs {v}");
                        } else {
                            assert_eq!(text.parse::<f64>().unwrap(), v, "{at}");
                        }
                    }
                    other => panic!("{at}: a view cell is never {other}"),
                }
            }
        }
    }
    let progress = view(&store, DashboardView::JobProgress, j).await;
    let total = |c: &str| progress.iter().map(|r| r[c].as_i64().unwrap()).sum::<i64>().to_string();
    let listed = tables["jobs"].iter().find(|r| r["job_id"].0 == job).expect("the job is listed");
    assert_eq!((listed["tasks"].0.clone(), listed["succeeded"].0.clone()), (total("tasks"), total("succeeded")));
    for chart in ["throughput", "acceptance", "taxels", "occlusion"] {
        let tag = dom.split("<img").find(|t| t.contains(&format!("data-chart=\"{chart}\""))).unwrap_or_default();
        assert!(tag.contains("data-loaded=\"1\""), "chart {chart} did not load: {tag}");
    }

    // Screenshot: the charts are painted (their bars and lines are the first series colour) and the
    // picture is kept in target/test-artifacts/ for a person to look at.
    let shot = tmp.path().join("dashboard.png");
    chromium_run(&page, &[&format!("--screenshot={}", shot.display()), "--window-size=1400,2600"], 10_000);
    let (width, height, painted) = series_pixels(&shot, [31, 95, 191]);
    assert_eq!((width, height), (1400, 2600));
    assert!(painted > 3_000, "only {painted} pixels of the charts' colour: were the charts drawn?");
    let kept = repo_root().join("target/test-artifacts");
    std::fs::create_dir_all(&kept).unwrap();
    std::fs::copy(&shot, kept.join("dashboard.png")).unwrap();
    store.close().await;
}

/// One table cell as the page shows it: its `data-value` and its text.
type Cell = (String, String);

/// The tables of the dumped page, by `data-view`: each row's cells by `data-col`.
fn page_tables(dom: &str) -> BTreeMap<String, Vec<BTreeMap<String, Cell>>> {
    let mut tables = BTreeMap::new();
    for chunk in dom.split("<table data-view=\"").skip(1) {
        let (name, rest) = chunk.split_once('"').unwrap();
        let body = rest.split("</table>").next().unwrap();
        let mut rows = Vec::new();
        for tr in body.split("<tr").skip(1) {
            let mut cells = BTreeMap::new();
            for td in tr.split("<td").skip(1) {
                let (tag, inner) = td.split_once('>').unwrap();
                let (Some(col), Some(value)) = (attribute(tag, "data-col"), attribute(tag, "data-value")) else {
                    continue;
                };
                let text = inner.split("</td>").next().unwrap();
                cells.insert(col, (value, unescape(text)));
            }
            if !cells.is_empty() {
                rows.push(cells);
            }
        }
        tables.insert(name.to_string(), rows);
    }
    tables
}

fn attribute(tag: &str, name: &str) -> Option<String> {
    let start = tag.find(&format!("{name}=\""))? + name.len() + 2;
    let end = tag[start..].find('"')?;
    Some(unescape(&tag[start..start + end]))
}

fn unescape(text: &str) -> String {
    text.replace("&lt;", "<").replace("&gt;", ">").replace("&quot;", "\"").replace("&#39;", "'").replace("&amp;", "&")
}

/// The PNG's size and how many of its pixels are exactly `rgb`.
fn series_pixels(path: &std::path::Path, rgb: [u8; 3]) -> (u32, u32, usize) {
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    let channels = info.color_type.samples();
    let pixels = buf[..info.buffer_size()].chunks(channels).filter(|p| p[..3] == rgb).count();
    (info.width, info.height, pixels)
}
