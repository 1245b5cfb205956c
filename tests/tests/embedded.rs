//! `vintctl run` on the embedded default, as a researcher uses it.

use std::collections::BTreeMap;
use std::path::Path;

use sha2::{Digest, Sha256};
use vint_tests::*;

#[test]
fn tiny_spec_produces_verified_samples_identical_for_any_worker_count_and_engine_reuse() {
    let tmp = tempfile::tempdir().unwrap();
    let mut hashes = Vec::new();
    // One worker keeps its engines warm for the whole job; three workers replace every engine
    // process after two tasks: a warm engine's cached scene must not change a single byte.
    for (workers, max_tasks) in [(1, "0"), (3, "2")] {
        let dir = tmp.path().join(format!("w{workers}"));
        let o = run_tiny_with_env(&dir, workers, &[("VINT_ENGINE_MAX_TASKS".into(), max_tasks.into())]);
        assert!(o.status.success(), "vintctl run failed:\n{}\n{}", stdout(&o), stderr(&o));
        let lines = verify_dataset(&dir.join("out"));
        assert!(!lines.is_empty(), "no samples");
        for line in &lines {
            let files: Vec<&str> = line["files"].as_object().unwrap().keys().map(String::as_str).collect();
            assert_eq!(
                files,
                [
                    "depth.png",
                    "depth_noisy.png",
                    "mask.png",
                    "mask_full.png",
                    "meta.json",
                    "rgb.png",
                    "segmentation.png"
                ]
            );
            let sample = line["sample_id"].as_str().unwrap();
            let meta: serde_json::Value =
                serde_json::from_slice(&std::fs::read(dir.join("out").join(sample).join("meta.json")).unwrap())
                    .unwrap();
            assert_eq!(meta["sample_id"], sample);
            assert_eq!(meta["camera"]["K"].as_array().unwrap().len(), 3);
            assert!(meta["poses"]["object"]["p"].as_array().unwrap().iter().all(|x| x.as_f64().unwrap().is_finite()));
            let record = grasp_record(&dir.join("out"), sample);
            assert_eq!(record["trial"]["object_pose"], meta["poses"]["object"], "{sample}: one pose, two places");
            assert!(!record["trial"]["link_poses"].as_object().unwrap().is_empty());
            assert!(!record["trial"]["joints"].as_object().unwrap().is_empty());
            // Touch only at contact: every active taxel sits on a link MuJoCo reports in contact
            // with the object (the trial's contacts, recorded apart from the touch read-out),
            // within the skin's 0.5 mm contact margin.
            let touching: std::collections::BTreeSet<&str> = record["trial"]["contacts"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|c| c["force"].as_f64().unwrap() > 0.0)
                .map(|c| c["link"].as_str().unwrap())
                .collect();
            for taxel in record["touch"]["active"].as_array().unwrap() {
                let link = taxel["link"].as_str().unwrap();
                assert!(touching.contains(link), "{sample}: taxel {} on {link}, not in contact", taxel["taxel"]);
                assert!(taxel["distance_m"].as_f64().unwrap() <= 5e-4 + 1e-9, "{sample}: {taxel}");
                assert!(taxel["reading"].as_f64().unwrap() > 0.0, "{sample}: {taxel}");
            }
            let readings = record["touch"]["readings"].as_array().unwrap();
            let active = readings.iter().filter(|r| r.as_f64().unwrap() > 0.0).count() as u64;
            assert_eq!(record["touch"]["active_count"].as_u64(), Some(active), "{sample}");
            let occlusion = meta["visibility"]["occlusion"].as_f64().unwrap();
            assert!((0.0..=1.0).contains(&occlusion), "{sample}: occlusion {occlusion}");
            let view: usize = sample.rsplit_once(".v").unwrap().1.parse().unwrap();
            let environment = if view < 3 { "studio" } else { "forest" };
            assert_eq!(meta["camera"]["environment"]["name"], environment, "{sample}");
        }
        // The Allegro spreads its fingers: its index (f0_j0), ring (f2_j0) and thumb (f3_j1)
        // abduction joints take different angles from grasp to grasp (the audit found them fixed).
        let mut abduction: BTreeMap<&str, Vec<f64>> = BTreeMap::new();
        let mut seen = std::collections::BTreeSet::new();
        for line in &lines {
            let sample = line["sample_id"].as_str().unwrap();
            let grasp = sample.rsplit_once(".v").unwrap().0;
            if !grasp.contains(".allegro.") || !seen.insert(grasp.to_string()) {
                continue;
            }
            let record = grasp_record(&dir.join("out"), sample);
            for joint in ["f0_j0", "f2_j0", "f3_j1"] {
                abduction.entry(joint).or_default().push(record["trial"]["joints"][joint].as_f64().unwrap());
            }
        }
        for (joint, angles) in &abduction {
            let mean = angles.iter().sum::<f64>() / angles.len() as f64;
            let std = (angles.iter().map(|a| (a - mean).powi(2)).sum::<f64>() / angles.len() as f64).sqrt();
            // Power grasps keep about a third of the Allegro's six tiny trials: two grasps here.
            assert!(angles.len() >= 2 && std > 0.05, "allegro {joint} hardly moves: {angles:?}");
        }
        // Every accepted grasp is seen from 3 views in each of 2 environments.
        let mut views_per_grasp = std::collections::BTreeMap::<String, usize>::new();
        for line in &lines {
            let sample = line["sample_id"].as_str().unwrap();
            *views_per_grasp.entry(sample.rsplit_once(".v").unwrap().0.to_string()).or_default() += 1;
        }
        assert!(views_per_grasp.values().all(|&n| n == 6), "{views_per_grasp:?}");
        // Object orientations spread over the sphere in camera space: the camera's roll turns the
        // object every way in the image, and grasps from every side at a random object orientation
        // point its axis into every octant (before both, its axis stayed within about 30° of
        // image up and never pointed away from the camera over tiny).
        let coverage = OrientationCoverage::of(&lines, &dir.join("out"));
        eprintln!("object orientation in camera space over tiny: {coverage:?}");
        assert!(coverage.sectors_hit() >= 9, "the object's axis points only a few ways in the images: {coverage:?}");
        assert!(coverage.octants_hit() >= 7, "the object's axis misses octants of the sphere: {coverage:?}");
        let summary: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("--json summary");
        assert_eq!(summary["manifest_sha256"], manifest_sha256(&dir.join("out")));
        hashes.push(manifest_sha256(&dir.join("out")));
    }
    assert_eq!(hashes[0], hashes[1], "1 warm and 3 recycling workers must produce the same dataset");
}

/// The jobs a `vintctl run` state directory holds, and the attempts each of their tasks has had.
async fn jobs_and_attempts(state: &Path) -> (Vec<String>, BTreeMap<String, u32>) {
    let url = format!("sqlite://{}", state.join("vint.db").display());
    let store = vint_store::Store::open(&url, vint_store::RetryPolicy::default()).await.unwrap();
    let jobs: Vec<String> = store.list_jobs(100).await.unwrap().into_iter().map(|j| j.id).collect();
    let mut attempts = BTreeMap::new();
    for job in &jobs {
        for task in store.tasks_of_job(job).await.unwrap() {
            attempts.insert(task.id.clone(), store.attempt_count(&task.id).await.unwrap());
        }
    }
    store.close().await;
    (jobs, attempts)
}

#[tokio::test(flavor = "multi_thread")]
async fn rerunning_a_spec_with_its_state_resumes_the_same_job() {
    let tmp = tempfile::tempdir().unwrap();
    let state = tmp.path().join("state");
    let first = run_tiny(tmp.path(), 2);
    assert!(first.status.success(), "{}", stderr(&first));
    let hash = manifest_sha256(&tmp.path().join("out"));
    let (jobs, attempts) = jobs_and_attempts(&state).await;
    assert_eq!(jobs.len(), 1, "{jobs:?}");
    assert!(!attempts.is_empty() && attempts.values().all(|&n| n >= 1), "every task ran: {attempts:?}");

    let again = run_tiny(tmp.path(), 2);
    assert!(again.status.success(), "{}", stderr(&again));
    assert_eq!(manifest_sha256(&tmp.path().join("out")), hash);
    // A fresh run would pass the check above too: reuse means the same job and not one new attempt.
    let (jobs_after, attempts_after) = jobs_and_attempts(&state).await;
    assert_eq!(jobs_after, jobs, "the re-run must resume the job, not submit another");
    assert_eq!(attempts_after, attempts, "the re-run must not run a finished task again");
}

#[test]
fn an_invalid_spec_exits_2_and_writes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let spec = tmp.path().join("bad.toml");
    let text =
        std::fs::read_to_string(tiny_spec()).unwrap().replace("resolution = [128, 128]", "resolution = [0, 128]");
    std::fs::write(&spec, text).unwrap();
    let out = tmp.path().join("out");
    let state = tmp.path().join("state");
    let o =
        vintctl(&["run", spec.to_str().unwrap(), "--out", out.to_str().unwrap(), "--state", state.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("render.resolution[0]: must be 16..=8192, got 0"), "{}", stderr(&o));
    assert!(!out.exists() && !state.exists(), "nothing may be written for an invalid spec");

    let v = vintctl(&["validate", spec.to_str().unwrap(), "--json"]);
    assert_eq!(v.status.code(), Some(2));
    let report: serde_json::Value = serde_json::from_str(&stdout(&v)).unwrap();
    assert_eq!(report["valid"], false);
    assert_eq!(report["errors"][0]["path"], "render.resolution[0]");

    let ok = vintctl(&["validate", tiny_spec().to_str().unwrap()]);
    assert!(ok.status.success(), "{}", stderr(&ok));
}

#[test]
fn a_missing_spec_file_is_bad_input() {
    let o = vintctl(&["validate", "/nonexistent/spec.toml"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("/nonexistent/spec.toml"));
}

#[test]
fn an_existing_unrelated_output_directory_is_not_replaced() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("precious");
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("thesis.tex"), "do not delete").unwrap();
    let state = tmp.path().join("state");
    let o = vintctl(&[
        "run",
        tiny_spec().to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--state",
        state.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(out.join("thesis.tex").exists());
}

#[test]
fn hands_lists_dof_and_taxels_per_region() {
    let o = vintctl(&["hands", "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let hands: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let allegro = hands.as_array().unwrap().iter().find(|h| h["name"] == "allegro").expect("allegro listed");
    assert_eq!(allegro["dof"], 16);
    let regions = allegro["taxels_per_region"].as_object().unwrap();
    let total: u64 = regions.values().map(|v| v.as_u64().unwrap()).sum();
    assert_eq!(total, 679);
    assert_eq!(regions.keys().map(String::as_str).collect::<Vec<_>>(), ["palm", "pulp", "tip"]);
}

#[test]
fn grasp_study_writes_csv_plot_and_table() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("study");
    let o = vintctl(&["study", "grasp", "--out", out.to_str().unwrap(), "--quick"]);
    assert!(o.status.success(), "{}\n{}", stdout(&o), stderr(&o));
    for f in ["grasp_study.csv", "grasp_study_summary.csv", "grasp_study.png", "grasp_study.md"] {
        assert!(out.join(f).metadata().map(|m| m.len() > 0).unwrap_or(false), "{f} missing");
    }
    let bad = vintctl(&["study", "paint", "--out", out.to_str().unwrap()]);
    assert_eq!(bad.status.code(), Some(2));
}

#[test]
fn render_study_writes_csv_plot_and_table_with_exact_labels() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("study");
    // Exit 0 also says that depth, masks and segmentation equal the reference at every setting.
    let o = vintctl(&["study", "render", "--out", out.to_str().unwrap(), "--quick"]);
    assert!(o.status.success(), "{}\n{}", stdout(&o), stderr(&o));
    for f in ["render_study.csv", "render_study_summary.csv", "render_study.png", "render_study.md"] {
        assert!(out.join(f).metadata().map(|m| m.len() > 0).unwrap_or(false), "{f} missing");
    }
    let summary = std::fs::read_to_string(out.join("render_study_summary.csv")).unwrap();
    let psnr = |config: &str| -> f64 {
        let header: Vec<&str> = summary.lines().next().unwrap().split(',').collect();
        let column = header.iter().position(|h| *h == "median_psnr_db").unwrap();
        let line = summary.lines().find(|l| l.starts_with(&format!("{config},"))).unwrap();
        line.split(',').nth(column).unwrap().parse().unwrap()
    };
    assert!(psnr("16spp") > psnr("4spp"), "more samples must come closer to the reference:\n{summary}");
}

/// `examples/custom.toml`: a user's MJCF hand with its taxel layout, a user's mesh object and a
/// user's HDRI, next to a built-in hand, object and HDRI.
fn custom_spec() -> std::path::PathBuf {
    repo_root().join("examples").join("custom.toml")
}

#[tokio::test(flavor = "multi_thread")]
async fn a_spec_with_its_own_hand_mesh_object_and_hdri_runs_end_to_end_with_touch() {
    let tmp = tempfile::tempdir().unwrap();
    let (out, state) = (tmp.path().join("out"), tmp.path().join("state"));
    let spec = custom_spec();
    let (spec, out_arg, state_arg) = (spec.to_str().unwrap(), out.to_str().unwrap(), state.to_str().unwrap());
    let o = vintctl(&["--json", "run", spec, "--out", out_arg, "--state", state_arg]);
    assert!(o.status.success(), "vintctl run failed:\n{}\n{}", stdout(&o), stderr(&o));
    let lines = verify_dataset(&out);
    let samples: Vec<&str> = lines.iter().map(|l| l["sample_id"].as_str().unwrap()).collect();
    for pair in ["cup.gripper.", "cup.trx3.", "tomato_soup_can.gripper."] {
        assert!(samples.iter().any(|s| s.starts_with(pair)), "no accepted grasp for {pair}: {samples:?}");
    }
    let file_sha = |name: &str| {
        hex::encode(Sha256::digest(std::fs::read(repo_root().join("examples/assets").join(name)).unwrap()))
    };
    let (cup_sha, lab_sha) = (file_sha("cup.obj"), file_sha("lab.hdr"));
    for sample in samples.iter().filter(|s| s.starts_with("cup.gripper.")) {
        let record = grasp_record(&out, sample);
        assert!(record["touch"]["active_count"].as_u64().unwrap() >= 3, "{sample}: no touch");
        assert_eq!(record["object"]["shape"]["asset"], cup_sha.as_str(), "{sample}: the mesh is named by its hash");
        let links = record["trial"]["link_poses"].as_object().unwrap();
        assert!(links.contains_key("left_tip") && links.contains_key("palm"), "{sample}: {links:?}");
    }
    // View 1 of every grasp is lit by the user's HDRI, named by its hash.
    let lit = samples.iter().filter(|s| s.ends_with(".v01")).collect::<Vec<_>>();
    assert!(!lit.is_empty(), "{samples:?}");
    for sample in lit {
        let meta: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join(sample).join("meta.json")).unwrap()).unwrap();
        let environment = &meta["camera"]["environment"];
        assert_eq!(environment["name"], "lab", "{sample}");
        assert_eq!(environment["asset"], lab_sha.as_str(), "{sample}");
        assert_eq!((environment["rotation_deg"].as_f64(), environment["strength"].as_f64()), (Some(45.0), Some(1.5)));
    }

    // Lineage: the grasp task's parameters name the user files, which show as its inputs.
    let url = format!("sqlite://{}", state.join("vint.db").display());
    let store = vint_store::Store::open(&url, vint_store::RetryPolicy::default()).await.unwrap();
    let job = &store.list_jobs(1).await.unwrap()[0];
    let grasp = format!("{}/grasp/cup/gripper/c00000", job.id);
    let chain = store.lineage(&grasp).await.unwrap();
    let inputs: Vec<&str> = chain[0].inputs.iter().map(|a| a.name.as_str()).collect();
    assert_eq!(inputs, ["assets/cup.obj", "assets/gripper.xml", "assets/gripper_taxels.csv"]);
    assert!(chain[0].task.params_json.contains(&cup_sha));
    // A render task names the HDRI, which shows as its input; the grasp task does not.
    let render = format!("{}/render/{}", job.id, samples[0].rsplit_once('.').unwrap().0.replace('.', "/"));
    let chain = store.lineage(&render).await.unwrap();
    let inputs: Vec<&str> = chain[0].inputs.iter().map(|a| a.name.as_str()).collect();
    assert!(inputs.contains(&"assets/lab.hdr"), "{render}: {inputs:?}");
    assert!(chain.iter().filter(|e| e.task.key.starts_with("grasp/")).all(|e| !e.task.params_json.contains(&lab_sha)));
    store.close().await;
}

#[test]
fn a_spec_naming_a_missing_file_exits_2_and_submits_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let spec = tmp.path().join("custom.toml");
    std::fs::copy(custom_spec(), &spec).unwrap(); // without its assets directory
    let (out, state) = (tmp.path().join("out"), tmp.path().join("state"));
    let o =
        vintctl(&["run", spec.to_str().unwrap(), "--out", out.to_str().unwrap(), "--state", state.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    for field in ["hand.gripper.mjcf", "hand.gripper.taxels", "object.cup.mesh", "render.environments[1].file"] {
        assert!(stderr(&o).contains(&format!("{field}: must name a readable file")), "{}", stderr(&o));
    }
    assert!(stderr(&o).contains("got \"assets/cup.obj\""), "{}", stderr(&o));
    assert!(!out.exists() && !state.exists(), "nothing may be written or submitted");
    let v = vintctl(&["validate", spec.to_str().unwrap()]);
    assert_eq!(v.status.code(), Some(2));
}

#[test]
fn a_user_hdri_must_be_a_readable_hdr_or_exr_file_next_to_the_spec() {
    let tmp = tempfile::tempdir().unwrap();
    let spec = tmp.path().join("spec.toml");
    let tiny = std::fs::read_to_string(tiny_spec()).unwrap();
    let forest = "{ name = \"forest\", rotation_deg = 0.0, strength = 1.2 }";
    assert!(tiny.contains(forest));
    let validate = |entry: &str| {
        std::fs::write(&spec, tiny.replace(forest, entry)).unwrap();
        vintctl(&["validate", spec.to_str().unwrap()])
    };
    let missing = validate("{ name = \"lab\", file = \"hdri/lab.hdr\" }");
    assert_eq!(missing.status.code(), Some(2), "{}", stderr(&missing));
    assert!(
        stderr(&missing).contains("render.environments[1].file: must name a readable file")
            && stderr(&missing).contains("got \"hdri/lab.hdr\""),
        "{}",
        stderr(&missing)
    );
    std::fs::create_dir(tmp.path().join("hdri")).unwrap();
    std::fs::copy(repo_root().join("examples/assets/lab.hdr"), tmp.path().join("hdri/lab.hdr")).unwrap();
    let present = validate("{ name = \"lab\", file = \"hdri/lab.hdr\" }");
    assert!(present.status.success(), "{}", stderr(&present));
    let png = validate("{ name = \"lab\", file = \"hdri/lab.png\" }");
    assert_eq!(png.status.code(), Some(2));
    assert!(stderr(&png).contains("render.environments[1].file: must name a .hdr, .exr file"), "{}", stderr(&png));
    let shadow = validate("{ name = \"forest\", file = \"hdri/lab.hdr\" }");
    assert_eq!(shadow.status.code(), Some(2));
    assert!(stderr(&shadow).contains("must not reuse the name of a bundled HDRI"), "{}", stderr(&shadow));
}

/// The grasps a dataset holds, per (object, hand): `object.hand` → grasp indices.
fn grasps_by_pair(lines: &[serde_json::Value]) -> BTreeMap<String, std::collections::BTreeSet<u32>> {
    let mut out: BTreeMap<String, std::collections::BTreeSet<u32>> = BTreeMap::new();
    for line in lines {
        let grasp = line["sample_id"].as_str().unwrap().rsplit_once(".v").unwrap().0;
        let (pair, index) = grasp.rsplit_once(".g").unwrap();
        out.entry(pair.to_string()).or_default().insert(index.parse().unwrap());
    }
    out
}

#[test]
fn a_quota_keeps_the_first_accepted_grasps_of_the_same_trials() {
    let tmp = tempfile::tempdir().unwrap();
    let spec = |quota: &str| {
        format!(
            "hands = [\"trx3\", \"allegro\"]\nobjects = [\"tomato_soup_can\"]\n[dataset]\nname = \"quota\"\nseed = 11\n\
             [grasp]\ntrials_per_pair = 4\nchunk_size = 2\nhold_s = 0.3\n{quota}\n\
             [render]\nresolution = [16, 16]\nviews_per_environment = 1\nenvironments = [\"studio\"]\n\
             [outputs]\nmodalities = [\"depth\", \"pose\"]\n"
        )
    };
    let mut datasets = Vec::new();
    for (name, quota) in [("all", ""), ("quota", "accepted_per_pair = 1")] {
        let dir = tmp.path().join(name);
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("spec.toml");
        std::fs::write(&path, spec(quota)).unwrap();
        let (out, state) = (dir.join("out"), dir.join("state"));
        let o = vintctl(&[
            "--json",
            "run",
            path.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--state",
            state.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{name}: vintctl run failed:\n{}\n{}", stdout(&o), stderr(&o));
        datasets.push(grasps_by_pair(&verify_dataset(&out)));
    }
    let (all, quota) = (&datasets[0], &datasets[1]);
    assert!(!all.is_empty(), "no pair accepted any of its 4 trials");
    // The same seeds run the same trials: with a quota of one, each pair keeps exactly the first
    // grasp the unlimited run accepted, and runs nothing past it.
    for (pair, grasps) in all {
        let first = grasps.iter().next().copied();
        assert_eq!(
            quota.get(pair).map(|g| g.iter().copied().collect::<Vec<_>>()),
            Some(first.into_iter().collect()),
            "{pair}"
        );
    }
    assert_eq!(quota.keys().collect::<Vec<_>>(), all.keys().collect::<Vec<_>>());

    // `vintctl plan` predicted the quota run's database, table by table: exactly when every pair
    // filled its quota (the plan's counts are then exact), never fewer rows otherwise.
    let dir = tmp.path().join("quota");
    let o = vintctl(&["--json", "plan", dir.join("spec.toml").to_str().unwrap()]);
    assert!(o.status.success(), "{}\n{}", stdout(&o), stderr(&o));
    let plan: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(plan["exact"], true);
    let written = tokio::runtime::Runtime::new().unwrap().block_on(async {
        let url = format!("sqlite://{}", dir.join("state/vint.db").display());
        let store = vint_store::Store::open(&url, vint_store::RetryPolicy::default()).await.unwrap();
        let rows = store.table_rows().await.unwrap();
        store.close().await;
        rows
    });
    let planned: Vec<u64> =
        plan["database"]["tables"].as_array().unwrap().iter().map(|t| t["rows"].as_u64().unwrap()).collect();
    if quota.len() as u64 == plan["counts"]["pairs"].as_u64().unwrap() {
        assert_eq!(planned, written.counts(), "every pair filled its quota: the plan is exact");
    } else {
        assert!(planned.iter().zip(written.counts()).all(|(p, w)| *p >= w), "{planned:?} < {written:?}");
    }
}

#[test]
fn a_textured_mesh_must_list_the_files_it_refers_to_and_fit_the_face_limit() {
    let tmp = tempfile::tempdir().unwrap();
    let spec = tmp.path().join("spec.toml");
    std::fs::create_dir(tmp.path().join("assets")).unwrap();
    let cube = "mtllib box.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
    std::fs::write(tmp.path().join("assets/box.obj"), cube).unwrap();
    std::fs::write(tmp.path().join("assets/box.mtl"), "newmtl m\nmap_Kd tex/box.png\n").unwrap();
    std::fs::create_dir(tmp.path().join("assets/tex")).unwrap();
    std::fs::write(tmp.path().join("assets/tex/box.png"), b"\x89PNG").unwrap();
    let big =
        "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nelement face 600000\nend_header\n";
    std::fs::write(tmp.path().join("assets/big.ply"), big).unwrap();
    let tiny = std::fs::read_to_string(tiny_spec()).unwrap();
    let validate = |mesh: &str, files: &str| {
        let table = format!(
            "\n[object.box]\nmesh = \"{mesh}\"\nfiles = {files}\nunit = \"mm\"\nmass_kg = 0.1\nmaterial = \"cardboard\"\n"
        );
        std::fs::write(&spec, tiny.replacen("objects = [", "objects = [\"box\", ", 1) + &table).unwrap();
        vintctl(&["validate", spec.to_str().unwrap()])
    };
    let ok = validate("assets/box.obj", "[\"assets/box.mtl\", \"assets/tex/box.png\"]");
    assert_eq!(ok.status.code(), Some(0), "{}", stderr(&ok));
    let unlisted = validate("assets/box.obj", "[\"assets/box.mtl\"]");
    assert_eq!(unlisted.status.code(), Some(2), "{}", stderr(&unlisted));
    assert!(
        stderr(&unlisted).contains(
            "object.box.files: must list every file the mesh refers to: assets/box.mtl names \"tex/box.png\""
        ),
        "{}",
        stderr(&unlisted)
    );
    let big = validate("assets/big.ply", "[]");
    assert_eq!(big.status.code(), Some(2), "{}", stderr(&big));
    assert!(
        stderr(&big)
            .contains("object.box.mesh: must have at most 500000 triangles, got \"assets/big.ply\" (600000 triangles)"),
        "{}",
        stderr(&big)
    );
}

#[test]
fn a_bop_models_object_keeps_its_obj_id_and_symmetries_in_the_native_and_bop_layouts() {
    let tmp = tempfile::tempdir().unwrap();
    std::fs::create_dir(tmp.path().join("models")).unwrap();
    for name in ["box.obj", "box.mtl", "box.png"] {
        std::fs::copy(repo_root().join("examples/assets").join(name), tmp.path().join("models").join(name)).unwrap();
    }
    let turn = "[-1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]";
    let spec = tmp.path().join("spec.toml");
    std::fs::write(
        &spec,
        format!(
            "hands = [\"trx3\"]\nobjects = [\"carton\", \"tomato_soup_can\"]\n\
             [object.carton]\nmesh = \"models/box.obj\"\nfiles = [\"models/box.mtl\", \"models/box.png\"]\n\
             unit = \"mm\"\nmass_kg = 0.12\nmaterial = \"cardboard\"\nobj_id = 7\nsymmetries_discrete = [{turn}]\n\
             [dataset]\nname = \"bop_ids\"\nseed = 5\n[grasp]\ntrials_per_pair = 4\nchunk_size = 4\nhold_s = 0.5\n\
             [render]\nresolution = [64, 64]\nsamples = 4\nviews_per_environment = 1\nenvironments = [\"studio\"]\n\
             [outputs]\nmodalities = [\"depth\", \"mask\", \"pose\"]\n"
        ),
    )
    .unwrap();
    let (out, state) = (tmp.path().join("out"), tmp.path().join("state"));
    let run =
        vintctl(&["run", spec.to_str().unwrap(), "--out", out.to_str().unwrap(), "--state", state.to_str().unwrap()]);
    assert_eq!(run.status.code(), Some(0), "{}", stderr(&run));
    let dataset: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("dataset.json")).unwrap()).unwrap();
    let objects = dataset["objects"].as_array().unwrap();
    let carton = objects.iter().find(|o| o["name"] == "carton").unwrap();
    assert_eq!((carton["obj_id"].as_u64(), carton["model_source"].as_str()), (Some(7), Some("bop")), "{carton}");
    assert_eq!(carton["symmetries_discrete"], serde_json::from_str::<serde_json::Value>(&format!("[{turn}]")).unwrap());
    let soup = objects.iter().find(|o| o["name"] == "tomato_soup_can").unwrap();
    assert_eq!(soup["obj_id"].as_u64(), catalog_obj_id("tomato_soup_can"));

    let bop = tmp.path().join("bop");
    let convert = vintctl(&["convert", out.to_str().unwrap(), "--out", bop.to_str().unwrap(), "--format", "bop"]);
    assert_eq!(convert.status.code(), Some(0), "{}", stderr(&convert));
    let mut ids = std::collections::BTreeSet::new();
    let mut info_keys = Vec::new();
    for entry in walk(&bop) {
        let name = entry.file_name().unwrap().to_string_lossy().to_string();
        if name == "scene_gt.json" {
            let gt: BTreeMap<String, Vec<serde_json::Value>> =
                serde_json::from_str(&std::fs::read_to_string(&entry).unwrap()).unwrap();
            ids.extend(gt.values().flatten().filter_map(|g| g["obj_id"].as_u64()));
        } else if name == "models_info.json" {
            let info: BTreeMap<String, serde_json::Value> =
                serde_json::from_str(&std::fs::read_to_string(&entry).unwrap()).unwrap();
            info_keys.extend(info.into_keys());
        }
    }
    assert!(ids.contains(&7), "scene_gt obj_ids {ids:?}");
    assert!(info_keys.contains(&"7".to_string()), "models_info keys {info_keys:?}");
}

fn catalog_obj_id(name: &str) -> Option<u64> {
    vint_core::catalog::obj_id(name).map(u64::from)
}

fn walk(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap().flatten() {
        let path = entry.path();
        if path.is_dir() { out.extend(walk(&path)) } else { out.push(path) }
    }
    out
}

#[test]
fn a_bop_models_object_keeps_its_files_frame_in_the_bop_layout() {
    // A box whose file origin is a corner-ish point far from its bounding-box centre (40, 35, 15) mm.
    let tmp = tempfile::tempdir().unwrap();
    let (lo, hi) = ([0.0, 10.0, 0.0], [80.0, 60.0, 30.0]);
    let corners: Vec<[f64; 3]> =
        (0..8).map(|i| [0, 1, 2].map(|k| if i & (1 << k) == 0 { lo[k] } else { hi[k] })).collect();
    let mut obj = String::from("# a box off its origin, millimetres\n");
    for c in &corners {
        obj += &format!("v {} {} {}\n", c[0], c[1], c[2]);
    }
    // Outward triangles (OBJ counts from 1; vertex i has bit k set when at hi[k]).
    for f in [[1, 3, 4, 2], [5, 6, 8, 7], [1, 2, 6, 5], [3, 7, 8, 4], [1, 5, 7, 3], [2, 4, 8, 6]] {
        obj += &format!("f {} {} {}\nf {} {} {}\n", f[0], f[1], f[2], f[0], f[2], f[3]);
    }
    std::fs::create_dir(tmp.path().join("models")).unwrap();
    std::fs::write(tmp.path().join("models/offset_box.obj"), obj).unwrap();
    // A half turn about the vertical axis through the box's centre, in the file's frame (metres).
    let turn = "[-1.0, 0.0, 0.0, 0.08, 0.0, -1.0, 0.0, 0.07, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]";
    let spec = tmp.path().join("spec.toml");
    std::fs::write(
        &spec,
        format!(
            "hands = [\"trx3\"]\nobjects = [\"offset_box\"]\n\
             [object.offset_box]\nmesh = \"models/offset_box.obj\"\n\
             unit = \"mm\"\nmass_kg = 0.12\nmaterial = \"cardboard\"\nobj_id = 9\nsymmetries_discrete = [{turn}]\n\
             [dataset]\nname = \"bop_frame\"\nseed = 5\n[grasp]\ntrials_per_pair = 4\nchunk_size = 4\nhold_s = 0.5\n\
             [render]\nresolution = [64, 64]\nsamples = 4\nviews_per_environment = 2\nenvironments = [\"studio\"]\n\
             [outputs]\nmodalities = [\"depth\", \"mask\", \"pose\"]\n"
        ),
    )
    .unwrap();
    let (out, state) = (tmp.path().join("out"), tmp.path().join("state"));
    let run =
        vintctl(&["run", spec.to_str().unwrap(), "--out", out.to_str().unwrap(), "--state", state.to_str().unwrap()]);
    assert_eq!(run.status.code(), Some(0), "{}", stderr(&run));

    // The native layout stays in the object frame (bounding-box centre) and names the file's.
    let dataset: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("dataset.json")).unwrap()).unwrap();
    let native = &dataset["objects"][0];
    assert_eq!(native["file_offset_mm"], serde_json::json!([40.0, 35.0, 15.0]), "{native}");
    let centred_turn = [-1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0];
    assert_eq!(native["symmetries_discrete"], serde_json::json!([centred_turn]), "{native}");

    let bop = tmp.path().join("bop");
    let convert = vintctl(&["convert", out.to_str().unwrap(), "--out", bop.to_str().unwrap(), "--format", "bop"]);
    assert_eq!(convert.status.code(), Some(0), "{}", stderr(&convert));
    // The BOP model is the file's box, vertex for vertex (float32 mm), not the centred one.
    let mut shipped = ply_vertices_mm(&std::fs::read(bop.join("models/obj_000009.ply")).unwrap());
    let mut original = corners.clone();
    for list in [&mut shipped, &mut original] {
        list.sort_by(|a, b| a.partial_cmp(b).unwrap());
    }
    assert_eq!(shipped.len(), original.len(), "{shipped:?}");
    for (s, o) in shipped.iter().zip(&original) {
        assert!(s.iter().zip(o).all(|(a, b)| (a - b).abs() < 1e-3), "shipped {shipped:?}, file {original:?}");
    }
    let info: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(bop.join("models/models_info.json")).unwrap()).unwrap();
    let entry = &info["9"];
    let mins = ["min_x", "min_y", "min_z"].map(|k| entry[k].as_f64().unwrap());
    assert!(mins.iter().zip(lo).all(|(m, l)| (m - l).abs() < 1e-3), "{entry}");
    let in_mm = [-1.0, 0.0, 0.0, 80.0, 0.0, -1.0, 0.0, 70.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0];
    assert_eq!(entry["symmetries_discrete"], serde_json::json!([in_mm]), "{entry}");
    // Poses and model agree in the file's frame: the independent re-projection of the shipped
    // model with scene_gt's poses matches the rendered depth and masks.
    let check = std::process::Command::new(python())
        .arg(repo_root().join("tests/python/check_bop.py"))
        .arg(&bop)
        .output()
        .unwrap();
    assert!(check.status.success(), "check_bop.py failed:\n{}\n{}", stdout(&check), stderr(&check));
    let summary: serde_json::Value = serde_json::from_str(&stdout(&check)).unwrap();
    assert!(summary["images"].as_u64().unwrap_or(0) > 0, "{summary}");
}

/// The vertices of a binary little-endian PLY whose vertex element (first) is float32 x y z and
/// then any other float32 properties (the BOP layout adds nx ny nz).
fn ply_vertices_mm(bytes: &[u8]) -> Vec<[f64; 3]> {
    let end = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    let header = std::str::from_utf8(&bytes[..end]).unwrap();
    let count: usize = header.lines().find_map(|l| l.strip_prefix("element vertex ")).unwrap().trim().parse().unwrap();
    let properties = header
        .lines()
        .skip_while(|l| !l.starts_with("element vertex "))
        .skip(1)
        .take_while(|l| l.starts_with("property "))
        .inspect(|l| assert!(l.starts_with("property float "), "{l}"))
        .count();
    let stride = 4 * properties;
    bytes[end..end + stride * count]
        .chunks_exact(stride)
        .map(|v| [0, 1, 2].map(|k| f64::from(f32::from_le_bytes(v[4 * k..4 * k + 4].try_into().unwrap()))))
        .collect()
}
