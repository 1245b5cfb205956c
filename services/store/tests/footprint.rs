//! `vint_store::footprint` against what the store writes: a job planned by the real planner
//! (`vint_core::plan`), run to the end by a test worker that completes every task with the files
//! its stage contract names (written out here, apart from the contract's own file counts), holds
//! exactly the rows `task_rows` predicts, table by table, on both backends.

#[macro_use]
mod common;

use common::*;
use vint_core::contract::{grasp, noise, package, render};
use vint_core::plan::{GraspChunk, JobPlan, after_grasp, initial_tasks};
use vint_core::sample::SampleId;
use vint_core::{DatasetSpec, JobState, Stage};
use vint_store::footprint::{TableRows, task_rows};
use vint_store::{LeasedTask, Store};

/// Two objects × one hand, 5 trials in chunks of 2 (3 chunks per pair: 2, 2 and 1 trials).
fn spec(modalities: &str) -> DatasetSpec {
    DatasetSpec::parse(&format!(
        "hands = [\"trx3\"]\nobjects = [\"tomato_soup_can\", \"mug\"]\n[dataset]\nname = \"f\"\nseed = 5\n\
         [grasp]\ntrials_per_pair = 5\nchunk_size = 2\n[render]\nviews_per_environment = 2\n\
         environments = [\"studio\", \"forest\"]\n[outputs]\nmodalities = {modalities}\n"
    ))
    .unwrap()
}

/// How many of a chunk's trials the test worker accepts: varied, and none for some chunks.
fn accepted_of(chunk: &GraspChunk, trials: std::ops::Range<u32>) -> Vec<u32> {
    let n = (chunk.chunk as usize + chunk.object.len()) % 3;
    trials.take(n).collect()
}

/// The files a task's stage contract says it writes, named as the engines and the package stage
/// name them, and the samples a package task makes.
fn outputs_of(plan: &JobPlan, t: &LeasedTask) -> (Vec<String>, Vec<String>) {
    let params: serde_json::Value = serde_json::from_str(&t.params_json).unwrap();
    let views = 0..plan.views_per_grasp();
    match t.stage {
        Stage::Grasp => (vec![grasp::GRASPS_FILE.into(), grasp::TOUCH_FILE.into(), grasp::MODEL_FILE.into()], vec![]),
        Stage::Render => {
            let files = render::view_files(&plan.render_outputs, plan.depth_format);
            (views.flat_map(|v| files.iter().map(move |f| f.name(v))).collect(), vec![])
        }
        Stage::Noise => (views.map(|v| noise::noisy_depth_file(v, plan.depth_format)).collect(), vec![]),
        Stage::Package => {
            let p: package::Params = serde_json::from_value(params).unwrap();
            let mut files = Vec::new();
            let mut grasps = std::collections::BTreeSet::new();
            for s in &p.samples {
                files.push(format!("{}/{}", s.sample_id, package::META_FILE));
                for m in &p.modalities {
                    files.extend(m.sample_files(p.depth_format).iter().map(|f| format!("{}/{}", s.sample_id, f.name)));
                }
                let id: SampleId = s.sample_id.parse().unwrap();
                grasps.insert(id.grasp().to_string());
            }
            files.extend(grasps.iter().map(|g| format!("{g}/{}", package::GRASP_RECORD_FILE)));
            (files, p.samples.iter().map(|s| s.sample_id.clone()).collect())
        }
    }
}

/// Runs `spec` to the end and returns the rows `footprint` predicted for it.
async fn run_to_the_end(store: &Store, spec: &DatasetSpec) -> TableRows {
    let plan = JobPlan::new(spec, &[]).unwrap();
    let mut new_job = job("j");
    new_job.plan_json = serde_json::to_string(&plan).unwrap();
    let initial = initial_tasks(spec, &[]).unwrap();
    let mut predicted = TableRows::submit(0) + task_rows(&initial).unwrap();
    store.submit_job(&new_job, &initial, 0).await.unwrap();
    for now in 1.. {
        let leased = store.lease("w", &Stage::ALL, 64, 60_000, now).await.unwrap();
        if leased.is_empty() {
            break;
        }
        // Keyed as the coordinator keys what a production worker leases (`vint_core::reuse`).
        let keys: Vec<(String, u32, String)> =
            leased.iter().map(|t| (t.id.clone(), t.attempt, format!("key of {}", t.id))).collect();
        store.set_content_keys(&keys).await.unwrap();
        for t in leased {
            let (files, samples) = outputs_of(&plan, &t);
            let mut c = completion(fence(&t, "w"), &files.iter().map(String::as_str).collect::<Vec<_>>());
            c.samples = samples;
            let mut children = Vec::new();
            if t.stage == Stage::Grasp {
                let chunk = GraspChunk::from_key(&t.key).unwrap();
                let accepted = accepted_of(&chunk, plan.trials(&chunk));
                children = after_grasp(&plan, &chunk, &accepted).unwrap();
                predicted += task_rows(&children).unwrap();
            }
            store.complete(&c, &children, now).await.unwrap();
        }
    }
    assert_eq!(store.job("j").await.unwrap().unwrap().state, JobState::Succeeded);
    predicted
}

store_test!(a_job_writes_the_rows_its_footprint_predicts_with_noisy_depth, |store: Store| async move {
    let spec = spec("[\"rgb\", \"depth\", \"depth_noisy\", \"mask\", \"segmentation\", \"pose\"]");
    let predicted = run_to_the_end(&store, &spec).await;
    assert!(predicted.output_files > 2 * predicted.outputs, "{predicted:?}");
    assert_eq!(store.table_rows().await.unwrap(), predicted);
    let samples = store.samples("j").await.unwrap();
    assert!(!samples.is_empty() && store.progress("j").await.unwrap().samples == samples.len() as u64);
    // The job's stored plan names each sample's package task: the one whose files hold it.
    for (sample, files) in &samples {
        let found = store.sample_package_task(None, sample).await.unwrap();
        let (job, task) = found.unwrap_or_else(|| panic!("{sample}: no package task"));
        assert_eq!((job.as_str(), task.as_str()), ("j", files[0].task_id.as_str()), "{sample}");
    }
});

store_test!(a_job_writes_the_rows_its_footprint_predicts_without_noise_tasks, |store: Store| async move {
    let spec = spec("[\"rgb\", \"mask\", \"pose\"]");
    let predicted = run_to_the_end(&store, &spec).await;
    assert!(predicted.outputs > 0, "{predicted:?}");
    assert_eq!(store.table_rows().await.unwrap(), predicted);
});
