//! The noise stage: an Azure-Kinect-like time-of-flight depth model applied to every depth image
//! of one grasp's render task (`vint_engines.noise`; the model and its sources:
//! `docs/depth_noise.md`).

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

use super::depth::DepthFormat;
use super::render::{VIEW_INDEX, ViewFile};
use super::{Bound, SEED_MAX};

/// Multiplies the axial σ of the mode (1 = the calibration in `docs/depth_noise.md`).
pub const SIGMA_SCALE: Bound<f64> = Bound::new(0.0, 10.0, 1.0);
/// σ of the lateral jitter, in the mode's native pixels (BlenderProc's Kinect model uses 0.25 px;
/// FACTS.md, "Depth sensor").
pub const LATERAL_SIGMA_PX: Bound<f64> = Bound::new(0.0, 5.0, 0.25);
/// A depth step larger than this across a pixel's footprint makes it a mixed (flying) pixel (m).
pub const FLYING_JUMP_M: Bound<f64> = Bound::new(0.001, 10.0, 0.02);
/// The share of mixed pixels the sensor's depth engine invalidates (the rest fly).
pub const FLYING_INVALID_SHARE: Bound<f64> = Bound::new(0.0, 1.0, 0.5);
/// Multipath bias per metre of concavity depth (see `docs/depth_noise.md`, multipath).
pub const MULTIPATH_GAIN: Bound<f64> = Bound::new(0.0, 2.0, 0.3);
/// Half-angle of the cone around the mirror direction in which a metal surface saturates (deg).
pub const SPECULAR_CONE_DEG: Bound<f64> = Bound::new(0.0, 45.0, 10.0);
/// The ToF camera's distance from the colour camera, along the colour camera's x axis (m). Our
/// assumption for the Azure Kinect: factory calibrations put the depth camera about 32 mm from
/// the colour camera (docs/depth_noise.md).
pub const TOF_BASELINE_M: Bound<f64> = Bound::new(0.0, 0.2, 0.032);
/// σ of the depth engine's spatial smoothing of the noise, in native pixels (0: white noise). Our
/// assumption (docs/depth_noise.md): 1 native pixel, neighbours correlate at 0.78.
pub const SPATIAL_SIGMA_PX: Bound<f64> = Bound::new(0.0, 5.0, 1.0);

/// An Azure Kinect depth mode: its native resolution, field of view and operating range
/// (Microsoft, Azure Kinect DK hardware specification, "Depth camera supported operating modes").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
pub enum DepthMode {
    /// 640×576, 75°×65°, 0.5–3.86 m.
    #[default]
    #[serde(rename = "nfov_unbinned")]
    NfovUnbinned,
    /// 320×288, 75°×65°, 0.5–5.46 m.
    #[serde(rename = "nfov_2x2binned")]
    Nfov2x2Binned,
    /// 512×512, 120°×120°, 0.25–2.88 m.
    #[serde(rename = "wfov_2x2binned")]
    Wfov2x2Binned,
    /// 1024×1024, 120°×120°, 0.25–2.21 m.
    #[serde(rename = "wfov_unbinned")]
    WfovUnbinned,
}

/// A depth mode's figures (Microsoft's hardware specification).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ModeFigures {
    pub width_px: u32,
    pub height_px: u32,
    pub fov_h_deg: f64,
    pub fov_v_deg: f64,
    pub min_range_m: f64,
    pub max_range_m: f64,
}

impl DepthMode {
    pub const ALL: [DepthMode; 4] =
        [DepthMode::NfovUnbinned, DepthMode::Nfov2x2Binned, DepthMode::Wfov2x2Binned, DepthMode::WfovUnbinned];

    pub fn as_str(self) -> &'static str {
        match self {
            DepthMode::NfovUnbinned => "nfov_unbinned",
            DepthMode::Nfov2x2Binned => "nfov_2x2binned",
            DepthMode::Wfov2x2Binned => "wfov_2x2binned",
            DepthMode::WfovUnbinned => "wfov_unbinned",
        }
    }

    pub fn figures(self) -> ModeFigures {
        let (width_px, height_px, fov_h_deg, fov_v_deg, min_range_m, max_range_m) = match self {
            DepthMode::NfovUnbinned => (640, 576, 75.0, 65.0, 0.5, 3.86),
            DepthMode::Nfov2x2Binned => (320, 288, 75.0, 65.0, 0.5, 5.46),
            DepthMode::Wfov2x2Binned => (512, 512, 120.0, 120.0, 0.25, 2.88),
            DepthMode::WfovUnbinned => (1024, 1024, 120.0, 120.0, 0.25, 2.21),
        };
        ModeFigures { width_px, height_px, fov_h_deg, fov_v_deg, min_range_m, max_range_m }
    }
}

/// The modes' figures as the committed schema carries them (`depth_modes`), so the engine reads
/// the one table this module defines.
pub fn modes_table() -> Value {
    let mut table = serde_json::Map::new();
    for mode in DepthMode::ALL {
        let f = mode.figures();
        table.insert(
            mode.as_str().to_string(),
            json!({
                "width_px": f.width_px,
                "height_px": f.height_px,
                "fov_h_deg": f.fov_h_deg,
                "fov_v_deg": f.fov_v_deg,
                "min_range_m": f.min_range_m,
                "max_range_m": f.max_range_m,
            }),
        );
    }
    Value::Object(table)
}

/// A noise task's parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
#[schemars(rename = "NoiseParams")]
pub struct Params {
    #[serde(default)]
    pub noise: NoiseModel,
    #[schemars(length(min = 1, max = super::render::MAX_VIEWS))]
    pub views: Vec<View>,
    /// How the noisy depth images are stored (the render task's clean ones are read in either).
    #[serde(default)]
    pub depth_format: DepthFormat,
}

/// The depth-sensor model (`vint_engines/noise/model.py` and `docs/depth_noise.md` document each
/// term). Axial noise and the mode's range always apply; the other pieces can be switched off.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct NoiseModel {
    /// The Azure Kinect depth mode: range, native resolution and field of view.
    pub mode: DepthMode,
    /// Multiplies the mode's axial σ.
    #[schemars(range(min = SIGMA_SCALE.min, max = SIGMA_SCALE.max))]
    pub sigma_scale: f64,
    /// Lateral jitter of where each pixel samples the scene.
    pub lateral: bool,
    /// σ of the lateral jitter, in native pixels of the mode.
    #[schemars(range(min = LATERAL_SIGMA_PX.min, max = LATERAL_SIGMA_PX.max))]
    pub lateral_sigma_px: f64,
    /// Mixed foreground/background depths at depth edges.
    pub flying_pixels: bool,
    /// A step larger than this within a pixel's footprint mixes depths (m).
    #[schemars(range(min = FLYING_JUMP_M.min, max = FLYING_JUMP_M.max))]
    pub flying_jump_m: f64,
    /// The share of mixed pixels that read invalid instead of flying.
    #[schemars(range(min = FLYING_INVALID_SHARE.min, max = FLYING_INVALID_SHARE.max))]
    pub flying_invalid_share: f64,
    /// Positive bias in concave corners (light that reaches the pixel by two bounces).
    pub multipath: bool,
    /// Bias per metre of concavity depth.
    #[schemars(range(min = MULTIPATH_GAIN.min, max = MULTIPATH_GAIN.max))]
    pub multipath_gain: f64,
    /// Per-segment materials from `camera.json`: IR reflectivity, glass, specular metal.
    pub materials: bool,
    /// Half-angle of the saturating cone around a metal surface's mirror direction (deg).
    #[schemars(range(min = SPECULAR_CONE_DEG.min, max = SPECULAR_CONE_DEG.max))]
    pub specular_cone_deg: f64,
    /// Depth seen from the ToF camera beside the colour camera and registered onto it: no reading
    /// where the ToF camera cannot see the surface (occlusion shadows, resampling holes).
    pub registration: bool,
    /// The ToF camera's offset from the colour camera along its x axis (m).
    #[schemars(range(min = TOF_BASELINE_M.min, max = TOF_BASELINE_M.max))]
    pub tof_baseline_m: f64,
    /// σ of the depth engine's spatial smoothing of the axial noise, in native pixels (0: white).
    #[schemars(range(min = SPATIAL_SIGMA_PX.min, max = SPATIAL_SIGMA_PX.max))]
    pub spatial_sigma_px: f64,
}

impl Default for NoiseModel {
    fn default() -> NoiseModel {
        NoiseModel {
            mode: DepthMode::default(),
            sigma_scale: SIGMA_SCALE.default,
            lateral: true,
            lateral_sigma_px: LATERAL_SIGMA_PX.default,
            flying_pixels: true,
            flying_jump_m: FLYING_JUMP_M.default,
            flying_invalid_share: FLYING_INVALID_SHARE.default,
            multipath: true,
            multipath_gain: MULTIPATH_GAIN.default,
            materials: true,
            specular_cone_deg: SPECULAR_CONE_DEG.default,
            registration: true,
            tof_baseline_m: TOF_BASELINE_M.default,
            spatial_sigma_px: SPATIAL_SIGMA_PX.default,
        }
    }
}

/// One view's index (its render task's depth file) and the seed of its noise.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
#[schemars(rename = "NoiseView")]
pub struct View {
    #[schemars(range(min = VIEW_INDEX.min, max = VIEW_INDEX.max))]
    pub view_index: u32,
    #[schemars(range(max = SEED_MAX))]
    pub seed: u64,
}

/// The noisy depth of view `view` stored as `format` (`v03_depth_noisy.png`; 0 = invalid).
pub fn noisy_depth_file(view: u32, format: DepthFormat) -> String {
    format!("v{view:02}_depth_noisy.{}", format.extension())
}

/// The key of the noise task of grasp `grasp_index` of (object, hand).
pub fn task_key(object: &str, hand: &str, grasp_index: u32) -> String {
    format!("noise/{object}/{hand}/g{grasp_index:06}")
}

/// A noise task reads its render task's depth images, their segmentation (which surface, so which
/// material, each pixel sees) and camera records (intrinsics, segment materials).
pub fn reads(file: &str) -> bool {
    DepthFormat::ALL
        .map(ViewFile::Depth)
        .iter()
        .chain(&[ViewFile::Segmentation, ViewFile::Camera])
        .any(|f| file.starts_with('v') && file.len() == f.name(0).len() && file.ends_with(&f.name(0)[3..]))
}

/// What a noise engine answers.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct NoiseResult {
    /// Views made noisy.
    pub views: u32,
}

/// A noise task writes one noisy depth image per view.
pub fn files_written(task: &Params) -> u64 {
    task.views.len() as u64
}

/// Per pixel of a noisy depth image with every piece of the ToF model on. docs/depth_noise.md
/// (benches/noise_cost.py): 8.5 ms per 128×128 view, 146 ms per 512×512, 602 ms per 1024×1024.
const S_PER_PIXEL: f64 = 0.56e-6;

/// Every view made noisy; a depth image per view stored.
pub fn cost(work: &super::Workload, task: &Params) -> super::Cost {
    let pixels = work.pixels * work.samples as f64;
    let bytes = super::render::noisy_depth_bytes_per_pixel(task.depth_format, work.pixels) * pixels;
    super::Cost { cpu_s: S_PER_PIXEL * pixels, bytes }
}

/// The timing-only answer: each view's noisy depth, the size of the depth it is made from (as
/// `.npy`), or as PNG the size the measured model gives an image of its pixels (found from the
/// clean PNG's size by the same model).
pub fn fake(
    task: &Params,
    inputs: &[super::FakeInput<'_>],
) -> Result<(NoiseResult, Vec<super::FakeFile>), super::FakeError> {
    let noisy_size = |clean: u64| match task.depth_format {
        DepthFormat::Npy => clean,
        DepthFormat::Png => {
            let pixels = super::render::PNG_DEPTH.pixels_of(clean as f64);
            (super::render::PNG_NOISY_DEPTH.bytes_per_pixel(pixels) * pixels).round() as u64
        }
    };
    let mut files = Vec::with_capacity(task.views.len());
    for view in &task.views {
        let depth = ViewFile::Depth(task.depth_format).name(view.view_index);
        let size =
            inputs.iter().find(|i| i.name == depth).map(|i| noisy_size(i.size)).ok_or_else(|| {
                super::FakeError::MissingInput { stage: crate::stage::Stage::Noise, name: depth.clone() }
            })?;
        let name = noisy_depth_file(view.view_index, task.depth_format);
        files.push(super::FakeFile { name, kind: ViewFile::Depth(task.depth_format).kind(), size });
    }
    Ok((NoiseResult { views: task.views.len() as u32 }, files))
}
