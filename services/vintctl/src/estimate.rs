//! What a spec would cost, roughly: tasks per stage, samples, CPU time and output size, so that
//! `vintctl validate` can warn before an absurd spec is run. Tasks, CPU time and object-store
//! bytes per stage come from `vint_core::cost` (the planner's counts, each stage's own cost
//! model); `vintctl plan` (`plan.rs`) shows the same and adds the database's rows and bytes.
//!
//! It is an upper bound (every grasp trial accepted) made from per-unit figures measured on the
//! project machine (2 vCPUs, AMD EPYC; one render thread per engine); another CPU, a GPU or a
//! scene unlike the built-in objects changes them. Each figure names its source, so that it can
//! be re-derived when `docs/benchmarks.md` is re-measured.

use serde::Serialize;
use vint_core::DatasetSpec;
use vint_core::contract::Workload;
use vint_core::contract::package::{GRASP_RECORD_BYTES, META_JSON_BYTES, Modality};
use vint_core::cost::{self, CostError};

/// Above these a spec earns a warning.
pub const LARGE_CPU_S: f64 = 86_400.0; // one CPU-day
pub const LARGE_OUTPUT_BYTES: f64 = 100e9; // 100 GB

/// What an estimate is, said wherever it is shown.
pub const BASIS: &str = "rough upper bound (every trial accepted) from per-unit figures measured on a 2-core AMD \
     EPYC with one render thread per engine (docs/benchmarks.md); CPU time is summed over cores";

/// One stage's tasks and CPU seconds (on one core of the measured machine).
#[derive(Debug, Serialize, PartialEq)]
pub struct StageEstimate {
    pub stage: &'static str,
    pub tasks: u64,
    /// Whether `tasks` is fixed by the spec (tasks at submit; the rest with a quota).
    pub tasks_exact: bool,
    pub cpu_seconds: f64,
}

/// A rough, upper-bound estimate of what a spec costs.
#[derive(Debug, Serialize, PartialEq)]
pub struct Estimate {
    /// `BASIS`: a label that travels with the figures.
    pub basis: &'static str,
    /// In pipeline order.
    pub stages: Vec<StageEstimate>,
    pub samples_max: u64,
    pub cpu_seconds: f64,
    pub output_bytes: f64,
    /// Why the spec is large, if it is.
    pub warnings: Vec<String>,
}

/// Bytes per pixel of the image files one view of `spec` carries in a sample: each modality's
/// images are the size of the render outputs it is made from, and noisy depth its own (as PNG,
/// noise compresses worse than a clean surface).
fn sample_bytes_per_pixel(spec: &DatasetSpec, pixels: f64) -> f64 {
    let depth = spec.outputs.depth_format;
    Modality::ALL
        .into_iter()
        .filter(|m| spec.outputs.wants(*m))
        .map(|m| match m {
            Modality::DepthNoisy => vint_core::contract::render::noisy_depth_bytes_per_pixel(depth, pixels),
            _ => m.render_outputs().iter().map(|o| o.bytes_per_pixel(depth, pixels)).sum(),
        })
        .sum()
}

/// Bytes of the exported dataset (native layout): every sample's files and `meta.json`, one
/// record per grasp.
pub fn dataset_bytes(spec: &DatasetSpec, w: &Workload) -> f64 {
    let views = w.samples as f64;
    views * (sample_bytes_per_pixel(spec, w.pixels) * w.pixels + META_JSON_BYTES) + w.grasps as f64 * GRASP_RECORD_BYTES
}

impl Estimate {
    pub fn of(spec: &DatasetSpec) -> Result<Estimate, CostError> {
        let c = cost::of(spec)?;
        let output_bytes = dataset_bytes(spec, &c.work);
        let total = c.total().cpu_s;
        let g = &spec.grasp;

        let mut warnings = Vec::new();
        if let Some(n) = g.accepted_per_pair.filter(|&n| n > g.trials_per_pair) {
            warnings.push(format!(
                "grasp.accepted_per_pair = {n} exceeds grasp.trials_per_pair = {}: each pair stops at its trial budget \
                 with at most {} accepted grasps; raise trials_per_pair (the bound on trials) to reach {n}",
                g.trials_per_pair, g.trials_per_pair
            ));
        }
        if total > LARGE_CPU_S {
            warnings.push(format!(
                "this spec would take about {} of compute (more than 1 CPU-day): check grasp.trials_per_pair, the views per grasp, \
                 render.resolution and render.samples",
                cpu_time(total)
            ));
        }
        if output_bytes > LARGE_OUTPUT_BYTES {
            warnings.push(format!(
                "this spec would write about {} (more than 100 GB): check the sample count, render.resolution and \
                 outputs.modalities",
                size(output_bytes)
            ));
        }
        Ok(Estimate {
            basis: BASIS,
            stages: c
                .stages
                .iter()
                .map(|s| StageEstimate {
                    stage: s.stage.as_str(),
                    tasks: s.tasks,
                    tasks_exact: s.tasks_exact,
                    cpu_seconds: s.cost.cpu_s,
                })
                .collect(),
            samples_max: c.work.samples,
            cpu_seconds: total,
            output_bytes,
            warnings,
        })
    }
}

/// CPU seconds as people read them: `0.2 CPU-s`, `42 CPU-s`, `18 CPU-min`, `5.3 CPU-h`,
/// `3.1 CPU-days`.
pub fn cpu_time(s: f64) -> String {
    if s < 10.0 {
        format!("{s:.1} CPU-s")
    } else if s < 120.0 {
        format!("{s:.0} CPU-s")
    } else if s < 7_200.0 {
        format!("{:.0} CPU-min", s / 60.0)
    } else if s < 2.0 * 86_400.0 {
        format!("{:.1} CPU-h", s / 3_600.0)
    } else {
        format!("{:.1} CPU-days", s / 86_400.0)
    }
}

/// Bytes in decimal units: `17 MB`, `2.4 TB`.
pub fn size(bytes: f64) -> String {
    let units = [("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)];
    match units.iter().find(|(_, scale)| bytes >= *scale) {
        Some((unit, scale)) if bytes / scale < 10.0 => format!("{:.1} {unit}", bytes / scale),
        Some((unit, scale)) => format!("{:.0} {unit}", bytes / scale),
        None => format!("{bytes:.0} B"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TINY: &str = include_str!("../../../examples/tiny.toml");

    /// The estimate of tiny.toml with one line replaced.
    fn tiny_with(old: &str, new: &str) -> Estimate {
        assert!(TINY.contains(old), "tiny.toml lacks {old:?}");
        Estimate::of(&DatasetSpec::parse(&TINY.replacen(old, new, 1)).unwrap()).unwrap()
    }

    fn tasks(e: &Estimate) -> Vec<(&str, u64)> {
        e.stages.iter().map(|s| (s.stage, s.tasks)).collect()
    }

    fn stage<'a>(e: &'a Estimate, name: &str) -> &'a StageEstimate {
        e.stages.iter().find(|s| s.stage == name).unwrap()
    }

    fn cpu(e: &Estimate, name: &str) -> f64 {
        stage(e, name).cpu_seconds
    }

    /// The figures are calibrated on tiny.toml, so they must reproduce its measurement: with the
    /// default scene (table, flange), the sensor model and the denoiser, one `vintctl run
    /// examples/tiny.toml --workers 1` took 53.6 CPU-s (user + system, every process, engine
    /// start-ups included) for its 60 samples on 2026-11-27 beside a render study (43.9 CPU-s with
    /// `denoise = false`), ~64 s for tiny's bound of 72 (grasp type `any` then); with the spec's
    /// power grasp (5 of 12 trials accepted, 30 samples) 28.5 CPU-s alone, ~68 s for 72 at that rate.
    /// Written with 16-bit PNG depth (2026-11-29): 2.42 MB for those 30 samples and 5 grasps, ~5.8 MB
    /// for 72 and 12 (docs/benchmarks.md, "Depth as PNG").
    #[test]
    fn tiny_costs_what_was_measured_within_a_quarter() {
        let e = Estimate::of(&DatasetSpec::parse(TINY).unwrap()).unwrap();
        assert_eq!(tasks(&e), [("grasp", 6), ("render", 12), ("noise", 12), ("package", 6)]);
        assert_eq!(e.samples_max, 72);
        assert!((48.0..80.0).contains(&e.cpu_seconds), "{:?}", e.stages);
        assert!((4.4e6..7.3e6).contains(&e.output_bytes), "{}", e.output_bytes);
        assert!(e.warnings.is_empty(), "{:?}", e.warnings);
    }

    /// The object store of a real `vintctl run examples/tiny.toml` (2026-11-29, on `4c46d1c` with
    /// 16-bit PNG depth: 12 trials, 5 accepted grasps, 30 samples), distinct objects' bytes by the
    /// stage that first wrote them (from the job's `outputs` rows): grasp 275 549, render 1 330 151,
    /// noise 533 318, package 593 152. Each stage's own `cost` model, on the run's counts.
    #[test]
    fn object_store_bytes_reproduce_a_real_tiny_run_per_stage() {
        let spec = DatasetSpec::parse(TINY).unwrap();
        let c = cost::of(&spec).unwrap();
        let w = Workload { grasps: 5, samples: 30, ..c.work };
        let tasks = |stage| {
            let mut tasks = vint_core::plan::initial_tasks(&spec, &[]).unwrap();
            let chunk = vint_core::plan::GraspChunk::from_key(&tasks[0].key).unwrap();
            tasks.extend(vint_core::plan::after_grasp(&c.job, &chunk, &[0]).unwrap());
            tasks.into_iter().find(|t| t.stage == stage).unwrap().params
        };
        for (stage, measured) in [
            (vint_core::Stage::Grasp, 275_549.0),
            (vint_core::Stage::Render, 1_330_151.0),
            (vint_core::Stage::Noise, 533_318.0),
            (vint_core::Stage::Package, 593_152.0),
        ] {
            let model = vint_core::contract::cost(stage, &w, &tasks(stage)).unwrap().bytes;
            assert!((model / measured - 1.0).abs() < 0.1, "{stage}: {model} against {measured} measured");
        }
    }

    #[test]
    fn a_huge_spec_is_warned_about_in_time_and_size() {
        let e = tiny_with("trials_per_pair = 2", "trials_per_pair = 100000");
        assert_eq!(e.stages[0].tasks, 6 * 100_000 / 2, "chunks of 2 trials");
        assert_eq!(e.samples_max, 6 * 100_000 * 6);
        assert_eq!(e.warnings.len(), 2, "{:?}", e.warnings);
        assert!(e.warnings[0].contains("CPU-days") && e.warnings[0].contains("more than 1 CPU-day"));
        assert!(e.warnings[1].contains("GB (more than 100 GB)"), "{:?}", e.warnings);
    }

    #[test]
    fn a_quota_bounds_the_samples_and_one_beyond_the_trial_budget_is_warned_about() {
        let e = tiny_with("trials_per_pair = 2", "trials_per_pair = 40\naccepted_per_pair = 10");
        assert_eq!(e.samples_max, 6 * 10 * 6, "6 pairs × 10 grasps × 6 views");
        assert_eq!(stage(&e, "render").tasks, 6 * 10);
        assert_eq!(stage(&e, "grasp").tasks, 6 * 5, "10 grasps in chunks of 2");
        assert!(e.warnings.is_empty(), "{:?}", e.warnings);
        let beyond = tiny_with("trials_per_pair = 2", "trials_per_pair = 2\naccepted_per_pair = 10");
        assert_eq!(beyond.samples_max, 6 * 2 * 6);
        assert_eq!(beyond.warnings.len(), 1, "{:?}", beyond.warnings);
        assert!(beyond.warnings[0].contains("exceeds grasp.trials_per_pair = 2"), "{:?}", beyond.warnings);
    }

    #[test]
    fn cost_follows_what_is_rendered() {
        let base = Estimate::of(&DatasetSpec::parse(TINY).unwrap()).unwrap();
        let more_samples = tiny_with("samples = 16", "samples = 1024");
        // The denoiser's cost does not grow with samples, so 64× the samples is less than 64× the cost.
        assert!(cpu(&more_samples, "render") > 20.0 * cpu(&base, "render"));
        let no_rgb = tiny_with("modalities = [\"rgb\", ", "modalities = [");
        assert!(cpu(&no_rgb, "render") < cpu(&base, "render") / 2.0);
        assert!(no_rgb.output_bytes < base.output_bytes);
        let no_noise = tiny_with("\"depth_noisy\", ", "");
        let noise = stage(&no_noise, "noise");
        assert_eq!((noise.tasks, noise.tasks_exact, noise.cpu_seconds), (0, true, 0.0));
    }

    #[test]
    fn figures_read_as_people_say_them() {
        assert_eq!(cpu_time(0.18), "0.2 CPU-s");
        assert_eq!(cpu_time(42.2), "42 CPU-s");
        assert_eq!(cpu_time(1_100.0), "18 CPU-min");
        assert_eq!(cpu_time(19_080.0), "5.3 CPU-h");
        assert_eq!(cpu_time(3.1 * 86_400.0), "3.1 CPU-days");
        assert_eq!(size(17_070_560.0), "17 MB");
        assert_eq!(size(2.44e12), "2.4 TB");
        assert_eq!(size(512.0), "512 B");
    }
}
