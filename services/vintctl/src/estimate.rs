//! What a spec would cost, roughly: tasks per stage, samples, CPU time and output size, so that
//! `vintctl validate` can warn before an absurd spec is run.
//!
//! It is an upper bound (every grasp trial accepted) made from per-unit figures measured on the
//! project machine (2 vCPUs, AMD EPYC; one render thread per engine); another CPU, a GPU or a
//! scene unlike the built-in objects changes them. Each figure names its source, so that it can
//! be re-derived when `docs/benchmarks.md` is re-measured.

use serde::Serialize;
use vint_core::DatasetSpec;
use vint_core::contract::package::Modality;

/// Grasp: CPU seconds per trial at the default 2 ms timestep with 2.25 s simulated (a 1 s hold).
/// docs/benchmarks.md, "Grasp engine": "a trial costs ~60–80 ms of CPU (2.25 s of simulated time
/// at 2 ms)".
const GRASP_S_PER_TRIAL: f64 = 0.070;
const GRASP_REFERENCE_SIM_S: f64 = 2.25;
const GRASP_REFERENCE_HOLD_S: f64 = 1.0;
const GRASP_REFERENCE_TIMESTEP_S: f64 = 0.002;

/// Render: path tracing per pixel and sample. docs/benchmarks.md, "Render engine", pruning table:
/// 640×480 at 64 spp takes 10 896 ms with RGB and 217 ms without, (10 896 − 217) ms / (307 200 px
/// × 64) ≈ 0.54 µs (0.63 µs at 128×128 × 16 spp).
const RENDER_S_PER_PIXEL_SAMPLE: f64 = 0.55e-6;
/// Render: the geometry passes (depth, masks, segmentation) per pixel: the same table's 217 ms
/// for 307 200 px without path tracing.
const RENDER_S_PER_PIXEL: f64 = 0.7e-6;
/// Render: per view whatever the size (camera and scene updates, the object-alone pass).
/// docs/benchmarks.md, "tiny.toml": 72 views at 128×128 / 16 spp in ~270 ms each, of which the two
/// rates above account for ~160 ms.
const RENDER_S_PER_VIEW: f64 = 0.1;
/// Render: OpenImageDenoise per pixel. /work/shared/FACTS.md (Cycles on CPU): 640×480 renders in
/// 5–6.5 s, 8.4 s with denoise: ~2.5 s / 307 200 px.
const DENOISE_S_PER_PIXEL: f64 = 8e-6;
/// Noise: per pixel of a noisy depth image with every piece of the ToF model on. docs/depth_noise.md
/// (benches/noise_cost.py): 8.5 ms per 128×128 view, 146 ms per 512×512, 602 ms per 1024×1024.
const NOISE_S_PER_PIXEL: f64 = 0.56e-6;
/// Package: per sample. docs/benchmarks.md, "tiny.toml": 244 ms for 72 samples.
const PACKAGE_S_PER_SAMPLE: f64 = 0.0034;

/// Bytes per pixel of each image file, and of a sample's meta.json. docs/benchmarks.md, "Output
/// size per sample": medians of tiny.toml's 72 samples (128×128, 16 spp). An RGB PNG shrinks as
/// samples per pixel rise (less noise to compress); depth is float32 `.npy`.
const RGB_BYTES_PER_PIXEL: f64 = 1.8; // rgb.png, median 29 916 B
const DEPTH_BYTES_PER_PIXEL: f64 = 4.0; // depth.npy and depth_noisy.npy, 65 664 B each
const MASKS_BYTES_PER_PIXEL: f64 = 0.05; // mask.png + mask_full.png, 383 + 398 B
const SEGMENTATION_BYTES_PER_PIXEL: f64 = 0.045; // segmentation.png, 707 B
const META_JSON_BYTES: f64 = 4_417.0; // meta.json, median (4.1–4.7 KB): the view alone
const GRASP_RECORD_BYTES: f64 = 37_053.0; // <grasp_id>/grasp.json, median (26–50 KB), once per grasp

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

impl Estimate {
    pub fn of(spec: &DatasetSpec) -> Estimate {
        let pairs = (spec.hands.len() * spec.objects.len()) as u64;
        let trials = pairs * u64::from(spec.grasp.trials_per_pair);
        let chunks = pairs * u64::from(spec.chunks_per_pair());
        let samples = spec.max_samples();
        let wants = |m: Modality| spec.outputs.wants(m);
        let r = &spec.render;
        let pixels = f64::from(r.resolution[0]) * f64::from(r.resolution[1]);
        let views = samples as f64;

        let g = &spec.grasp;
        let shake_s = if g.shake_accel_mps2 > 0.0 { g.shake_duration_s } else { 0.0 };
        let simulated = GRASP_REFERENCE_SIM_S - GRASP_REFERENCE_HOLD_S + g.hold_s + shake_s;
        let per_trial =
            GRASP_S_PER_TRIAL * (simulated / GRASP_REFERENCE_SIM_S) * (GRASP_REFERENCE_TIMESTEP_S / g.timestep_s);
        let mut per_view = RENDER_S_PER_VIEW + RENDER_S_PER_PIXEL * pixels;
        if wants(Modality::Rgb) {
            per_view += RENDER_S_PER_PIXEL_SAMPLE * pixels * f64::from(r.samples);
            if r.denoise {
                per_view += DENOISE_S_PER_PIXEL * pixels;
            }
        }
        let noisy = wants(Modality::DepthNoisy);
        let grasp = per_trial * trials as f64;
        let render = per_view * views;
        let noise = if noisy { NOISE_S_PER_PIXEL * pixels * views } else { 0.0 };
        let package = PACKAGE_S_PER_SAMPLE * views;

        let mut bytes_per_pixel = 0.0;
        for (modality, bpp) in [
            (Modality::Rgb, RGB_BYTES_PER_PIXEL),
            (Modality::Depth, DEPTH_BYTES_PER_PIXEL),
            (Modality::DepthNoisy, DEPTH_BYTES_PER_PIXEL),
            (Modality::Mask, MASKS_BYTES_PER_PIXEL),
            (Modality::Segmentation, SEGMENTATION_BYTES_PER_PIXEL),
        ] {
            if wants(modality) {
                bytes_per_pixel += bpp;
            }
        }
        let grasps = views / f64::from(r.views_per_grasp().max(1));
        let output_bytes = views * (bytes_per_pixel * pixels + META_JSON_BYTES) + grasps * GRASP_RECORD_BYTES;
        let total = grasp + render + noise + package;

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
                grasp: chunks,
                render_max: grasps as u64,
                noise_max: if noisy { grasps as u64 } else { 0 },
                package_max: chunks,
            },
            samples_max: samples,
            cpu_seconds: CpuSeconds { grasp, render, noise, package, total },
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

    /// The figures are calibrated on tiny.toml, so they must reproduce its measurement
    /// (docs/benchmarks.md: Σ engine 21.4 s with 1.4 s of start-up; 12.83 MB written since each
    /// grasp's record is stored once rather than in every view's meta.json).
    #[test]
    fn tiny_costs_what_was_measured_within_a_quarter() {
        let e = Estimate::of(&DatasetSpec::parse(TINY).unwrap());
        assert_eq!(e.tasks, Tasks { grasp: 6, render_max: 12, noise_max: 12, package_max: 6 });
        assert_eq!(e.samples_max, 72);
        assert!((15.0..25.0).contains(&e.cpu_seconds.total), "{:?}", e.cpu_seconds);
        assert!((9.6e6..16e6).contains(&e.output_bytes), "{}", e.output_bytes);
        assert!(e.warnings.is_empty(), "{:?}", e.warnings);
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
        assert!(more_samples.cpu_seconds.render > 30.0 * base.cpu_seconds.render);
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
