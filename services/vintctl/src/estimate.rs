//! What a spec would cost, roughly: tasks per stage, samples, CPU time and output size, so that
//! `vintctl validate` can warn before an absurd spec is run. `vintctl plan` (`plan.rs`) costs a
//! spec from the same model (`Workload`, `cpu_seconds`, `object_store_bytes`, `dataset_bytes`)
//! and adds the database's rows and bytes.
//!
//! It is an upper bound (every grasp trial accepted) made from per-unit figures measured on the
//! project machine (2 vCPUs, AMD EPYC; one render thread per engine); another CPU, a GPU or a
//! scene unlike the built-in objects changes them. Each figure names its source, so that it can
//! be re-derived when `docs/benchmarks.md` is re-measured.

use serde::Serialize;
use vint_core::DatasetSpec;
use vint_core::contract::package::Modality;
use vint_core::contract::render::RenderOutput;
use vint_core::file_sizes::{
    CAMERA_JSON_BYTES, DEPTH_BYTES_PER_PIXEL, GRASP_RECORD_BYTES, GRASPS_JSON_BYTES_PER_TRIAL, MASKS_BYTES_PER_PIXEL,
    META_JSON_BYTES, OBJECT_PLY_BYTES, RGB_BYTES_PER_PIXEL, SEGMENTATION_BYTES_PER_PIXEL, TOUCH_JSON_BYTES_PER_TRIAL,
};

/// Grasp: CPU seconds per trial at the default 2 ms timestep with 2.25 s simulated (a 1 s hold).
/// docs/benchmarks.md, "Grasp engine": "a trial costs ~60–80 ms of CPU (2.25 s of simulated time
/// at 2 ms)".
const GRASP_S_PER_TRIAL: f64 = 0.070;
const GRASP_REFERENCE_SIM_S: f64 = 2.25;
const GRASP_REFERENCE_HOLD_S: f64 = 1.0;
const GRASP_REFERENCE_TIMESTEP_S: f64 = 0.002;

/// Render: path tracing per pixel and sample, with the default scene (the table fills most of the
/// image with a diffuse surface that shades and bounces where the bare HDRI background only
/// looked up a colour: ~2.5–3× the bare scene's cost at 640×480, `benches/scene_cost.py`).
/// Calibrated on tiny.toml (128×128, 16 raw spp, the default scene): ~0.59 CPU-s per view in all,
/// of which the fixed and geometry parts ~0.11 s, leaving ~0.47 s for 262 144 pixel-samples (the
/// test below).
const RENDER_S_PER_PIXEL_SAMPLE: f64 = 1.8e-6;
/// Render: the geometry passes (depth, masks, segmentation) per pixel: the same table's 217 ms
/// for 307 200 px without path tracing.
const RENDER_S_PER_PIXEL: f64 = 0.7e-6;
/// Render: per view whatever the size (camera and scene updates, the object-alone pass).
/// docs/benchmarks.md, "tiny.toml": 72 views at 128×128 / 16 spp in ~270 ms each, of which the two
/// rates above accounted for ~160 ms.
const RENDER_S_PER_VIEW: f64 = 0.1;
/// Render: OpenImageDenoise (the engine's own call, with Cycles' albedo and normal passes) per
/// view and per pixel: 1.6 s for a 640×480 image on one thread and 0.09 s for 128×128 (timed
/// beside a render study), and tiny.toml's 60 views cost 53.6 CPU-s with it against 43.9 without
/// (~0.16 s a view with the passes and their files).
const DENOISE_S_PER_VIEW: f64 = 0.075;
const DENOISE_S_PER_PIXEL: f64 = 5.2e-6;
/// Noise: per pixel of a noisy depth image with every piece of the ToF model on. docs/depth_noise.md
/// (benches/noise_cost.py): 8.5 ms per 128×128 view, 146 ms per 512×512, 602 ms per 1024×1024.
const NOISE_S_PER_PIXEL: f64 = 0.56e-6;
/// Package: per sample. docs/benchmarks.md, "tiny.toml": 244 ms for 72 samples.
const PACKAGE_S_PER_SAMPLE: f64 = 0.0034;

/// Above these a spec earns a warning.
pub const LARGE_CPU_S: f64 = 86_400.0; // one CPU-day
pub const LARGE_OUTPUT_BYTES: f64 = 100e9; // 100 GB

/// Tasks per stage; render, noise and samples are upper bounds (one render task per accepted grasp).
#[derive(Debug, Serialize, PartialEq)]
pub struct Tasks {
    pub grasp: u64,
    pub render_max: u64,
    pub noise_max: u64,
    pub package_max: u64,
}

/// CPU seconds by stage, on one core of the measured machine.
#[derive(Debug, Serialize, PartialEq)]
pub struct CpuSeconds {
    pub grasp: f64,
    pub render: f64,
    pub noise: f64,
    pub package: f64,
    pub total: f64,
}

/// What an estimate is, said wherever it is shown.
pub const BASIS: &str = "rough upper bound (every trial accepted) from per-unit figures measured on a 2-core AMD \
     EPYC with one render thread per engine (docs/benchmarks.md); CPU time is summed over cores";

/// A rough, upper-bound estimate of what a spec costs.
#[derive(Debug, Serialize, PartialEq)]
pub struct Estimate {
    /// `BASIS`: a label that travels with the figures.
    pub basis: &'static str,
    pub tasks: Tasks,
    pub samples_max: u64,
    pub cpu_seconds: CpuSeconds,
    pub output_bytes: f64,
    /// Why the spec is large, if it is.
    pub warnings: Vec<String>,
}

/// What a spec asks for, counted: the ground both `validate`'s estimate and `plan` stand on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Workload {
    /// (object, hand) pairs.
    pub pairs: u64,
    pub objects: u64,
    /// Grasp tasks: exact, fixed at submit.
    pub chunks: u64,
    /// Trials the grasp tasks may run: the spec's bound.
    pub trials: u64,
    /// Accepted grasps: the quota's target (`grasp.accepted_per_pair`), reached when every chunk
    /// fills its quota within its trials; without a quota, every trial (an upper bound).
    pub grasps: u64,
    /// Whether the spec fixes `grasps` with a quota.
    pub quota: bool,
    pub views_per_grasp: u64,
    /// `grasps × views_per_grasp`.
    pub samples: u64,
    /// Pixels per view.
    pub pixels: f64,
    /// Whether noisy depth is requested (one noise task per render task).
    pub noisy: bool,
}

impl Workload {
    pub fn of(spec: &DatasetSpec) -> Workload {
        let pairs = (spec.hands.len() * spec.objects.len()) as u64;
        let budget = spec.grasp.budget();
        let views_per_grasp = u64::from(spec.render.views_per_grasp());
        let grasps = pairs * u64::from(budget.grasps());
        let r = &spec.render;
        Workload {
            pairs,
            objects: spec.objects.len() as u64,
            chunks: pairs * u64::from(budget.chunks()),
            trials: pairs * u64::from(spec.grasp.trials_per_pair),
            grasps,
            quota: spec.grasp.accepted_per_pair.is_some(),
            views_per_grasp,
            samples: grasps * views_per_grasp,
            pixels: f64::from(r.resolution[0]) * f64::from(r.resolution[1]),
            noisy: spec.outputs.wants(Modality::DepthNoisy),
        }
    }
}

/// A figure for each stage.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct PerStage {
    pub grasp: f64,
    pub render: f64,
    pub noise: f64,
    pub package: f64,
}

impl PerStage {
    pub fn total(&self) -> f64 {
        self.grasp + self.render + self.noise + self.package
    }
}

/// CPU seconds per grasp trial at the spec's physics: the measured trial scaled by simulated
/// time and timestep.
fn grasp_s_per_trial(spec: &DatasetSpec) -> f64 {
    let g = &spec.grasp;
    let shake_s = if g.shake_accel_mps2 > 0.0 { g.shake_duration_s } else { 0.0 };
    let simulated = GRASP_REFERENCE_SIM_S - GRASP_REFERENCE_HOLD_S + g.hold_s + shake_s;
    GRASP_S_PER_TRIAL * (simulated / GRASP_REFERENCE_SIM_S) * (GRASP_REFERENCE_TIMESTEP_S / g.timestep_s)
}

/// CPU seconds one view costs the render engine.
fn render_s_per_view(spec: &DatasetSpec, pixels: f64) -> f64 {
    let r = &spec.render;
    let mut per_view = RENDER_S_PER_VIEW + RENDER_S_PER_PIXEL * pixels;
    if spec.outputs.wants(Modality::Rgb) {
        per_view += RENDER_S_PER_PIXEL_SAMPLE * pixels * f64::from(r.samples);
        if r.denoise {
            per_view += DENOISE_S_PER_VIEW + DENOISE_S_PER_PIXEL * pixels;
        }
    }
    per_view
}

/// CPU seconds per stage on one core of the measured machine: every trial of the bound run
/// (grasp), every view of `w.grasps` rendered, made noisy and packaged.
pub fn cpu_seconds(spec: &DatasetSpec, w: &Workload) -> PerStage {
    let views = w.samples as f64;
    PerStage {
        grasp: grasp_s_per_trial(spec) * w.trials as f64,
        render: render_s_per_view(spec, w.pixels) * views,
        noise: if w.noisy { NOISE_S_PER_PIXEL * w.pixels * views } else { 0.0 },
        package: PACKAGE_S_PER_SAMPLE * views,
    }
}

/// Bytes per pixel of the image files one view of `spec` carries in a sample.
fn sample_bytes_per_pixel(spec: &DatasetSpec) -> f64 {
    [
        (Modality::Rgb, RGB_BYTES_PER_PIXEL),
        (Modality::Depth, DEPTH_BYTES_PER_PIXEL),
        (Modality::DepthNoisy, DEPTH_BYTES_PER_PIXEL),
        (Modality::Mask, MASKS_BYTES_PER_PIXEL),
        (Modality::Segmentation, SEGMENTATION_BYTES_PER_PIXEL),
    ]
    .into_iter()
    .filter(|(m, _)| spec.outputs.wants(*m))
    .map(|(_, bpp)| bpp)
    .sum()
}

/// Bytes of the exported dataset (native layout): every sample's files and `meta.json`, one
/// record per grasp.
pub fn dataset_bytes(spec: &DatasetSpec, w: &Workload) -> f64 {
    let views = w.samples as f64;
    views * (sample_bytes_per_pixel(spec) * w.pixels + META_JSON_BYTES) + w.grasps as f64 * GRASP_RECORD_BYTES
}

/// Bytes each stage adds to the object store. Content addressing stores a packaged image once:
/// it is the render's or noise's object under the same hash, so the package stage adds only its
/// JSON (`meta.json` per sample, a record per grasp). Render tasks write what the noise stage
/// reads even when the sample does not carry it (the segmentation the noise model needs).
pub fn object_store_bytes(w: &Workload, render_outputs: &[RenderOutput]) -> PerStage {
    let views = w.samples as f64;
    let render_bpp: f64 = render_outputs
        .iter()
        .map(|o| match o {
            RenderOutput::Rgb => RGB_BYTES_PER_PIXEL,
            RenderOutput::Depth => DEPTH_BYTES_PER_PIXEL,
            RenderOutput::Mask => MASKS_BYTES_PER_PIXEL,
            RenderOutput::Segmentation => SEGMENTATION_BYTES_PER_PIXEL,
        })
        .sum();
    PerStage {
        grasp: w.trials as f64 * (GRASPS_JSON_BYTES_PER_TRIAL + TOUCH_JSON_BYTES_PER_TRIAL)
            + w.objects as f64 * OBJECT_PLY_BYTES,
        render: views * (render_bpp * w.pixels + CAMERA_JSON_BYTES),
        noise: if w.noisy { views * DEPTH_BYTES_PER_PIXEL * w.pixels } else { 0.0 },
        package: views * META_JSON_BYTES + w.grasps as f64 * GRASP_RECORD_BYTES,
    }
}

impl Estimate {
    pub fn of(spec: &DatasetSpec) -> Estimate {
        let w = Workload::of(spec);
        let cpu = cpu_seconds(spec, &w);
        let output_bytes = dataset_bytes(spec, &w);
        let total = cpu.total();
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
        Estimate {
            basis: BASIS,
            tasks: Tasks {
                grasp: w.chunks,
                render_max: w.grasps,
                noise_max: if w.noisy { w.grasps } else { 0 },
                package_max: w.chunks,
            },
            samples_max: w.samples,
            cpu_seconds: CpuSeconds {
                grasp: cpu.grasp,
                render: cpu.render,
                noise: cpu.noise,
                package: cpu.package,
                total,
            },
            output_bytes,
            warnings,
        }
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
        Estimate::of(&DatasetSpec::parse(&TINY.replacen(old, new, 1)).unwrap())
    }

    /// The figures are calibrated on tiny.toml, so they must reproduce its measurement: with the
    /// default scene (table, flange), the sensor model and the denoiser, one `vintctl run
    /// examples/tiny.toml --workers 1` took 53.6 CPU-s (user + system, every process, engine
    /// start-ups included) for its 60 samples on 2026-11-27 beside a render study (43.9 CPU-s with
    /// `denoise = false`), ~64 s for tiny's bound of 72 (grasp type `any` then); with the spec's
    /// power grasp (5 of 12 trials accepted, 30 samples) 28.5 CPU-s alone, ~68 s for 72 at that rate;
    /// 12.83 MB written since each grasp's record is stored once rather than in every view's
    /// meta.json (docs/benchmarks.md).
    #[test]
    fn tiny_costs_what_was_measured_within_a_quarter() {
        let e = Estimate::of(&DatasetSpec::parse(TINY).unwrap());
        assert_eq!(e.tasks, Tasks { grasp: 6, render_max: 12, noise_max: 12, package_max: 6 });
        assert_eq!(e.samples_max, 72);
        assert!((48.0..80.0).contains(&e.cpu_seconds.total), "{:?}", e.cpu_seconds);
        assert!((9.6e6..16e6).contains(&e.output_bytes), "{}", e.output_bytes);
        assert!(e.warnings.is_empty(), "{:?}", e.warnings);
    }

    /// The object store of a real `vintctl run examples/tiny.toml` (2026-11-25, commit `687edb3`:
    /// 12 trials, 10 accepted grasps, 60 samples), distinct objects' bytes by the stage that first
    /// wrote them (`scripts/measure_db_bytes.py`'s run): grasp 233 747, render 5 861 717, noise
    /// 3 939 840, package 597 582.
    #[test]
    fn object_store_bytes_reproduce_a_real_tiny_run_per_stage() {
        let spec = DatasetSpec::parse(TINY).unwrap();
        let w = Workload { grasps: 10, samples: 60, ..Workload::of(&spec) };
        let plan = vint_core::plan::JobPlan::new(&spec, &[]).unwrap();
        let b = object_store_bytes(&w, &plan.render_outputs);
        for (stage, model, measured) in [
            ("grasp", b.grasp, 233_747.0),
            ("render", b.render, 5_861_717.0),
            ("noise", b.noise, 3_939_840.0),
            ("package", b.package, 597_582.0),
        ] {
            assert!((model / measured - 1.0).abs() < 0.1, "{stage}: {model} against {measured} measured");
        }
    }

    #[test]
    fn a_huge_spec_is_warned_about_in_time_and_size() {
        let e = tiny_with("trials_per_pair = 2", "trials_per_pair = 100000");
        assert_eq!(e.tasks.grasp, 6 * 100_000 / 2, "chunks of 2 trials");
        assert_eq!(e.samples_max, 6 * 100_000 * 6);
        assert_eq!(e.warnings.len(), 2, "{:?}", e.warnings);
        assert!(e.warnings[0].contains("CPU-days") && e.warnings[0].contains("more than 1 CPU-day"));
        assert!(e.warnings[1].contains("GB (more than 100 GB)"), "{:?}", e.warnings);
    }

    #[test]
    fn a_quota_bounds_the_samples_and_one_beyond_the_trial_budget_is_warned_about() {
        let e = tiny_with("trials_per_pair = 2", "trials_per_pair = 40\naccepted_per_pair = 10");
        assert_eq!(e.samples_max, 6 * 10 * 6, "6 pairs × 10 grasps × 6 views");
        assert_eq!(e.tasks.render_max, 6 * 10);
        assert_eq!(e.tasks.grasp, 6 * 5, "10 grasps in chunks of 2");
        assert!(e.warnings.is_empty(), "{:?}", e.warnings);
        let beyond = tiny_with("trials_per_pair = 2", "trials_per_pair = 2\naccepted_per_pair = 10");
        assert_eq!(beyond.samples_max, 6 * 2 * 6);
        assert_eq!(beyond.warnings.len(), 1, "{:?}", beyond.warnings);
        assert!(beyond.warnings[0].contains("exceeds grasp.trials_per_pair = 2"), "{:?}", beyond.warnings);
    }

    #[test]
    fn cost_follows_what_is_rendered() {
        let base = Estimate::of(&DatasetSpec::parse(TINY).unwrap());
        let more_samples = tiny_with("samples = 16", "samples = 1024");
        // The denoiser's cost does not grow with samples, so 64× the samples is less than 64× the cost.
        assert!(more_samples.cpu_seconds.render > 20.0 * base.cpu_seconds.render);
        let no_rgb = tiny_with("modalities = [\"rgb\", ", "modalities = [");
        assert!(no_rgb.cpu_seconds.render < base.cpu_seconds.render / 2.0);
        assert!(no_rgb.output_bytes < base.output_bytes);
        let no_noise = tiny_with("\"depth_noisy\", ", "");
        assert_eq!((no_noise.tasks.noise_max, no_noise.cpu_seconds.noise), (0, 0.0));
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
