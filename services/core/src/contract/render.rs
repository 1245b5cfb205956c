//! The render stage: every view of one accepted grasp, rendered by Blender/Cycles
//! (`vint_engines.render`). `docs/rendering.md` has the conventions of its outputs.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::depth::DepthFormat;
use super::grasp::{GRASPS_FILE, MODEL_FILE};
use super::{Bound, SEED_MAX};
use crate::asset::Asset;

pub const WIDTH_PX: Bound<u32> = Bound::new(16, 8192, 128);
pub const HEIGHT_PX: Bound<u32> = Bound::new(16, 8192, 128);
/// Cycles samples per pixel of the RGB image. Default 32: with the denoiser (on by default), the
/// cheapest setting whose foreground — the object, hand and arm pixels — reaches 35 dB median PSNR
/// against a 512-sample reference at 640×480 over the render study's opaque and glass objects,
/// with no firefly (docs/studies/render/render_study.md).
pub const SAMPLES: Bound<u32> = Bound::new(1, 65_536, 32);
/// Whether the RGB image is denoised (`Settings::denoise`).
pub const DENOISE: bool = true;
/// Horizontal field of view (degrees).
pub const FOV_DEG: Bound<f64> = Bound::new(5.0, 150.0, 60.0);
/// Each end of the camera's distance range from the object (m).
pub const RADIUS_M: Bound<f64> = Bound::new(0.05, 10.0, 0.5);
pub const RADIUS_M_DEFAULT: [f64; 2] = [0.5, 0.65];
/// Each end of the camera's elevation range above the horizontal plane (degrees).
pub const ELEVATION_DEG: Bound<f64> = Bound::new(-90.0, 90.0, 15.0);
pub const ELEVATION_DEG_DEFAULT: [f64; 2] = [15.0, 75.0];
/// Each end of the camera's roll about its optical axis (degrees). A robot's camera is mounted
/// upright, so by default world up stays near image up: a jitter of ±5° (a mount's tolerance).
/// [-180, 180] turns views through every direction.
pub const ROLL_DEG: Bound<f64> = Bound::new(-180.0, 180.0, -5.0);
pub const ROLL_DEG_DEFAULT: [f64; 2] = [-5.0, 5.0];
/// How far from the image centre the object's centre may land, as a fraction of the way to the
/// image edge (0: always centred). The renderer shrinks the draw so the object's bounding sphere
/// stays in the frame with `FRAME_MARGIN` of the image left over.
pub const OFFCENTRE: Bound<f64> = Bound::new(0.0, 0.9, 0.6);
/// The intrinsics' spread between units of a camera model (σ): the focal length is scaled by
/// 1 + N(0, σ), the principal point moved by N(0, σ) of the image's width and height, per view.
/// 0 (the default) keeps the nominal pinhole: principal point at the centre, `fov_deg`.
pub const INTRINSICS_JITTER: Bound<f64> = Bound::new(0.0, 0.1, 0.0);
/// Each radial coefficient of the lens distortion (k1, k2, k3 of OpenCV's Brown–Conrady model).
/// Real colour cameras sit far inside: the Azure Kinect's colour camera, which its factory
/// calibrates with OpenCV's rational model, bends like k1 ≈ 0.1 near the axis (one published
/// unit: k1 = 0.34 over k4 = 0.22), and wide-angle lenses that the five coefficients still
/// describe reach |k1| ≈ 0.3–0.5; past 1 the polynomial describes no lens over a useful field of
/// view (fisheyes need another model). Whether a lens is invertible over the image depends on the
/// field of view too: `radial_reach`.
pub const DISTORTION_RADIAL: Bound<f64> = Bound::new(-1.0, 1.0, 0.0);
/// Each tangential (decentring) coefficient, p1 and p2: calibrated lenses give |p| ~ 1e-4–1e-3
/// (that Azure Kinect unit: below 5e-4); 0.1 is a lens element grossly off its axis.
pub const DISTORTION_TANGENTIAL: Bound<f64> = Bound::new(-0.1, 0.1, 0.0);
/// The lens distortion's coefficients in OpenCV's order, [k1, k2, p1, p2, k3], with their bounds.
pub const DISTORTION: [(&str, Bound<f64>); 5] = [
    ("k1", DISTORTION_RADIAL),
    ("k2", DISTORTION_RADIAL),
    ("p1", DISTORTION_TANGENTIAL),
    ("p2", DISTORTION_TANGENTIAL),
    ("k3", DISTORTION_RADIAL),
];
/// No distortion: a pinhole (the default; nothing is resampled).
pub const PINHOLE: [f64; 5] = [0.0; 5];
/// Each end of the range a sampled view's occlusion must fall in (the share of the object's full
/// mask the hand and arm hide). Default the paper's: "occlusion by the fingers 10–90 %"
/// (VinT-6D, §3.3.7). The renderer redraws a view's camera until it lands in range, at most
/// `MAX_CAMERA_ATTEMPTS` times (`vint_engines/render/viewpoint.py`); [0, 1] accepts every camera.
pub const OCCLUSION: Bound<f64> = Bound::new(0.0, 1.0, 0.1);
pub const OCCLUSION_DEFAULT: [f64; 2] = [0.1, 0.9];
/// The firefly filter's threshold: a pixel brighter than all 8 neighbours by more than this share
/// of full scale takes their median (`vint_engines/render/fireflies.py`); 0 is off.
pub const DESPECKLE: Bound<f64> = Bound::new(0.0, 1.0, 0.3);
/// Cycles' clamp on indirect light (`sample_clamp_indirect`, Cycles' default 10; 0 is off).
pub const CLAMP_INDIRECT: Bound<f64> = Bound::new(0.0, 1000.0, 10.0);
/// The table top's gap below the lowest point of the hand, the object and the arm's flange (m).
pub const TABLE_GAP_M: Bound<f64> = Bound::new(0.0, 1.0, 0.05);
/// Catalog objects standing on the table around the grasp (0: none). At most 8: a 1.6 × 1.0 m top
/// around a grasp holds about that many household objects with 2 cm between them, and each is an
/// object in every view's segmentation and RGB scene.
pub const DISTRACTORS: Bound<u32> = Bound::new(0, 8, 0);
/// The light's per-view strength spread (standard deviation, EV; 0: the environment's own).
pub const STRENGTH_EV_SIGMA: Bound<f64> = Bound::new(0.0, 3.0, 0.0);
/// The light's per-view turn about world +z, uniform within ± this (degrees; 0: none).
pub const ROTATION_JITTER_DEG: Bound<f64> = Bound::new(0.0, 180.0, 0.0);
/// Each end of the light's colour temperature range (kelvin; 6504 is neutral daylight).
pub const TEMPERATURE_K: Bound<f64> = Bound::new(1667.0, 25_000.0, 6504.0);
pub const TEMPERATURE_K_DEFAULT: [f64; 2] = [6504.0, 6504.0];
/// The colour sensor's exposure error (standard deviation, EV).
pub const EXPOSURE_EV_SIGMA: Bound<f64> = Bound::new(0.0, 3.0, 0.2);
/// The white balance's error on red and blue (standard deviation of the log gain).
pub const WHITE_BALANCE_SIGMA: Bound<f64> = Bound::new(0.0, 0.5, 0.03);
/// Shot noise: variance per unit of linear signal (Brooks et al. 2019 fit 1e-4 to 1.2e-2).
pub const SHOT_NOISE: Bound<f64> = Bound::new(0.0, 0.1, 0.002);
/// Read noise: variance at zero signal (linear units).
pub const READ_NOISE: Bound<f64> = Bound::new(0.0, 0.01, 4.3e-6);
/// Each of Cycles' light-path caps.
pub const BOUNCES: Bound<u32> = Bound::new(0, 1024, 12);
/// An environment's turn about world +z (degrees) and strength.
pub const ROTATION_DEG: Bound<f64> = Bound::new(-360.0, 360.0, 0.0);
pub const STRENGTH: Bound<f64> = Bound::new(0.0, 1000.0, 1.0);
/// View indices: two digits in file names (`v00`…`v99`), so at most 100 views per grasp.
pub const VIEW_INDEX: Bound<u32> = Bound::new(0, 99, 0);
pub const MAX_VIEWS: u32 = VIEW_INDEX.max + 1;
/// The environment a view without one renders under.
pub const DEFAULT_ENVIRONMENT: &str = "studio";

/// A render task's parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
#[schemars(rename = "RenderParams")]
pub struct Params {
    pub grasp_index: u32,
    #[serde(default)]
    pub render: Settings,
    /// Environments the views name, with their turn and strength; a bundled HDRI not listed
    /// renders as is.
    #[serde(default)]
    pub environments: Vec<Environment>,
    /// The job's HDRI files the environments name (staged only when `rgb` is rendered).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub assets: Vec<Asset>,
    #[schemars(length(min = 1, max = MAX_VIEWS))]
    pub views: Vec<View>,
    /// What to render; depth, masks and segmentation are never path traced.
    #[serde(default = "RenderOutput::all")]
    pub outputs: Vec<RenderOutput>,
    /// How the depth images are stored (`contract::depth`): 16-bit PNG of 0.1 mm steps by default.
    #[serde(default)]
    pub depth_format: DepthFormat,
    /// The job's objects, which no distractor may be: an unannotated instance of an object the
    /// dataset annotates would teach a detector that it is background. Only with distractors.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub dataset_objects: Vec<String>,
}

/// Image size, sampling and camera placement, shared by every view of a task.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
#[schemars(rename = "RenderSettings")]
pub struct Settings {
    #[schemars(range(min = WIDTH_PX.min, max = WIDTH_PX.max))]
    pub width: u32,
    #[schemars(range(min = HEIGHT_PX.min, max = HEIGHT_PX.max))]
    pub height: u32,
    #[schemars(range(min = SAMPLES.min, max = SAMPLES.max))]
    pub samples: u32,
    /// OpenImageDenoise on the RGB image, guided by the albedo and normal passes; run by the
    /// engine outside Blender, so it is byte-reproducible (docs/rendering.md). On by default.
    pub denoise: bool,
    /// The firefly filter's threshold (share of full scale; 0: off).
    #[schemars(range(min = DESPECKLE.min, max = DESPECKLE.max))]
    pub despeckle: f64,
    /// Cycles' clamp on indirect light; 0 is off.
    #[schemars(range(min = CLAMP_INDIRECT.min, max = CLAMP_INDIRECT.max))]
    pub clamp_indirect: f64,
    pub bounces: Bounces,
    /// Lower the caps to what the scene's materials can use (exact); false only to measure it.
    pub prune_bounces: bool,
    #[schemars(range(min = FOV_DEG.min, max = FOV_DEG.max))]
    pub fov_deg: f64,
    /// The environment of views that name none.
    #[schemars(regex(pattern = r"^[a-z0-9_]{1,64}$"))]
    pub environment: String,
    /// Camera distance range, [min, max] (min ≤ max).
    #[schemars(inner(range(min = RADIUS_M.min, max = RADIUS_M.max)))]
    pub radius_m: [f64; 2],
    /// Camera elevation range, [min, max] (min ≤ max).
    #[schemars(inner(range(min = ELEVATION_DEG.min, max = ELEVATION_DEG.max)))]
    pub elevation_deg: [f64; 2],
    /// Camera roll range about the optical axis, [min, max] (min ≤ max); [0, 0] keeps world up
    /// as image up.
    #[schemars(inner(range(min = ROLL_DEG.min, max = ROLL_DEG.max)))]
    pub roll_deg: [f64; 2],
    /// How far off the image centre the object may be framed (fraction of the way to the edge).
    #[schemars(range(min = OFFCENTRE.min, max = OFFCENTRE.max))]
    pub offcentre: f64,
    /// Per-view spread of the focal length and principal point (σ, fraction; 0: nominal).
    #[schemars(range(min = INTRINSICS_JITTER.min, max = INTRINSICS_JITTER.max))]
    pub intrinsics_jitter: f64,
    /// Lens distortion, OpenCV's [k1, k2, p1, p2, k3]; all 0 (the default) is a pinhole. Left out
    /// of the parameters when 0, so a pinhole task's parameters are what they were before it.
    #[serde(skip_serializing_if = "is_pinhole")]
    #[schemars(schema_with = "distortion_schema")]
    pub distortion: [f64; 5],
    /// The range a sampled view's occlusion must fall in, [min, max] (min ≤ max): its camera is
    /// redrawn (seeded, bounded) until it does. A view with an explicit camera is not redrawn.
    #[schemars(inner(range(min = OCCLUSION.min, max = OCCLUSION.max)))]
    pub occlusion: [f64; 2],
    /// Which side of the palm a sampled camera may stand on.
    pub palm_side: PalmSide,
    /// What stands around the grasp.
    pub scene: Scene,
    /// The colour camera's sensor: exposure and white-balance errors, shot and read noise.
    pub sensor: Sensor,
    /// Per-view randomisation of the environment's strength, turn and colour temperature.
    pub light: Light,
}

/// Which side of the palm a sampled camera may stand on, judged by the palm normal (the palm
/// frame's +z, towards the object: docs/hands.md) at the palm link's origin.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum PalmSide {
    /// Anywhere the radius and elevation ranges allow.
    #[default]
    Any,
    /// In front of the palm's plane (never looking at the back of the hand): redrawn like an
    /// occlusion out of range.
    Front,
}

impl PalmSide {
    pub const ALL: [PalmSide; 2] = [PalmSide::Any, PalmSide::Front];
}

/// Per-view light randomisation (`vint_engines/render/lighting.py`), drawn from the view's seed:
/// off by default (every field at its neutral value).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
#[schemars(rename = "RenderLight")]
pub struct Light {
    #[schemars(range(min = STRENGTH_EV_SIGMA.min, max = STRENGTH_EV_SIGMA.max))]
    pub strength_ev_sigma: f64,
    #[schemars(range(min = ROTATION_JITTER_DEG.min, max = ROTATION_JITTER_DEG.max))]
    pub rotation_jitter_deg: f64,
    /// [min, max] (min ≤ max); [6504, 6504] keeps the environment's own colour.
    #[schemars(inner(range(min = TEMPERATURE_K.min, max = TEMPERATURE_K.max)))]
    pub temperature_k: [f64; 2],
}

impl Default for Light {
    fn default() -> Light {
        Light {
            strength_ev_sigma: STRENGTH_EV_SIGMA.default,
            rotation_jitter_deg: ROTATION_JITTER_DEG.default,
            temperature_k: TEMPERATURE_K_DEFAULT,
        }
    }
}

/// The colour sensor model applied to the path-traced image (`vint_engines/render/sensor.py`:
/// Poissonian-Gaussian noise in linear light, seeded by the view).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
#[schemars(rename = "RenderSensor")]
pub struct Sensor {
    /// false: the image as rendered (a perfect camera).
    pub enabled: bool,
    #[schemars(range(min = EXPOSURE_EV_SIGMA.min, max = EXPOSURE_EV_SIGMA.max))]
    pub exposure_ev_sigma: f64,
    #[schemars(range(min = WHITE_BALANCE_SIGMA.min, max = WHITE_BALANCE_SIGMA.max))]
    pub white_balance_sigma: f64,
    #[schemars(range(min = SHOT_NOISE.min, max = SHOT_NOISE.max))]
    pub shot_noise: f64,
    #[schemars(range(min = READ_NOISE.min, max = READ_NOISE.max))]
    pub read_noise: f64,
}

impl Default for Sensor {
    fn default() -> Sensor {
        Sensor {
            enabled: true,
            exposure_ev_sigma: EXPOSURE_EV_SIGMA.default,
            white_balance_sigma: WHITE_BALANCE_SIGMA.default,
            shot_noise: SHOT_NOISE.default,
            read_noise: READ_NOISE.default,
        }
    }
}

/// The scene around the grasp. The grasp itself happens in free space (`docs/physics.md`); these
/// pieces are seen by the camera (and by depth and segmentation), never by the physics.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
#[schemars(rename = "RenderScene")]
pub struct Scene {
    /// A wooden table top under the hand, catching its shadow.
    pub table: bool,
    /// The table top's gap below the lowest point of the hand, object and flange (m).
    #[schemars(range(min = TABLE_GAP_M.min, max = TABLE_GAP_M.max))]
    pub table_gap_m: f64,
    /// The robot arm's flange and last link at the hand's wrist.
    pub flange: bool,
    /// Catalog objects standing on the table around the grasp (needs the table). Left out of the
    /// task parameters when 0, so a task without them is the one planned before they existed.
    #[serde(skip_serializing_if = "is_zero")]
    #[schemars(range(min = DISTRACTORS.min, max = DISTRACTORS.max), extend("default" = 0))]
    pub distractors: u32,
}

impl Default for Scene {
    fn default() -> Scene {
        Scene { table: true, table_gap_m: TABLE_GAP_M.default, flange: true, distractors: DISTRACTORS.default }
    }
}

fn is_zero(count: &u32) -> bool {
    *count == 0
}

impl Default for Settings {
    fn default() -> Settings {
        Settings {
            width: WIDTH_PX.default,
            height: HEIGHT_PX.default,
            samples: SAMPLES.default,
            denoise: DENOISE,
            despeckle: DESPECKLE.default,
            clamp_indirect: CLAMP_INDIRECT.default,
            bounces: Bounces::default(),
            prune_bounces: true,
            fov_deg: FOV_DEG.default,
            environment: DEFAULT_ENVIRONMENT.to_string(),
            radius_m: RADIUS_M_DEFAULT,
            elevation_deg: ELEVATION_DEG_DEFAULT,
            roll_deg: ROLL_DEG_DEFAULT,
            offcentre: OFFCENTRE.default,
            intrinsics_jitter: INTRINSICS_JITTER.default,
            distortion: PINHOLE,
            occlusion: OCCLUSION_DEFAULT,
            palm_side: PalmSide::default(),
            scene: Scene::default(),
            sensor: Sensor::default(),
            light: Light::default(),
        }
    }
}

fn is_pinhole(distortion: &[f64; 5]) -> bool {
    *distortion == PINHOLE
}

/// `distortion`'s schema: five numbers, each within its own coefficient's bound, by default a
/// pinhole's (written here: a field skipped when at its default gets none from schemars).
fn distortion_schema(_: &mut schemars::SchemaGenerator) -> schemars::Schema {
    let items: Vec<serde_json::Value> = DISTORTION
        .iter()
        .map(|(name, b)| {
            serde_json::json!({"title": name, "type": "number", "format": "double", "minimum": b.min, "maximum": b.max})
        })
        .collect();
    schemars::json_schema!({
        "type": "array",
        "prefixItems": items,
        "items": false,
        "minItems": DISTORTION.len(),
        "maxItems": DISTORTION.len(),
        "default": PINHOLE,
    })
}

/// How far out a lens stays invertible: the largest distorted radius (normalised image
/// coordinates, |(x, y)| / z) its radial map r ↦ r·(1 + k1·r² + k2·r⁴ + k3·r⁶) reaches while its
/// slope stays at least `MIN_RADIAL_SLOPE`, looking no further than `out_to` (returned when the
/// map gets there). A view is resampled only from a lens whose reach covers the image's corners;
/// the spec checks the nominal intrinsics with this, the renderer each view's own
/// (`vint_engines/render/lens.py`, tangential terms included).
pub fn radial_reach(distortion: &[f64; 5], out_to: f64) -> f64 {
    let [k1, k2, _, _, k3] = *distortion;
    let radius = |r: f64| r * (1.0 + r * r * (k1 + r * r * (k2 + r * r * k3)));
    let slope = |r: f64| 1.0 + r * r * (3.0 * k1 + r * r * (5.0 * k2 + r * r * 7.0 * k3));
    // While the slope stays above MIN_RADIAL_SLOPE the map passes `out_to` before
    // r = out_to / MIN_RADIAL_SLOPE: a bounded walk, in steps fine enough for a degree-6 slope.
    if !(out_to > 0.0 && out_to.is_finite()) {
        return out_to;
    }
    let step = out_to / RADIAL_STEPS;
    let mut r = 0.0;
    while r <= out_to / MIN_RADIAL_SLOPE {
        if slope(r) < MIN_RADIAL_SLOPE {
            return radius(r).min(out_to);
        }
        if radius(r) >= out_to {
            break;
        }
        r += step;
    }
    out_to
}

/// The least slope of a lens's radial map over the image (`radial_reach`): 0 is where the map
/// folds back (no longer invertible); above it, a distorted pixel stands for at most
/// 1 / `MIN_RADIAL_SLOPE` undistorted ones along a radius, so the pinhole canvas a view is
/// resampled from stays within a few times the image and its corners keep detail to resample.
pub const MIN_RADIAL_SLOPE: f64 = 0.2;
const RADIAL_STEPS: f64 = 4096.0;

/// Cycles' light-path caps (Cycles' defaults); volume bounces are always 0.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct Bounces {
    #[schemars(range(min = BOUNCES.min, max = BOUNCES.max))]
    pub total: u32,
    #[schemars(range(min = BOUNCES.min, max = BOUNCES.max))]
    pub diffuse: u32,
    #[schemars(range(min = BOUNCES.min, max = BOUNCES.max))]
    pub glossy: u32,
    #[schemars(range(min = BOUNCES.min, max = BOUNCES.max))]
    pub transmission: u32,
    #[schemars(range(min = BOUNCES.min, max = BOUNCES.max))]
    pub transparent: u32,
}

impl Default for Bounces {
    fn default() -> Bounces {
        Bounces { total: 12, diffuse: 4, glossy: 4, transmission: 12, transparent: 8 }
    }
}

/// An HDRI, turned about world +z and scaled in strength: a bundled one by name, or a user's file
/// (`asset`, its SHA-256) under a name no bundled one has.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Environment {
    #[schemars(regex(pattern = r"^[a-z0-9_]{1,64}$"))]
    pub name: String,
    #[serde(default)]
    #[schemars(range(min = ROTATION_DEG.min, max = ROTATION_DEG.max))]
    pub rotation_deg: f64,
    #[serde(default = "default_strength")]
    #[schemars(range(min = STRENGTH.min, max = STRENGTH.max))]
    pub strength: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schemars(regex(pattern = r"^[0-9a-f]{64}$"))]
    pub asset: Option<String>,
}

fn default_strength() -> f64 {
    STRENGTH.default
}

/// One view: its index, the seed of its camera and sampling, its environment, and optionally an
/// explicit camera instead of a sampled one.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct View {
    #[schemars(range(min = VIEW_INDEX.min, max = VIEW_INDEX.max))]
    pub view_index: u32,
    #[schemars(range(max = SEED_MAX))]
    pub seed: u64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schemars(regex(pattern = r"^[a-z0-9_]{1,64}$"))]
    pub environment: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<Camera>,
}

/// A world-to-camera transform in the OpenCV convention (`R_w2c` must be a rotation).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
#[allow(non_snake_case)]
pub struct Camera {
    pub R_w2c: [[f64; 3]; 3],
    pub t_w2c: [f64; 3],
}

/// What a render task can produce for each view.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum RenderOutput {
    /// Path traced 8-bit sRGB image.
    Rgb,
    /// Depth along the optical axis (metres; stored as `Params::depth_format` says).
    Depth,
    /// The object's visible and full masks.
    Mask,
    /// Instance segmentation (background, object, hand links).
    Segmentation,
}

impl RenderOutput {
    pub const ALL: [RenderOutput; 4] =
        [RenderOutput::Rgb, RenderOutput::Depth, RenderOutput::Mask, RenderOutput::Segmentation];

    pub fn all() -> Vec<RenderOutput> {
        RenderOutput::ALL.to_vec()
    }

    /// The files this output adds to each view, depth stored as `depth`.
    pub fn view_files(self, depth: DepthFormat) -> &'static [ViewFile] {
        match self {
            RenderOutput::Rgb => &[ViewFile::Rgb],
            RenderOutput::Depth => match depth {
                DepthFormat::Png => &[ViewFile::Depth(DepthFormat::Png)],
                DepthFormat::Npy => &[ViewFile::Depth(DepthFormat::Npy)],
            },
            RenderOutput::Mask => &[ViewFile::Mask, ViewFile::MaskFull],
            RenderOutput::Segmentation => &[ViewFile::Segmentation],
        }
    }
}

/// The files a render task asked for `outputs` writes per view: theirs (depth stored as `depth`)
/// and the camera record.
pub fn view_files(outputs: &[RenderOutput], depth: DepthFormat) -> Vec<ViewFile> {
    std::iter::once(ViewFile::Camera).chain(outputs.iter().flat_map(|o| o.view_files(depth).iter().copied())).collect()
}

/// A file a render task writes for each view `v`: `v{NN}_{suffix}`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ViewFile {
    Rgb,
    Depth(DepthFormat),
    Mask,
    MaskFull,
    Segmentation,
    /// Always written: intrinsics, extrinsics, visibility, segmentation ids, environment.
    Camera,
}

impl ViewFile {
    fn suffix(self) -> &'static str {
        match self {
            ViewFile::Rgb => "rgb.png",
            ViewFile::Depth(DepthFormat::Png) => "depth.png",
            ViewFile::Depth(DepthFormat::Npy) => "depth.npy",
            ViewFile::Mask => "mask.png",
            ViewFile::MaskFull => "mask_full.png",
            ViewFile::Segmentation => "segmentation.png",
            ViewFile::Camera => "camera.json",
        }
    }

    /// The file's name for view `view` (`v03_depth.png`).
    pub fn name(self, view: u32) -> String {
        format!("v{view:02}_{}", self.suffix())
    }
}

/// The key of the render task of grasp `grasp_index` of (object, hand).
pub fn task_key(object: &str, hand: &str, grasp_index: u32) -> String {
    format!("render/{object}/{hand}/g{grasp_index:06}")
}

/// A render task reads its grasp chunk's poses and hand geometry and the object's model mesh;
/// never the touch readings (the bulk of a chunk's output), which only the package stage reads.
pub fn reads(file: &str) -> bool {
    file == GRASPS_FILE || file == MODEL_FILE
}

/// What a render engine answers.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct RenderResult {
    /// Views rendered.
    pub views: u32,
    /// The device Cycles rendered on (`CPU`, `OPTIX`, `CUDA`).
    pub device: String,
    /// Each view's occlusion, in the order of the task's views: the share of the object the hand
    /// hides, 1 when none of it is in view (`occlusion` of the view's camera record). Empty from
    /// an engine that does not report it (the timing-only worker renders nothing).
    #[serde(default)]
    pub occlusion: Vec<f64>,
}

/// Bytes per pixel of each image file. docs/benchmarks.md, "Output size per sample": medians of
/// tiny.toml's 30 samples (128×128, 16 spp; 2026-11-29). An RGB PNG shrinks as samples per pixel
/// rise (less noise to compress).
pub const RGB_BYTES_PER_PIXEL: f64 = 2.1; // rgb.png, median 34 372 B
pub const MASKS_BYTES_PER_PIXEL: f64 = 0.049; // mask.png + mask_full.png, 396 + 402 B
pub const SEGMENTATION_BYTES_PER_PIXEL: f64 = 0.052; // segmentation.png, 859 B
/// A view's `camera.json`: the median of the same 30 (`scripts/measure_db_bytes.py` prints them).
pub const CAMERA_JSON_BYTES: f64 = 2_204.0;
/// A float32 `.npy` depth image (clean or noisy): 4 bytes a pixel and its header, 65 664 B at
/// 128×128.
pub const NPY_DEPTH_BYTES_PER_PIXEL: f64 = 4.0;
/// A `.npy` file's header before its float32 data.
pub const NPY_HEADER_BYTES: u64 = 128;

/// A 16-bit PNG depth image's size. Its bytes per pixel fall as the image grows (a surface spans
/// more pixels between its edges), so they follow a power law through two measurements of the
/// engines' files (docs/benchmarks.md, "Depth as PNG"; medians of 30 views each): tiny.toml at
/// 128×128, and the same grasps at the recipe's 640×480 camera. Never above 2 (the raw 16 bits).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PngDepthSize {
    /// Bytes per pixel at 128×128.
    pub at_128x128: f64,
    /// Bytes per pixel at 640×480.
    pub at_640x480: f64,
}

/// A clean depth image: smooth surfaces and a background of zeros compress well (median 6,024 B at
/// 128×128, 46,510 B at 640×480).
pub const PNG_DEPTH: PngDepthSize = PngDepthSize { at_128x128: 0.368, at_640x480: 0.151 };
/// A noisy depth image: the sensor's noise is what zlib cannot compress (median 18,867 B at
/// 128×128, 221,064 B at 640×480).
pub const PNG_NOISY_DEPTH: PngDepthSize = PngDepthSize { at_128x128: 1.152, at_640x480: 0.720 };

impl PngDepthSize {
    const SMALL_PX: f64 = 128.0 * 128.0;
    const LARGE_PX: f64 = 640.0 * 480.0;

    fn exponent(self) -> f64 {
        (self.at_640x480 / self.at_128x128).ln() / (Self::LARGE_PX / Self::SMALL_PX).ln()
    }

    pub fn bytes_per_pixel(self, pixels: f64) -> f64 {
        (self.at_128x128 * (pixels.max(1.0) / Self::SMALL_PX).powf(self.exponent())).min(2.0)
    }

    /// The pixels of an image of `bytes`: `bytes_per_pixel` inverted (below its cap of 2).
    pub fn pixels_of(self, bytes: f64) -> f64 {
        let unit = self.at_128x128 * Self::SMALL_PX;
        Self::SMALL_PX * (bytes.max(1.0) / unit).powf(1.0 / (1.0 + self.exponent()))
    }
}

/// Bytes per pixel of a clean depth image of `pixels` stored as `depth`.
pub fn depth_bytes_per_pixel(depth: DepthFormat, pixels: f64) -> f64 {
    match depth {
        DepthFormat::Png => PNG_DEPTH.bytes_per_pixel(pixels),
        DepthFormat::Npy => NPY_DEPTH_BYTES_PER_PIXEL,
    }
}

/// Bytes per pixel of a noisy depth image of `pixels` stored as `depth`.
pub fn noisy_depth_bytes_per_pixel(depth: DepthFormat, pixels: f64) -> f64 {
    match depth {
        DepthFormat::Png => PNG_NOISY_DEPTH.bytes_per_pixel(pixels),
        DepthFormat::Npy => NPY_DEPTH_BYTES_PER_PIXEL,
    }
}

impl RenderOutput {
    /// Bytes per pixel of the files this output adds to a view of `pixels`, depth stored as `depth`.
    pub fn bytes_per_pixel(self, depth: DepthFormat, pixels: f64) -> f64 {
        match self {
            RenderOutput::Rgb => RGB_BYTES_PER_PIXEL,
            RenderOutput::Depth => depth_bytes_per_pixel(depth, pixels),
            RenderOutput::Mask => MASKS_BYTES_PER_PIXEL,
            RenderOutput::Segmentation => SEGMENTATION_BYTES_PER_PIXEL,
        }
    }
}

impl ViewFile {
    /// The file's size at `pixels` pixels per image, as measured.
    pub fn bytes(self, pixels: u64) -> u64 {
        let px = pixels as f64;
        let bytes = match self {
            ViewFile::Rgb => RGB_BYTES_PER_PIXEL * px,
            ViewFile::Depth(DepthFormat::Npy) => return 4 * pixels + NPY_HEADER_BYTES,
            ViewFile::Depth(DepthFormat::Png) => PNG_DEPTH.bytes_per_pixel(px) * px,
            ViewFile::Mask | ViewFile::MaskFull => MASKS_BYTES_PER_PIXEL / 2.0 * px,
            ViewFile::Segmentation => SEGMENTATION_BYTES_PER_PIXEL * px,
            ViewFile::Camera => CAMERA_JSON_BYTES,
        };
        bytes.round().max(1.0) as u64
    }

    pub fn kind(self) -> super::FileKind {
        match self {
            ViewFile::Depth(DepthFormat::Npy) => super::FileKind::Npy,
            ViewFile::Camera => super::FileKind::Json,
            _ => super::FileKind::Png,
        }
    }
}

/// A render task writes its outputs' files and a camera record for every view.
pub fn files_written(task: &Params) -> u64 {
    (task.views.len() * view_files(&task.outputs, task.depth_format).len()) as u64
}

/// Path tracing per pixel and sample, with the default scene (the table fills most of the image
/// with a diffuse surface that shades and bounces where the bare HDRI background only looked up
/// a colour: ~2.5–3× the bare scene's cost at 640×480, `benches/scene_cost.py`). Calibrated on
/// tiny.toml (128×128, 16 raw spp, the default scene): ~0.59 CPU-s per view in all, of which the
/// fixed and geometry parts ~0.11 s, leaving ~0.47 s for 262 144 pixel-samples.
const S_PER_PIXEL_SAMPLE: f64 = 1.8e-6;
/// The geometry passes (depth, masks, segmentation) per pixel: the same table's 217 ms for
/// 307 200 px without path tracing.
const S_PER_PIXEL: f64 = 0.7e-6;
/// Per view whatever the size (camera and scene updates, the object-alone pass).
/// docs/benchmarks.md, "tiny.toml": 72 views at 128×128 / 16 spp in ~270 ms each, of which the two
/// rates above accounted for ~160 ms.
const S_PER_VIEW: f64 = 0.1;
/// OpenImageDenoise (the engine's own call, with Cycles' albedo and normal passes) per view and
/// per pixel: 1.6 s for a 640×480 image on one thread and 0.09 s for 128×128 (timed beside a
/// render study), and tiny.toml's 60 views cost 53.6 CPU-s with it against 43.9 without (~0.16 s
/// a view with the passes and their files).
const DENOISE_S_PER_VIEW: f64 = 0.075;
const DENOISE_S_PER_PIXEL: f64 = 5.2e-6;

/// CPU seconds one view of `task` costs: the geometry passes always, path tracing (and the
/// denoiser) only when RGB is asked for.
pub fn s_per_view(task: &Params) -> f64 {
    let pixels = f64::from(task.render.width) * f64::from(task.render.height);
    let mut per_view = S_PER_VIEW + S_PER_PIXEL * pixels;
    if task.outputs.contains(&RenderOutput::Rgb) {
        per_view += S_PER_PIXEL_SAMPLE * pixels * f64::from(task.render.samples);
        if task.render.denoise {
            per_view += DENOISE_S_PER_VIEW + DENOISE_S_PER_PIXEL * pixels;
        }
    }
    per_view
}

/// Every view of every grasp rendered; the outputs it is asked for (the segmentation the noise
/// model reads included) and a camera record per view stored.
pub fn cost(work: &super::Workload, task: &Params) -> super::Cost {
    let views = work.samples as f64;
    let bytes_per_pixel: f64 = task.outputs.iter().map(|o| o.bytes_per_pixel(task.depth_format, work.pixels)).sum();
    super::Cost { cpu_s: s_per_view(task) * views, bytes: views * (bytes_per_pixel * work.pixels + CAMERA_JSON_BYTES) }
}

/// The timing-only answer: every view's files at their measured sizes.
pub fn fake(task: &Params) -> (RenderResult, Vec<super::FakeFile>) {
    let pixels = u64::from(task.render.width) * u64::from(task.render.height);
    let files = task
        .views
        .iter()
        .flat_map(|view| {
            view_files(&task.outputs, task.depth_format).into_iter().map(move |file| super::FakeFile {
                name: file.name(view.view_index),
                kind: file.kind(),
                size: file.bytes(pixels),
            })
        })
        .collect();
    let result =
        RenderResult { views: task.views.len() as u32, device: super::TIMING_ONLY.into(), occlusion: Vec::new() };
    (result, files)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn view_files_reproduce_the_measured_tiny_sizes() {
        let px = 128 * 128;
        assert_eq!(ViewFile::Depth(DepthFormat::Npy).bytes(px), 65_664, "a 128×128 float32 .npy");
        let png = ViewFile::Depth(DepthFormat::Png).bytes(px) as f64;
        assert!((png - 6_024.0).abs() / 6_024.0 < 0.01, "{png}");
        let vga = 640 * 480;
        let png = ViewFile::Depth(DepthFormat::Png).bytes(vga) as f64;
        assert!((png - 46_510.0).abs() / 46_510.0 < 0.01, "{png}");
        let noisy = PNG_NOISY_DEPTH.bytes_per_pixel(vga as f64) * vga as f64;
        assert!((noisy - 221_064.0).abs() / 221_064.0 < 0.01, "{noisy}");
        for pixels in [16.0 * 16.0, 1e4, 1e6, 8192.0 * 8192.0] {
            for size in [PNG_DEPTH, PNG_NOISY_DEPTH] {
                let bytes = size.bytes_per_pixel(pixels);
                assert!(bytes > 0.0 && bytes <= 2.0, "{pixels}: {bytes}");
                if bytes < 2.0 {
                    let back = size.pixels_of(bytes * pixels);
                    assert!((back / pixels - 1.0).abs() < 1e-9, "{pixels} → {back}");
                }
            }
        }
        let rgb = ViewFile::Rgb.bytes(px) as f64;
        assert!((rgb - 34_372.0).abs() / 34_372.0 < 0.02, "{rgb}");
        assert_eq!(ViewFile::Camera.bytes(px), ViewFile::Camera.bytes(4 * px));
        assert!(ViewFile::Mask.bytes(16) >= 1, "no empty file, however small the image");
    }

    #[test]
    fn a_view_writes_its_camera_record_and_the_files_of_each_output() {
        let png = DepthFormat::Png;
        assert_eq!(view_files(&[], png), [ViewFile::Camera]);
        assert_eq!(
            view_files(&[RenderOutput::Rgb, RenderOutput::Mask], png),
            [ViewFile::Camera, ViewFile::Rgb, ViewFile::Mask, ViewFile::MaskFull]
        );
        assert_eq!(view_files(&RenderOutput::all(), png).len(), 6, "what the tiny run's render tasks write per view");
        assert_eq!(ViewFile::Depth(png).name(3), "v03_depth.png");
        assert_eq!(view_files(&[RenderOutput::Depth], DepthFormat::Npy)[1].name(3), "v03_depth.npy");
    }

    #[test]
    fn a_pinhole_task_leaves_distortion_out_of_its_parameters_and_reads_back_a_pinhole() {
        let pinhole = serde_json::to_value(Settings::default()).expect("serializes");
        assert!(pinhole.get("distortion").is_none(), "the parameters of a pinhole task are as before");
        let back: Settings = serde_json::from_value(pinhole).expect("deserializes");
        assert_eq!(back.distortion, PINHOLE);
        let lens = Settings { distortion: [-0.2, 0.05, 0.001, 0.0, 0.0], ..Settings::default() };
        let written = serde_json::to_value(&lens).expect("serializes");
        assert_eq!(written["distortion"], serde_json::json!([-0.2, 0.05, 0.001, 0.0, 0.0]));
    }

    #[test]
    fn a_lens_reaches_as_far_as_its_radial_map_keeps_growing() {
        assert_eq!(radial_reach(&PINHOLE, 0.72), 0.72);
        assert_eq!(radial_reach(&[0.5, 0.2, 0.1, -0.1, 0.1], 3.0), 3.0, "pincushion never folds");
        // k1 = -0.3: slope 1 - 0.9 r² reaches MIN_RADIAL_SLOPE at r = 0.943, where the map is at
        // 0.691 — short of a 640×480 60° image's corners (0.722), beyond a 50° one's (0.583).
        let barrel = [-0.3, 0.0, 0.0, 0.0, 0.0];
        let reach = radial_reach(&barrel, 0.722);
        assert!((reach - 0.6914).abs() < 1e-3, "{reach}");
        assert_eq!(radial_reach(&barrel, 0.583), 0.583);
        // k2 > 0 straightens it out again.
        assert_eq!(radial_reach(&[-0.3, 0.1, 0.0, 0.0, 0.0], 0.722), 0.722);
    }
}
