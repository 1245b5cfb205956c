//! `vintctl stats` on the tiny dataset: its figures are real PNGs, and every number in stats.json
//! equals a recount made here from the dataset's own files (meta.json, grasp.json, dataset.json;
//! BOP's scene_*.json) — not by the Python that wrote stats.json. The BOP layout gives the same
//! statistics as the native one, and a job id gives the same as its exported directory.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde_json::Value;
use vint_tests::{free_port, start_coordinator_with_store, stderr, stdout, vintctl};

use super::{bop, path_str, tiny};

const FIGURES: [&str; 8] = [
    "occlusion.png",
    "orientation.png",
    "distance.png",
    "taxels.png",
    "acceptance.png",
    "in_hand.png",
    "camera_palm.png",
    "counts.png",
];

/// `vintctl stats SUBJECT --out OUT --json` (plus `extra` global flags): what it printed, which is
/// also what it wrote to OUT/stats.json.
fn stats_of(subject: &str, out: &Path, extra: &[&str]) -> Value {
    let mut args = extra.to_vec();
    args.extend(["stats", subject, "--out", path_str(out), "--json"]);
    let run = vintctl(&args);
    assert!(run.status.success(), "vintctl stats {subject} failed:\n{}\n{}", stdout(&run), stderr(&run));
    let printed: Value = serde_json::from_str(&stdout(&run)).expect("stats --json prints JSON");
    let written: Value = read_json(&out.join("stats.json"));
    assert_eq!(printed, written, "--json prints stats.json");
    printed
}

fn read_json(path: &Path) -> Value {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_slice(&bytes).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn f64s(v: &Value) -> Vec<f64> {
    v.as_array().expect("array").iter().map(|x| x.as_f64().expect("number")).collect()
}

fn counts(v: &Value) -> Vec<u64> {
    v.as_array().expect("array").iter().map(|x| x.as_u64().expect("count")).collect()
}

/// What one view contributes: its hand, occlusion and object pose in the camera frame (metres).
struct View {
    hand: String,
    object: String,
    occlusion: f64,
    r_m2c: [[f64; 3]; 3],
    t_m2c: [f64; 3],
    /// The HDRI's name (meta.json `camera.environment.name`).
    environment: String,
    /// The renderer's own record of the palm side the camera sees (`camera.viewpoint.palm_side`).
    palm_side: String,
}

/// One grasp: its hand, the region of each active taxel and its grasp type.
struct Grasp {
    hand: String,
    regions: Vec<String>,
    grasp_type: String,
}

fn native_views_and_grasps(dir: &Path) -> (Vec<View>, BTreeMap<String, Grasp>) {
    let mut views = Vec::new();
    let mut grasps = BTreeMap::new();
    for entry in std::fs::read_dir(dir).expect("dataset dir") {
        let path = entry.expect("entry").path();
        if path.join("meta.json").is_file() {
            let meta = read_json(&path.join("meta.json"));
            let camera = &meta["camera"];
            let r = camera["R_m2c"].as_array().expect("R_m2c rows");
            let row = |i: usize| -> [f64; 3] { f64s(&r[i]).try_into().expect("3 columns") };
            views.push(View {
                hand: meta["hand"].as_str().expect("hand").into(),
                object: meta["object"]["name"].as_str().expect("object").into(),
                occlusion: meta["visibility"]["occlusion"].as_f64().expect("occlusion"),
                r_m2c: [row(0), row(1), row(2)],
                t_m2c: f64s(&camera["t_m2c"]).try_into().expect("3 numbers"),
                environment: camera["environment"]["name"].as_str().expect("environment").into(),
                palm_side: camera["viewpoint"]["palm_side"].as_str().expect("palm_side").into(),
            });
        } else if path.join("grasp.json").is_file() {
            let record = read_json(&path.join("grasp.json"));
            let regions = record["touch"]["active"].as_array().expect("touch.active");
            grasps.insert(
                record["grasp_id"].as_str().expect("grasp_id").to_string(),
                Grasp {
                    hand: record["hand"]["name"].as_str().expect("hand").into(),
                    regions: regions.iter().map(|t| t["region"].as_str().expect("region").to_string()).collect(),
                    grasp_type: record["trial"]["grasp"]["type"].as_str().expect("grasp type").into(),
                },
            );
        }
    }
    (views, grasps)
}

/// Occlusion's 10 % bin: `floor(10 · occlusion)`, 1.0 in the last.
fn occlusion_bin(occlusion: f64) -> usize {
    ((occlusion * 10.0).floor().max(0.0) as usize).min(9)
}

/// The bin of `x` among `edges`, closed on the left (the last also on the right).
fn bin_of(x: f64, edges: &[f64]) -> usize {
    let last = edges.len() - 2;
    edges.windows(2).position(|w| x >= w[0] && x < w[1]).unwrap_or(if x >= edges[last + 1] { last } else { 0 })
}

/// (band, sector) of the camera's direction in the object frame: the camera centre there is
/// `-Rᵀ t`; bands are sixths of sin(elevation) from -1, sectors 30° of azimuth from -180°.
fn orientation_cell(v: &View) -> (usize, usize) {
    let r = &v.r_m2c;
    let c: Vec<f64> = (0..3).map(|j| -(0..3).map(|i| r[i][j] * v.t_m2c[i]).sum::<f64>()).collect();
    let norm = c.iter().map(|x| x * x).sum::<f64>().sqrt();
    let (x, y, z) = (c[0] / norm, c[1] / norm, c[2] / norm);
    let azimuth = y.atan2(x).to_degrees();
    let sector = (((azimuth + 180.0) / 30.0).floor() as usize).min(11);
    let band = (((z + 1.0) * 3.0).floor().max(0.0) as usize).min(5);
    (band, sector)
}

/// A PNG whose chunks are all intact (lengths, CRC-32s), opening with IHDR of a non-empty image and
/// ending with IEND: its width and height.
pub fn assert_valid_png(path: &Path) -> (u32, u32) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "{}: PNG signature", path.display());
    let mut at = 8;
    let mut names = Vec::new();
    let mut size = (0, 0);
    while at < bytes.len() {
        let length = u32::from_be_bytes(bytes[at..at + 4].try_into().unwrap()) as usize;
        let body = &bytes[at + 4..at + 8 + length];
        let crc = u32::from_be_bytes(bytes[at + 8 + length..at + 12 + length].try_into().unwrap());
        assert_eq!(crc32(body), crc, "{}: CRC of chunk {}", path.display(), String::from_utf8_lossy(&body[..4]));
        if names.is_empty() {
            let (width, height) = (
                u32::from_be_bytes(body[4..8].try_into().unwrap()),
                u32::from_be_bytes(body[8..12].try_into().unwrap()),
            );
            assert!(width >= 100 && height >= 100, "{}: {width}x{height}", path.display());
            size = (width, height);
        }
        names.push(String::from_utf8_lossy(&body[..4]).into_owned());
        at += 12 + length;
    }
    assert_eq!(names.first().map(String::as_str), Some("IHDR"), "{}", path.display());
    assert_eq!(names.last().map(String::as_str), Some("IEND"), "{}", path.display());
    assert!(names.iter().any(|n| n == "IDAT"), "{}: no image data", path.display());
    size
}

/// CRC-32 (ISO-HDLC, as PNG uses it), bit by bit.
fn crc32(data: &[u8]) -> u32 {
    let mut crc = 0xFFFF_FFFFu32;
    for &byte in data {
        crc ^= u32::from(byte);
        for _ in 0..8 {
            crc = if crc & 1 == 1 { (crc >> 1) ^ 0xEDB8_8320 } else { crc >> 1 };
        }
    }
    !crc
}

#[test]
fn native_stats_equal_a_recount_of_the_dataset_files() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let out = tmp.path().join("stats");
    let stats = stats_of(path_str(tiny()), &out, &[]);
    for name in FIGURES {
        assert_valid_png(&out.join(name));
    }
    let table = std::fs::read_to_string(out.join("stats.md")).expect("stats.md");
    let (views, grasps) = native_views_and_grasps(tiny());
    assert!(table.contains(&format!("{} samples of {} grasps", views.len(), grasps.len())), "{table}");

    assert_eq!(stats["layout"], "native");
    assert_eq!(stats["counts"]["samples"].as_u64(), Some(views.len() as u64));
    assert_eq!(stats["counts"]["grasps"].as_u64(), Some(grasps.len() as u64));

    // Occlusion: 10 bins summing to the samples, each as recounted from meta.json, per hand too.
    let occlusion = &stats["occlusion"];
    let mut recount = [0u64; 10];
    let mut by_hand: BTreeMap<&str, [u64; 10]> = BTreeMap::new();
    for v in &views {
        recount[occlusion_bin(v.occlusion)] += 1;
        by_hand.entry(&v.hand).or_default()[occlusion_bin(v.occlusion)] += 1;
    }
    assert_eq!(counts(&occlusion["counts"]), recount.to_vec());
    assert_eq!(counts(&occlusion["counts"]).iter().sum::<u64>(), views.len() as u64);
    for (hand, bins) in &by_hand {
        assert_eq!(counts(&occlusion["by_hand"][*hand]), bins.to_vec(), "{hand}");
    }
    let mean = views.iter().map(|v| v.occlusion).sum::<f64>() / views.len() as f64;
    assert!((occlusion["summary"]["mean"].as_f64().unwrap() - mean).abs() < 1e-6, "{mean}");

    // Distance: |t_m2c| of every view, binned on the edges stats.json names, which span them all.
    let distance = &stats["distance_m"];
    let edges = f64s(&distance["edges"]);
    let norms: Vec<f64> = views.iter().map(|v| v.t_m2c.iter().map(|x| x * x).sum::<f64>().sqrt()).collect();
    let (low, high) = norms.iter().fold((f64::MAX, f64::MIN), |(l, h), &d| (l.min(d), h.max(d)));
    assert!(edges[0] <= low && high <= edges[edges.len() - 1], "{edges:?} spans {low}..{high}");
    let mut recount = vec![0u64; edges.len() - 1];
    for &d in &norms {
        recount[bin_of(d, &edges)] += 1;
    }
    assert_eq!(counts(&distance["counts"]), recount);
    assert!((distance["summary"]["min"].as_f64().unwrap() - low).abs() < 1e-6);
    assert!((distance["summary"]["max"].as_f64().unwrap() - high).abs() < 1e-6);
    // tiny's cameras stand 0.35-0.5 m from the object (render.radius_m): the origin is near its centre.
    assert!(low > 0.25 && high < 0.6, "{low}..{high}");

    // Viewing direction in the object frame on 6 × 12 equal-area cells.
    let orientation = &stats["orientation"];
    let mut grid = vec![vec![0u64; 12]; 6];
    for v in &views {
        let (band, sector) = orientation_cell(v);
        grid[band][sector] += 1;
    }
    let printed: Vec<Vec<u64>> = orientation["counts"].as_array().expect("rows").iter().map(counts).collect();
    assert_eq!(printed, grid);
    let seen = grid.iter().flatten().filter(|&&n| n > 0).count() as u64;
    assert_eq!(orientation["cells_seen"].as_u64(), Some(seen));
    for object in views.iter().map(|v| v.object.as_str()).collect::<std::collections::BTreeSet<_>>() {
        let cells: std::collections::BTreeSet<_> =
            views.iter().filter(|v| v.object == object).map(orientation_cell).collect();
        assert_eq!(orientation["by_object"][object]["cells_seen"].as_u64(), Some(cells.len() as u64), "{object}");
    }

    // Active taxels per grasp, by hand and region, from grasp.json's touch.active.
    let taxels = &stats["taxels"];
    let hands: std::collections::BTreeSet<&str> = grasps.values().map(|g| g.hand.as_str()).collect();
    for hand in hands {
        let mine: Vec<&Grasp> = grasps.values().filter(|g| g.hand == hand).collect();
        let got = &taxels["by_hand"][hand];
        assert_eq!(got["grasps"].as_u64(), Some(mine.len() as u64), "{hand}");
        let active: Vec<usize> = mine.iter().map(|g| g.regions.len()).collect();
        assert_eq!(got["active"]["min"].as_f64(), active.iter().min().map(|&n| n as f64), "{hand}");
        assert_eq!(got["active"]["max"].as_f64(), active.iter().max().map(|&n| n as f64), "{hand}");
        let mean = active.iter().sum::<usize>() as f64 / active.len() as f64;
        assert!((got["active"]["mean"].as_f64().unwrap() - mean).abs() < 1e-6, "{hand}");
        let mut by_region: BTreeMap<&str, (u64, u64)> = BTreeMap::new(); // (taxels, grasps touching)
        for g in &mine {
            for region in ["tip", "pulp", "palm"] {
                let n = g.regions.iter().filter(|r| *r == region).count() as u64;
                let e = by_region.entry(region).or_default();
                e.0 += n;
                e.1 += u64::from(n > 0);
            }
        }
        let all: u64 = mine.iter().map(|g| g.regions.len() as u64).sum();
        assert_eq!(by_region.values().map(|e| e.0).sum::<u64>(), all, "{hand}: every taxel is tip, pulp or palm");
        for (region, (total, touching)) in by_region {
            let r = &got["regions"][region];
            assert_eq!(r["total"].as_u64(), Some(total), "{hand} {region}");
            assert_eq!(r["grasps_touching"].as_u64(), Some(touching), "{hand} {region}");
        }
    }

    // Acceptance: dataset.json's pairs, reason by reason.
    let record = read_json(&tiny().join("dataset.json"));
    let pairs = stats["pairs"]["pairs"].as_array().expect("pairs");
    let expected = record["pairs"].as_array().expect("dataset.json pairs");
    assert_eq!(pairs.len(), expected.len());
    for p in expected {
        let got = pairs
            .iter()
            .find(|q| q["object"] == p["object"] && q["hand"] == p["hand"])
            .unwrap_or_else(|| panic!("no pair {p}"));
        assert_eq!(got["trials"], p["trials"], "{p}");
        assert_eq!(got["accepted"], p["accepted"], "{p}");
        for (reason, n) in p["rejected"].as_object().expect("rejected") {
            assert_eq!(&got["rejected"][reason], n, "{p} {reason}");
        }
        let listed: u64 = got["rejected"].as_object().expect("rejected").values().filter_map(Value::as_u64).sum();
        let recorded: u64 = p["rejected"].as_object().expect("rejected").values().filter_map(Value::as_u64).sum();
        assert_eq!(listed, recorded, "{p}: no reason invented");
    }
    let accepted: u64 = expected.iter().filter_map(|p| p["accepted"].as_u64()).sum();
    assert_eq!(stats["pairs"]["total"]["accepted"].as_u64(), Some(accepted));
    assert_eq!(accepted, grasps.len() as u64, "every accepted trial is a grasp of the dataset");

    // Grasp types, samples per object and environment, and the palm side each camera sees: the
    // last computed by stats from the palm's pose, recounted here from the renderer's own record.
    let mut types: BTreeMap<&str, u64> = BTreeMap::new();
    for g in grasps.values() {
        *types.entry(&g.grasp_type).or_default() += 1;
    }
    for (grasp_type, n) in &types {
        assert_eq!(stats["grasp_types"]["counts"][*grasp_type].as_u64(), Some(*n), "{grasp_type}");
    }
    let mut per_object: BTreeMap<&str, u64> = BTreeMap::new();
    let mut per_environment: BTreeMap<&str, u64> = BTreeMap::new();
    let mut sides: BTreeMap<&str, u64> = BTreeMap::new();
    for v in &views {
        *per_object.entry(&v.object).or_default() += 1;
        *per_environment.entry(&v.environment).or_default() += 1;
        *sides.entry(&v.palm_side).or_default() += 1;
    }
    for (object, n) in per_object {
        assert_eq!(stats["per_object"][object]["samples"].as_u64(), Some(n), "{object}");
    }
    assert_eq!(stats["per_environment"].as_object().expect("environments").len(), per_environment.len());
    for (environment, n) in per_environment {
        assert_eq!(stats["per_environment"][environment]["samples"].as_u64(), Some(n), "{environment}");
    }
    for side in ["front", "back"] {
        let recorded = sides.get(side).copied().unwrap_or(0);
        assert_eq!(stats["camera_palm"]["all"][side].as_u64(), Some(recorded), "{side}");
    }
    assert_eq!(stats["in_hand"]["all"]["grasps"].as_u64(), Some(grasps.len() as u64));
}

/// `a` and `b` equal, numbers within `tolerance` (BOP stores millimetres, native metres).
fn assert_close(a: &Value, b: &Value, tolerance: f64, at: &str) {
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
            assert!((x - y).abs() <= tolerance, "{at}: {x} vs {y}");
        }
        (Value::Array(x), Value::Array(y)) => {
            assert_eq!(x.len(), y.len(), "{at}: lengths");
            for (i, (x, y)) in x.iter().zip(y).enumerate() {
                assert_close(x, y, tolerance, &format!("{at}[{i}]"));
            }
        }
        (Value::Object(x), Value::Object(y)) => {
            assert_eq!(x.keys().collect::<Vec<_>>(), y.keys().collect::<Vec<_>>(), "{at}: keys");
            for (k, x) in x {
                assert_close(x, &y[k], tolerance, &format!("{at}.{k}"));
            }
        }
        _ => assert_eq!(a, b, "{at}"),
    }
}

#[test]
fn bop_layout_gives_the_same_stats_as_the_native_one() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let mut native = stats_of(path_str(tiny()), &tmp.path().join("native"), &[]);
    let mut from_bop = stats_of(path_str(bop()), &tmp.path().join("bop"), &[]);
    for name in FIGURES {
        assert_valid_png(&tmp.path().join("bop").join(name));
    }
    assert_eq!(native["layout"], "native");
    assert_eq!(from_bop["layout"], "bop");
    native["layout"] = Value::Null;
    from_bop["layout"] = Value::Null;
    // BOP's files carry no grasp type: unavailable there rather than invented.
    assert!(from_bop["grasp_types"].is_null() && !native["grasp_types"].is_null());
    native["grasp_types"] = Value::Null;
    // Counts exactly; poses went through millimetres, so their statistics agree to a micrometre.
    assert_close(&native, &from_bop, 1e-5, "stats");

    // And the BOP files themselves hold that many images and those occlusions.
    let mut images = 0;
    let mut occlusion = [0u64; 10];
    for split in ["train", "val", "test"] {
        let Ok(scenes) = std::fs::read_dir(bop().join(split)) else { continue };
        for scene in scenes {
            let meta = read_json(&scene.expect("scene").path().join("scene_meta.json"));
            for image in meta.as_object().expect("images").values() {
                images += 1;
                occlusion[occlusion_bin(image["occlusion"].as_f64().expect("occlusion"))] += 1;
            }
        }
    }
    assert_eq!(from_bop["counts"]["samples"].as_u64(), Some(images));
    assert_eq!(counts(&from_bop["occlusion"]["counts"]), occlusion.to_vec());
}

#[test]
fn a_job_id_gives_the_stats_of_its_exported_dataset() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let state: PathBuf = tiny().with_file_name("state");
    let port = free_port();
    let database = format!("sqlite://{}", state.join("vint.db").display());
    let objects = format!("file://{}", state.canonicalize().expect("state dir").join("objects").display());
    let _coordinator = start_coordinator_with_store(&database, port, &tmp.path().join("logs"), "c", Some(&objects));
    let at = format!("127.0.0.1:{port}");
    let jobs = vintctl(&["--coordinator", &at, "jobs", "--json"]);
    assert!(jobs.status.success(), "{}", stderr(&jobs));
    let jobs: Value = serde_json::from_str(&stdout(&jobs)).expect("jobs JSON");
    let job = jobs[0]["job_id"].as_str().expect("tiny's job").to_string();

    let from_job = stats_of(&job, &tmp.path().join("job"), &["--coordinator", &at]);
    let from_dir = stats_of(path_str(tiny()), &tmp.path().join("dir"), &[]);
    assert_eq!(from_job, from_dir);
    for name in FIGURES {
        let job_png = std::fs::read(tmp.path().join("job").join(name)).expect("figure");
        assert_eq!(job_png, std::fs::read(tmp.path().join("dir").join(name)).expect("figure"), "{name}");
    }
    let leftovers: Vec<_> = std::fs::read_dir(std::env::temp_dir())
        .expect("temp dir")
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|n| n.contains(&format!("vint-stats-{job}")))
        .collect();
    assert!(leftovers.is_empty(), "the job's exported copy is removed: {leftovers:?}");
}

#[test]
fn a_directory_that_is_no_dataset_is_bad_input() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let run = vintctl(&["stats", path_str(tmp.path()), "--out", path_str(&tmp.path().join("out")), "--json"]);
    assert_eq!(run.status.code(), Some(2), "{}", stderr(&run));
    let error: Value = serde_json::from_str(stdout(&run).trim()).expect("error JSON");
    assert_eq!(error["error"]["code"], 2);
    assert!(error["error"]["message"].as_str().unwrap_or_default().contains("neither a native dataset"), "{error}");
}
