//! The dataset spec: its TOML schema, defaults and validation.
//!
//! Parsing walks the TOML tree by hand instead of deriving `Deserialize`, so that one pass reports
//! *every* problem — wrong types, unknown keys, out-of-range values — each with its field path, the
//! value found and the rule it breaks, e.g. `render.resolution[0]: must be 16..=8192, got 0`.
//! (serde with `deny_unknown_fields` and `serde_path_to_error` stops at the first error; `garde` or
//! `validator` check ranges only once deserialization has succeeded, so type errors and unknown
//! keys would still come one run at a time.) Every bound and default of a field that becomes a
//! task parameter is a constant of the stage contracts (`crate::contract`), so a spec that parses
//! yields parameters every engine accepts; `number_fields` lists the number fields for the tests
//! that prove it. A spec that parses is valid; nothing downstream re-checks it.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt;

use serde::Serialize;
use toml::{Table, Value};

use crate::asset::{self, AssetUse};
use crate::budget::PairBudget;
use crate::catalog;
use crate::contract::depth::{self, DepthFormat};
use crate::contract::package::Modality;
use crate::contract::render::{self as render_contract, Bounces};
use crate::contract::{Bound, grasp, noise, object};
use crate::split::{self, SplitSettings};

use crate::suggest;

/// A validated dataset spec.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DatasetSpec {
    pub dataset: DatasetSection,
    pub hands: Vec<String>,
    pub objects: Vec<String>,
    /// The spec's own hands (`[hand.NAME]` tables), by name; `hands` may list them.
    pub hand_defs: BTreeMap<String, UserHand>,
    /// The spec's own mesh objects (`[object.NAME]` tables), by name; `objects` may list them.
    pub object_defs: BTreeMap<String, UserObject>,
    pub grasp: GraspSettings,
    pub touch: TouchSettings,
    pub render: RenderSettings,
    pub noise: NoiseSettings,
    pub outputs: Outputs,
    /// `[split]`: how exports deal grasps into train/val/test.
    pub split: SplitSettings,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DatasetSection {
    pub name: String,
    /// Root of every random stream (see `seed`).
    pub seed: u64,
}

/// `[noise]`: the sensor model the noise tasks apply, and whether cameras may stand closer than
/// the mode's minimum range.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct NoiseSettings {
    #[serde(flatten)]
    pub model: noise::NoiseModel,
    /// Accept `render.radius_m` below the mode's minimum range (those readings come out invalid).
    pub ignore_min_range: bool,
}

/// A user's hand: an MJCF model following `docs/hands.md`, its taxel layout (the format of
/// `catalog/hands/*/taxels.csv`) and the mesh files the MJCF refers to. Paths are relative to the
/// spec file.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct UserHand {
    pub mjcf: String,
    pub taxels: String,
    /// The MJCF's mesh files (`asset::HAND_MESH_EXTENSIONS`), as MuJoCo finds them from the MJCF
    /// (its `meshdir`), written relative to the spec file: they travel to its grasp tasks.
    pub files: Vec<String>,
}

/// A user's object: a triangle mesh file (OBJ, STL, PLY, glTF or GLB; convex-decomposed for
/// collision), the files it refers to (an OBJ's MTL and the textures, a PLY's `TextureFile`, a
/// glTF's buffers and images) and the catalog tags the built-in objects carry. Paths are relative
/// to the spec file.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct UserObject {
    pub mesh: String,
    /// The mesh's sidecar files (`asset::SIDECAR_EXTENSIONS`): they travel with it to the render
    /// tasks, which texture the object from them.
    pub files: Vec<String>,
    /// Length unit of the mesh file's coordinates: one of `MESH_UNITS`.
    pub unit: String,
    pub mass_kg: f64,
    pub material: object::Material,
    pub symmetry: object::Symmetry,
    /// The object's BOP `obj_id` when it is a BOP dataset's model (`object::BOP_OBJ_ID`), which the
    /// exports keep; absent, they number it from `catalog::USER_OBJECT_IDS`.
    pub obj_id: Option<u32>,
    /// Symmetry sets given in BOP's `models_info.json` form (metres), as `vintctl bop-objects`
    /// writes them; absent, `symmetry` says them.
    pub symmetries: Option<(Vec<object::ContinuousSymmetry>, Vec<object::DiscreteSymmetry>)>,
}

/// Length units a mesh file may be in, with their size in metres.
pub const MESH_UNITS: &[(&str, f64)] = &[("m", 1.0), ("cm", 0.01), ("mm", 0.001)];

impl UserObject {
    /// The object's symmetry sets (continuous, discrete): the explicit ones, else `symmetry`'s.
    pub fn symmetry_sets(&self) -> (Vec<object::ContinuousSymmetry>, Vec<object::DiscreteSymmetry>) {
        self.symmetries.clone().unwrap_or_else(|| self.symmetry.expand())
    }

    /// File units to metres.
    pub fn scale(&self) -> f64 {
        MESH_UNITS.iter().find(|(u, _)| *u == self.unit).map_or(1.0, |(_, s)| *s)
    }
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct GraspSettings {
    /// Grasp trials per (object, hand) pair; only accepted ones become samples. With
    /// `accepted_per_pair`, the most trials a pair may run.
    pub trials_per_pair: u32,
    /// Stop each pair at this many accepted grasps (the paper's 2,500); absent: run every trial.
    pub accepted_per_pair: Option<u32>,
    /// Trials per grasp-sim task (and so per packaging shard).
    pub chunk_size: u32,
    pub timestep_s: f64,
    pub lift_height_m: f64,
    pub hold_s: f64,
    /// A grasp holds when the object moves less than this relative to the palm while lifted.
    pub max_drop_m: f64,
    /// Palm standoff before closing, as [min, max] fractions of the hand's longest finger.
    pub standoff_ratio: [f64; 2],
    /// Shake test after the hold: peak acceleration (0 disables it), directions and duration.
    pub shake_accel_mps2: f64,
    pub shake_directions: u32,
    pub shake_duration_s: f64,
    /// Which grasps are kept (`power`, the paper's, `precision` or `any`).
    pub r#type: grasp::GraspType,
}

/// The tactile sensor model (see `vint_engines/grasp/touch.py`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TouchSettings {
    /// A taxel of a link in contact touches the object, and shares the link's contact force,
    /// within this distance of its surface.
    pub contact_margin_m: f64,
    /// Time over which contact forces are averaged (s).
    pub contact_window_s: f64,
    /// Local force below which a taxel reads nothing (N).
    pub activation_force_n: f64,
    /// Local force at which a new taxel reads half its gain (N).
    pub half_force_n: f64,
    /// Power law of the response in force.
    pub response_exponent: f64,
    /// Log-normal spread of per-taxel gains (a property of the sensor, fixed per hand).
    pub gain_sigma: f64,
    /// The range each grasp's aging is drawn from, [min, max]: the sensitivity left, 1 a new
    /// sensor. A single number `x` in the spec means `[x, x]` (every grasp the same).
    pub aging: [f64; 2],
    /// σ (m) of each taxel's placement deviation in its surface's tangent plane, per hand instance.
    pub position_sigma_m: f64,
    /// A grasp needs at least this many active taxels to be accepted.
    pub min_active_taxels: u32,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RenderSettings {
    /// [width, height] in pixels.
    pub resolution: [u32; 2],
    /// Cycles samples per pixel (of the RGB image; depth, masks and segmentation are not path traced).
    /// Default 32 with the denoiser: the cheapest setting whose foreground reaches 35 dB median PSNR
    /// at 640×480 over the render study's objects (docs/studies/render/render_study.md).
    pub samples: u32,
    /// OpenImageDenoise on the RGB image (guided by albedo and normals): what reaches 35 dB on the
    /// foreground; on by default (docs/rendering.md).
    pub denoise: bool,
    /// The firefly filter's threshold (share of full scale; 0: off).
    pub despeckle: f64,
    /// Cycles' clamp on indirect light (0: off).
    pub clamp_indirect: f64,
    /// Light-path caps; the renderer lowers them to what the scene's materials can use.
    pub bounces: Bounces,
    /// Views rendered under each environment: a grasp has `views_per_environment × environments`
    /// views, view `v` under `environments[v / views_per_environment]`.
    pub views_per_environment: u32,
    pub environments: Vec<Environment>,
    /// Horizontal field of view.
    pub fov_deg: f64,
    /// Camera distance range from the object.
    pub radius_m: [f64; 2],
    /// Camera elevation range above the horizontal plane.
    pub elevation_deg: [f64; 2],
    /// Camera roll range about the optical axis.
    pub roll_deg: [f64; 2],
    /// How far off the image centre the object may be framed (fraction of the way to the edge).
    pub offcentre: f64,
    /// Per-view spread of the focal length and principal point (σ; 0 keeps the nominal pinhole).
    pub intrinsics_jitter: f64,
    /// Lens distortion, OpenCV's [k1, k2, p1, p2, k3]; all 0 (the default) is a pinhole.
    pub distortion: [f64; 5],
    /// The range a sampled view's occlusion must fall in; its camera is redrawn until it does.
    pub occlusion: [f64; 2],
    /// Which side of the palm a sampled camera may stand on.
    pub palm_side: render_contract::PalmSide,
    /// The table and the arm's flange around the grasp (`[render.scene]`).
    pub scene: render_contract::Scene,
    /// The colour camera's sensor model (`[render.sensor]`).
    pub sensor: render_contract::Sensor,
    /// Per-view light randomisation (`[render.light]`).
    pub light: render_contract::Light,
}

/// Views of one grasp at most: view ids are two digits (`v00`..`v99`).
pub const MAX_VIEWS_PER_GRASP: u32 = render_contract::MAX_VIEWS;
/// Grasp trials per (object, hand) pair.
pub const TRIALS_PER_PAIR: Bound<u32> = Bound::new(1, 1_000_000, 8);
/// Accepted grasps a pair stops at (`grasp.accepted_per_pair`; the default is only the value the
/// contract tests try: absent, there is no quota). VinT-Sim has 2,500 per (object, hand).
pub const ACCEPTED_PER_PAIR: Bound<u32> = Bound::new(1, 1_000_000, 2_500);
/// Views under each environment.
pub const VIEWS_PER_ENVIRONMENT: Bound<u32> = Bound::new(1, MAX_VIEWS_PER_GRASP, 2);
/// The spec's shake acceleration: 0 (the default) disables the shake test.
pub const SHAKE_ACCEL_MPS2: Bound<f64> = Bound::new(0.0, grasp::SHAKE_ACCEL_MPS2.max, 0.0);

impl GraspSettings {
    /// How each (object, hand) pair's trials split into grasp-sim tasks.
    pub fn budget(&self) -> PairBudget {
        PairBudget { trials: self.trials_per_pair, accepted: self.accepted_per_pair, chunk_size: self.chunk_size }
    }
}

impl RenderSettings {
    pub fn views_per_grasp(&self) -> u32 {
        self.views_per_environment * self.environments.len() as u32
    }

    /// The environment view `v` of a grasp is rendered under.
    pub fn environment_of_view(&self, v: u32) -> &Environment {
        &self.environments[(v / self.views_per_environment) as usize % self.environments.len()]
    }
}

/// An HDRI environment, turned about world +z (counter-clockwise seen from above) and scaled in
/// strength: a bundled one by name (`catalog::ENVIRONMENTS`), or the user's own `.hdr`/`.exr`
/// file under a name of the spec's choosing.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Environment {
    pub name: String,
    pub rotation_deg: f64,
    pub strength: f64,
    /// The user's HDRI file (its field and path relative to the spec); `None` for a bundled one.
    #[serde(skip_serializing_if = "Option::is_none", serialize_with = "serialize_file")]
    pub file: Option<AssetUse>,
}

impl Environment {
    pub fn bundled(name: &str) -> Environment {
        Environment { name: name.to_string(), rotation_deg: 0.0, strength: 1.0, file: None }
    }
}

/// An environment's file serializes as its path, as the spec writes it.
fn serialize_file<S: serde::Serializer>(file: &Option<AssetUse>, s: S) -> Result<S::Ok, S::Error> {
    match file {
        Some(f) => s.serialize_str(&f.path),
        None => s.serialize_none(),
    }
}

/// Extensions of the HDRI files a spec may name (Radiance RGBE and OpenEXR).
pub const HDRI_EXTENSIONS: &[&str] = &["hdr", "exr"];

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Outputs {
    pub modalities: Vec<Modality>,
    /// How depth and noisy depth are stored: 16-bit PNG of 0.1 mm steps (the default) or float32
    /// `.npy` (`contract::depth`).
    pub depth_format: DepthFormat,
}

impl Outputs {
    pub fn wants(&self, modality: Modality) -> bool {
        self.modalities.contains(&modality)
    }
}

/// A number field of the spec and its bounds: what the reader below enforces, listed so that
/// tests can set every field to its extremes (`tests/tests/contract.rs`). Paths use `*` for a
/// name of the spec's own (`object.*.mass_kg`), `[*]` for every entry of a list of tables and
/// `[i]` for one entry of a fixed-length list whose entries have bounds of their own
/// (`render.distortion[2]`: the others keep their defaults).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NumberField {
    pub path: &'static str,
    pub bounds: NumberBounds,
    /// A `[low, high]` or `[x, y]` pair rather than a single number.
    pub pair: bool,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum NumberBounds {
    Float(Bound<f64>),
    Integer(Bound<i64>),
}

/// Every number field of the spec (see `NumberField`).
pub fn number_fields() -> Vec<NumberField> {
    let float = |path, b: Bound<f64>| NumberField { path, bounds: NumberBounds::Float(b), pair: false };
    let count = |path, b: Bound<u32>| NumberField {
        path,
        bounds: NumberBounds::Integer(Bound::new(i64::from(b.min), i64::from(b.max), i64::from(b.default))),
        pair: false,
    };
    let pair = |field: NumberField| NumberField { pair: true, ..field };
    let bounces = Bounces::default();
    let cap = |path, default: u32| count(path, Bound { default, ..render_contract::BOUNCES });
    vec![
        NumberField { path: "dataset.seed", bounds: NumberBounds::Integer(Bound::new(0, i64::MAX, 0)), pair: false },
        count("grasp.trials_per_pair", TRIALS_PER_PAIR),
        count("grasp.accepted_per_pair", ACCEPTED_PER_PAIR),
        count("grasp.chunk_size", grasp::TRIALS_PER_TASK),
        float("grasp.timestep_s", grasp::TIMESTEP_S),
        float("grasp.lift_height_m", grasp::LIFT_HEIGHT_M),
        float("grasp.hold_s", grasp::HOLD_S),
        float("grasp.max_drop_m", grasp::MAX_DROP_M),
        pair(float("grasp.standoff_ratio", grasp::STANDOFF_RATIO)),
        float("grasp.shake_accel_mps2", SHAKE_ACCEL_MPS2),
        count("grasp.shake_directions", grasp::SHAKE_DIRECTIONS),
        float("grasp.shake_duration_s", grasp::SHAKE_DURATION_S),
        float("touch.contact_margin_m", grasp::CONTACT_MARGIN_M),
        float("touch.contact_window_s", grasp::CONTACT_WINDOW_S),
        float("touch.activation_force_n", grasp::ACTIVATION_FORCE_N),
        float("touch.half_force_n", grasp::HALF_FORCE_N),
        float("touch.response_exponent", grasp::RESPONSE_EXPONENT),
        float("touch.gain_sigma", grasp::GAIN_SIGMA),
        pair(float("touch.aging", grasp::AGING)),
        float("touch.position_sigma_m", grasp::POSITION_SIGMA_M),
        count("touch.min_active_taxels", grasp::MIN_ACTIVE_TAXELS),
        pair(count("render.resolution", render_contract::WIDTH_PX)),
        count("render.samples", render_contract::SAMPLES),
        cap("render.bounces.total", bounces.total),
        cap("render.bounces.diffuse", bounces.diffuse),
        cap("render.bounces.glossy", bounces.glossy),
        cap("render.bounces.transmission", bounces.transmission),
        cap("render.bounces.transparent", bounces.transparent),
        count("render.views_per_environment", VIEWS_PER_ENVIRONMENT),
        float("render.environments[*].rotation_deg", render_contract::ROTATION_DEG),
        float("render.environments[*].strength", render_contract::STRENGTH),
        float("render.fov_deg", render_contract::FOV_DEG),
        pair(float("render.radius_m", render_contract::RADIUS_M)),
        pair(float("render.elevation_deg", render_contract::ELEVATION_DEG)),
        pair(float("render.roll_deg", render_contract::ROLL_DEG)),
        float("render.offcentre", render_contract::OFFCENTRE),
        float("render.intrinsics_jitter", render_contract::INTRINSICS_JITTER),
        float("render.distortion[0]", render_contract::DISTORTION[0].1),
        float("render.distortion[1]", render_contract::DISTORTION[1].1),
        float("render.distortion[2]", render_contract::DISTORTION[2].1),
        float("render.distortion[3]", render_contract::DISTORTION[3].1),
        float("render.distortion[4]", render_contract::DISTORTION[4].1),
        pair(float("render.occlusion", render_contract::OCCLUSION)),
        float("render.clamp_indirect", render_contract::CLAMP_INDIRECT),
        float("render.despeckle", render_contract::DESPECKLE),
        float("render.scene.table_gap_m", render_contract::TABLE_GAP_M),
        count("render.scene.distractors", render_contract::DISTRACTORS),
        float("render.light.strength_ev_sigma", render_contract::STRENGTH_EV_SIGMA),
        float("render.light.rotation_jitter_deg", render_contract::ROTATION_JITTER_DEG),
        pair(float("render.light.temperature_k", render_contract::TEMPERATURE_K)),
        float("render.sensor.exposure_ev_sigma", render_contract::EXPOSURE_EV_SIGMA),
        float("render.sensor.white_balance_sigma", render_contract::WHITE_BALANCE_SIGMA),
        float("render.sensor.shot_noise", render_contract::SHOT_NOISE),
        float("render.sensor.read_noise", render_contract::READ_NOISE),
        float("split.train", split::TRAIN),
        float("split.val", split::VAL),
        float("split.test", split::TEST),
        float("noise.sigma_scale", noise::SIGMA_SCALE),
        float("noise.lateral_sigma_px", noise::LATERAL_SIGMA_PX),
        float("noise.flying_jump_m", noise::FLYING_JUMP_M),
        float("noise.flying_invalid_share", noise::FLYING_INVALID_SHARE),
        float("noise.multipath_gain", noise::MULTIPATH_GAIN),
        float("noise.specular_cone_deg", noise::SPECULAR_CONE_DEG),
        float("noise.tof_baseline_m", noise::TOF_BASELINE_M),
        float("noise.spatial_sigma_px", noise::SPATIAL_SIGMA_PX),
        float("object.*.mass_kg", object::MASS_KG),
    ]
}

/// One problem with a spec.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SpecError {
    /// Field path, e.g. `render.resolution[0]`; empty for a document-level problem.
    pub path: String,
    /// The value found, as TOML, or `nothing` when absent.
    pub value: String,
    /// The rule the value breaks.
    pub rule: String,
}

impl fmt::Display for SpecError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.path.is_empty() {
            write!(f, "{}", self.rule)
        } else {
            write!(f, "{}: {}, got {}", self.path, self.rule, self.value)
        }
    }
}

/// Every problem found in a spec, in document order.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub struct SpecErrors(pub Vec<SpecError>);

impl fmt::Display for SpecErrors {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, e) in self.0.iter().enumerate() {
            if i > 0 {
                writeln!(f)?;
            }
            write!(f, "{e}")?;
        }
        Ok(())
    }
}

/// Largest spec accepted, so a hostile or mistaken file cannot exhaust memory.
pub const MAX_SPEC_BYTES: usize = 1 << 20;

impl DatasetSpec {
    /// Parses and validates a spec, reporting every problem at once.
    pub fn parse(text: &str) -> Result<DatasetSpec, SpecErrors> {
        if text.len() > MAX_SPEC_BYTES {
            return Err(SpecErrors(vec![SpecError {
                path: String::new(),
                value: format!("{} bytes", text.len()),
                rule: format!("spec is larger than {MAX_SPEC_BYTES} bytes"),
            }]));
        }
        let mut root: Table = text.parse().map_err(|e: toml::de::Error| {
            SpecErrors(vec![SpecError {
                path: String::new(),
                value: String::new(),
                rule: format!("not valid TOML: {}", e.to_string().trim()),
            }])
        })?;
        let mut r = Reader::default();
        let spec = read_spec(&mut r, &mut root);
        if r.errors.is_empty() { Ok(spec) } else { Err(SpecErrors(r.errors)) }
    }

    /// Number of grasp-sim tasks (chunks) per (object, hand) pair.
    pub fn chunks_per_pair(&self) -> u32 {
        self.grasp.budget().chunks()
    }

    /// Upper bound on the number of samples: every trial accepted, up to the quota.
    pub fn max_samples(&self) -> u64 {
        let grasps = self.grasp.budget().grasps();
        (self.hands.len() * self.objects.len()) as u64 * u64::from(grasps) * u64::from(self.render.views_per_grasp())
    }

    /// Every asset file the spec's listed hands and objects and its environments name, field by
    /// field.
    pub fn asset_uses(&self) -> Vec<AssetUse> {
        let mut uses = Vec::new();
        let mut add = |field: String, path: &str| uses.push(AssetUse { field, path: path.to_string() });
        for name in &self.hands {
            if let Some(h) = self.hand_defs.get(name) {
                add(format!("hand.{name}.mjcf"), &h.mjcf);
                add(format!("hand.{name}.taxels"), &h.taxels);
                for (i, file) in h.files.iter().enumerate() {
                    add(format!("hand.{name}.files[{i}]"), file);
                }
            }
        }
        for name in &self.objects {
            if let Some(o) = self.object_defs.get(name) {
                add(format!("object.{name}.mesh"), &o.mesh);
                for (i, file) in o.files.iter().enumerate() {
                    add(format!("object.{name}.files[{i}]"), file);
                }
            }
        }
        uses.extend(self.render.environments.iter().filter_map(|e| e.file.clone()));
        uses
    }

    /// The distinct asset paths the spec needs, sorted.
    pub fn asset_paths(&self) -> BTreeSet<String> {
        self.asset_uses().into_iter().map(|u| u.path).collect()
    }
}

fn read_spec(r: &mut Reader, root: &mut Table) -> DatasetSpec {
    let mut ds = r.section(root, "dataset");
    let dataset = DatasetSection {
        name: r.name(&mut ds, "dataset", "name", None),
        seed: r.int(&mut ds, "dataset.seed", "seed", 0..=i64::MAX, None) as u64,
    };
    r.finish(ds, "dataset", &["name", "seed"]);

    let hand_defs = read_user_hands(r, root);
    let object_defs = read_user_objects(r, root);
    let known_hands: Vec<&str> =
        catalog::hands().iter().map(|h| h.entry.name.as_str()).chain(hand_defs.keys().map(String::as_str)).collect();
    let hands = r.name_list(
        root,
        "",
        "hands",
        &["trx3"],
        &known_hands,
        "a hand in `vintctl hands` or one a [hand.NAME] table defines",
    );
    let known_objects: Vec<&str> =
        catalog::objects().iter().map(|o| o.name.as_str()).chain(object_defs.keys().map(String::as_str)).collect();
    let objects = r.name_list(
        root,
        "",
        "objects",
        &[],
        &known_objects,
        "an object in the built-in catalog or one an [object.NAME] table defines",
    );

    let mut g = r.section(root, "grasp");
    let grasp = GraspSettings {
        trials_per_pair: r.count(&mut g, "grasp", "trials_per_pair", TRIALS_PER_PAIR),
        accepted_per_pair: g
            .contains_key("accepted_per_pair")
            .then(|| r.count(&mut g, "grasp", "accepted_per_pair", ACCEPTED_PER_PAIR)),
        chunk_size: r.count(&mut g, "grasp", "chunk_size", grasp::TRIALS_PER_TASK),
        timestep_s: r.number(&mut g, "grasp", "timestep_s", grasp::TIMESTEP_S),
        lift_height_m: r.number(&mut g, "grasp", "lift_height_m", grasp::LIFT_HEIGHT_M),
        hold_s: r.number(&mut g, "grasp", "hold_s", grasp::HOLD_S),
        max_drop_m: r.number(&mut g, "grasp", "max_drop_m", grasp::MAX_DROP_M),
        standoff_ratio: r.float_range(
            &mut g,
            "grasp",
            "standoff_ratio",
            grasp::STANDOFF_RATIO,
            grasp::STANDOFF_RATIO_DEFAULT,
        ),
        shake_accel_mps2: r.number(&mut g, "grasp", "shake_accel_mps2", SHAKE_ACCEL_MPS2),
        shake_directions: r.count(&mut g, "grasp", "shake_directions", grasp::SHAKE_DIRECTIONS),
        shake_duration_s: r.number(&mut g, "grasp", "shake_duration_s", grasp::SHAKE_DURATION_S),
        r#type: r.tag(&mut g, "grasp", "type", &grasp::GraspType::ALL, Some(grasp::GraspType::default())),
    };
    r.finish(
        g,
        "grasp",
        &[
            "trials_per_pair",
            "accepted_per_pair",
            "chunk_size",
            "timestep_s",
            "lift_height_m",
            "hold_s",
            "max_drop_m",
            "standoff_ratio",
            "shake_accel_mps2",
            "shake_directions",
            "shake_duration_s",
            "type",
        ],
    );
    let budget = grasp.budget();
    if budget.max_task_trials() > grasp::TRIALS_PER_TASK.max {
        r.error(
            "grasp.chunk_size",
            Value::Integer(i64::from(grasp.chunk_size)),
            format!(
                "with trials_per_pair = {} and accepted_per_pair = {}, one grasp task may run {} trials \
                 (chunk_size × trials per accepted grasp); at most {}: lower chunk_size",
                grasp.trials_per_pair,
                grasp.accepted_per_pair.unwrap_or(grasp.trials_per_pair),
                budget.max_task_trials(),
                grasp::TRIALS_PER_TASK.max
            ),
        );
    }

    let mut t = r.section(root, "touch");
    let touch = TouchSettings {
        contact_margin_m: r.number(&mut t, "touch", "contact_margin_m", grasp::CONTACT_MARGIN_M),
        contact_window_s: r.number(&mut t, "touch", "contact_window_s", grasp::CONTACT_WINDOW_S),
        activation_force_n: r.number(&mut t, "touch", "activation_force_n", grasp::ACTIVATION_FORCE_N),
        half_force_n: r.number(&mut t, "touch", "half_force_n", grasp::HALF_FORCE_N),
        response_exponent: r.number(&mut t, "touch", "response_exponent", grasp::RESPONSE_EXPONENT),
        gain_sigma: r.number(&mut t, "touch", "gain_sigma", grasp::GAIN_SIGMA),
        aging: r.float_range_or_number(&mut t, "touch", "aging", grasp::AGING, grasp::AGING_DEFAULT),
        position_sigma_m: r.number(&mut t, "touch", "position_sigma_m", grasp::POSITION_SIGMA_M),
        min_active_taxels: r.count(&mut t, "touch", "min_active_taxels", grasp::MIN_ACTIVE_TAXELS),
    };
    if let Some(v) = t.remove("footprint_radius_m") {
        r.error(
            "touch.footprint_radius_m",
            v,
            "was removed: every taxel within touch.contact_margin_m of the object is its own contact \
             element, with no footprint around MuJoCo's contact points, see docs/touch.md",
        );
    }
    r.finish(
        t,
        "touch",
        &[
            "contact_margin_m",
            "contact_window_s",
            "activation_force_n",
            "half_force_n",
            "response_exponent",
            "gain_sigma",
            "aging",
            "position_sigma_m",
            "min_active_taxels",
        ],
    );

    let mut rd = r.section(root, "render");
    let resolution =
        r.int_pair(&mut rd, "render", "resolution", [render_contract::WIDTH_PX, render_contract::HEIGHT_PX]);
    if let Some(v) = rd.remove("views_per_grasp") {
        r.error(
            "render.views_per_grasp",
            v,
            "was renamed: set render.views_per_environment (a grasp gets views_per_environment × environments views)",
        );
    }
    let render = RenderSettings {
        resolution,
        samples: r.count(&mut rd, "render", "samples", render_contract::SAMPLES),
        denoise: r.boolean(&mut rd, "render.denoise", "denoise", render_contract::DENOISE),
        despeckle: r.number(&mut rd, "render", "despeckle", render_contract::DESPECKLE),
        clamp_indirect: r.number(&mut rd, "render", "clamp_indirect", render_contract::CLAMP_INDIRECT),
        bounces: read_bounces(r, &mut rd),
        views_per_environment: r.count(&mut rd, "render", "views_per_environment", VIEWS_PER_ENVIRONMENT),
        environments: read_environments(r, &mut rd),
        fov_deg: r.number(&mut rd, "render", "fov_deg", render_contract::FOV_DEG),
        radius_m: r.float_range(
            &mut rd,
            "render",
            "radius_m",
            render_contract::RADIUS_M,
            render_contract::RADIUS_M_DEFAULT,
        ),
        elevation_deg: r.float_range(
            &mut rd,
            "render",
            "elevation_deg",
            render_contract::ELEVATION_DEG,
            render_contract::ELEVATION_DEG_DEFAULT,
        ),
        roll_deg: r.float_range(
            &mut rd,
            "render",
            "roll_deg",
            render_contract::ROLL_DEG,
            render_contract::ROLL_DEG_DEFAULT,
        ),
        offcentre: r.number(&mut rd, "render", "offcentre", render_contract::OFFCENTRE),
        intrinsics_jitter: r.number(&mut rd, "render", "intrinsics_jitter", render_contract::INTRINSICS_JITTER),
        distortion: read_distortion(r, &mut rd),
        occlusion: r.float_range(
            &mut rd,
            "render",
            "occlusion",
            render_contract::OCCLUSION,
            render_contract::OCCLUSION_DEFAULT,
        ),
        palm_side: r.tag(
            &mut rd,
            "render",
            "palm_side",
            &render_contract::PalmSide::ALL,
            Some(render_contract::PalmSide::default()),
        ),
        scene: read_scene(r, &mut rd),
        sensor: read_sensor(r, &mut rd),
        light: read_light(r, &mut rd),
    };
    if !render.environments.is_empty() && render.views_per_grasp() > MAX_VIEWS_PER_GRASP {
        r.error(
            "render.views_per_environment",
            Value::Integer(i64::from(render.views_per_environment)),
            format!(
                "times {} environments must be at most {MAX_VIEWS_PER_GRASP} views per grasp",
                render.environments.len()
            ),
        );
    }
    check_distortion(r, &render);
    r.finish(
        rd,
        "render",
        &[
            "resolution",
            "samples",
            "denoise",
            "despeckle",
            "clamp_indirect",
            "bounces",
            "views_per_environment",
            "environments",
            "environment",
            "fov_deg",
            "radius_m",
            "elevation_deg",
            "roll_deg",
            "offcentre",
            "intrinsics_jitter",
            "distortion",
            "occlusion",
            "palm_side",
            "scene",
            "sensor",
            "light",
        ],
    );

    let mut n = r.section(root, "noise");
    let on = noise::NoiseModel::default();
    let model = noise::NoiseModel {
        mode: r.tag(&mut n, "noise", "mode", &noise::DepthMode::ALL, Some(on.mode)),
        sigma_scale: r.number(&mut n, "noise", "sigma_scale", noise::SIGMA_SCALE),
        lateral: r.boolean(&mut n, "noise.lateral", "lateral", on.lateral),
        lateral_sigma_px: r.number(&mut n, "noise", "lateral_sigma_px", noise::LATERAL_SIGMA_PX),
        flying_pixels: r.boolean(&mut n, "noise.flying_pixels", "flying_pixels", on.flying_pixels),
        flying_jump_m: r.number(&mut n, "noise", "flying_jump_m", noise::FLYING_JUMP_M),
        flying_invalid_share: r.number(&mut n, "noise", "flying_invalid_share", noise::FLYING_INVALID_SHARE),
        multipath: r.boolean(&mut n, "noise.multipath", "multipath", on.multipath),
        multipath_gain: r.number(&mut n, "noise", "multipath_gain", noise::MULTIPATH_GAIN),
        materials: r.boolean(&mut n, "noise.materials", "materials", on.materials),
        specular_cone_deg: r.number(&mut n, "noise", "specular_cone_deg", noise::SPECULAR_CONE_DEG),
        registration: r.boolean(&mut n, "noise.registration", "registration", on.registration),
        tof_baseline_m: r.number(&mut n, "noise", "tof_baseline_m", noise::TOF_BASELINE_M),
        spatial_sigma_px: r.number(&mut n, "noise", "spatial_sigma_px", noise::SPATIAL_SIGMA_PX),
    };
    let noise = NoiseSettings {
        model,
        ignore_min_range: r.boolean(&mut n, "noise.ignore_min_range", "ignore_min_range", false),
    };
    for old in ["sigma_base_m", "sigma_per_m", "min_range_m", "max_range_m", "edge_hole_jump_m", "dropout"] {
        if let Some(v) = n.remove(old) {
            r.error(
                &join("noise", old),
                v,
                "was removed: the noise model is an Azure Kinect mode (noise.mode) with cited parameters, \
                 see docs/depth_noise.md",
            );
        }
    }
    r.finish(
        n,
        "noise",
        &[
            "mode",
            "sigma_scale",
            "lateral",
            "lateral_sigma_px",
            "flying_pixels",
            "flying_jump_m",
            "flying_invalid_share",
            "multipath",
            "multipath_gain",
            "materials",
            "specular_cone_deg",
            "registration",
            "tof_baseline_m",
            "spatial_sigma_px",
            "ignore_min_range",
        ],
    );

    let mut o = r.section(root, "outputs");
    let modality_names: Vec<&str> = Modality::ALL.iter().map(|m| m.as_str()).collect();
    let outputs = Outputs {
        modalities: r
            .name_list(
                &mut o,
                "outputs",
                "modalities",
                &modality_names,
                &modality_names,
                &format!("one of {}", modality_names.join(", ")),
            )
            .iter()
            .filter_map(|m| Modality::parse(m))
            .collect(),
        depth_format: r.tag(&mut o, "outputs", "depth_format", &DepthFormat::ALL, Some(DepthFormat::default())),
    };
    r.finish(o, "outputs", &["modalities", "depth_format"]);
    check_min_range(r, &render, &noise, &outputs);
    check_png_depth_range(r, &render, &outputs);
    let split = read_split(r, root, &objects, &hands);

    r.finish(
        std::mem::take(root),
        "",
        &["dataset", "hands", "objects", "hand", "object", "grasp", "touch", "render", "noise", "outputs", "split"],
    );
    DatasetSpec { dataset, hands, objects, hand_defs, object_defs, grasp, touch, render, noise, outputs, split }
}

/// `[split]`: fractions that sum to 1, and held-out objects and hands the spec lists.
fn read_split(r: &mut Reader, root: &mut Table, objects: &[String], hands: &[String]) -> SplitSettings {
    let mut t = r.section(root, "split");
    let (train, val, test) = (
        r.number(&mut t, "split", "train", split::TRAIN),
        r.number(&mut t, "split", "val", split::VAL),
        r.number(&mut t, "split", "test", split::TEST),
    );
    let sum = train + val + test;
    if (sum - 1.0).abs() > split::SUM_TOLERANCE {
        r.error("split", Value::Float(sum), "split.train + split.val + split.test must sum to 1");
    }
    let mut held_out = |key: &str, listed: &[String], what: &str| {
        if !t.contains_key(key) {
            return Vec::new();
        }
        let known: Vec<&str> = listed.iter().map(String::as_str).collect();
        r.name_list(&mut t, "split", key, &[], &known, &format!("one of the spec's {what}"))
    };
    let held_out_objects = held_out("held_out_objects", objects, "objects");
    let held_out_hands = held_out("held_out_hands", hands, "hands");
    r.finish(t, "split", &["train", "val", "test", "held_out_objects", "held_out_hands"]);
    SplitSettings { train, val, test, held_out_objects, held_out_hands }
}

/// With noisy depth requested, the nearest camera must stand within the mode's range (a nearer one
/// would see only invalid depth), unless the spec says `noise.ignore_min_range = true`.
fn check_min_range(r: &mut Reader, render: &RenderSettings, noise: &NoiseSettings, outputs: &Outputs) {
    let mode = noise.model.mode;
    let min_range_m = mode.figures().min_range_m;
    // A refused mode was reported; the default standing in for it says nothing about the range.
    let mode_refused = r.errors.iter().any(|e| e.path == "noise.mode");
    if !mode_refused
        && outputs.wants(Modality::DepthNoisy)
        && !noise.ignore_min_range
        && render.radius_m[0] < min_range_m
    {
        r.error(
            "render.radius_m[0]",
            Value::Float(render.radius_m[0]),
            format!(
                "must be at least {min_range_m} m, the minimum range of noise.mode {:?} (depth_noisy is requested): \
                 move the camera out, choose a mode with a shorter range (wfov_2x2binned, wfov_unbinned: 0.25 m), \
                 or set noise.ignore_min_range = true",
                mode.as_str()
            ),
        );
    }
}

/// With depth stored as 16-bit PNG, the farthest camera must stand within what a PNG holds
/// (`depth::PNG_MAX_M`, 6.5535 m): farther, the object itself would store as no reading.
fn check_png_depth_range(r: &mut Reader, render: &RenderSettings, outputs: &Outputs) {
    let depth_wanted = outputs.wants(Modality::Depth) || outputs.wants(Modality::DepthNoisy);
    if depth_wanted && outputs.depth_format == DepthFormat::Png && render.radius_m[1] > depth::PNG_MAX_M {
        r.error(
            "render.radius_m[1]",
            Value::Float(render.radius_m[1]),
            format!(
                "must be at most {} m with outputs.depth_format = \"png\" (16-bit steps of 0.1 mm hold no \
                 farther depth): move the camera in, or set outputs.depth_format = \"npy\"",
                depth::PNG_MAX_M
            ),
        );
    }
}

/// `render.distortion`: OpenCV's five coefficients [k1, k2, p1, p2, k3], each within its bound;
/// a pinhole when absent.
fn read_distortion(r: &mut Reader, rd: &mut Table) -> [f64; 5] {
    let path = "render.distortion";
    let mut out = render_contract::PINHOLE;
    match rd.remove("distortion") {
        None => {}
        Some(Value::Array(items)) if items.len() == out.len() => {
            for (i, v) in items.into_iter().enumerate() {
                let (_, bound) = render_contract::DISTORTION[i];
                if let Some(x) = r.float_value(&format!("{path}[{i}]"), v, (bound.min, bound.max)) {
                    out[i] = x;
                }
            }
        }
        Some(v) => r.error(path, v, "must be an array of five numbers [k1, k2, p1, p2, k3] (OpenCV's order)"),
    }
    out
}

/// A distorted image is resampled from a pinhole render, which needs the lens invertible over the
/// whole image: its radial map must keep growing out to the corners at the nominal intrinsics
/// (`render_contract::radial_reach`; the renderer checks each view's own, which
/// `render.intrinsics_jitter` moves).
fn check_distortion(r: &mut Reader, render: &RenderSettings) {
    // A refused value's stand-in (its default) says nothing about this lens.
    let refused = |e: &SpecError| {
        ["render.resolution", "render.fov_deg", "render.distortion"].iter().any(|p| e.path.starts_with(p))
    };
    if render.distortion == render_contract::PINHOLE || r.errors.iter().any(refused) {
        return;
    }
    let [width, height] = render.resolution.map(f64::from);
    let focal_px = (width / 2.0) / (render.fov_deg.to_radians() / 2.0).tan();
    let corner = ((width - 1.0) / 2.0).hypot((height - 1.0) / 2.0) / focal_px;
    let reach = render_contract::radial_reach(&render.distortion, corner);
    if reach < corner {
        r.error(
            "render.distortion",
            Value::Array(render.distortion.iter().map(|&k| Value::Float(k)).collect()),
            format!(
                "must stay invertible out to the image's corners: with resolution {}×{} and fov_deg {} they lie \
                 at radius {corner:.3} (normalised), but the radial map r·(1 + k1·r² + k2·r⁴ + k3·r⁶) stops \
                 growing (slope below {}) at radius {reach:.3}: weaken k1, k2 or k3, or narrow the field of view",
                render.resolution[0],
                render.resolution[1],
                render.fov_deg,
                render_contract::MIN_RADIAL_SLOPE,
            ),
        );
    }
}

/// `[hand.NAME]` tables: `mjcf` and `taxels` file paths, and the MJCF's mesh `files`.
fn read_user_hands(r: &mut Reader, root: &mut Table) -> BTreeMap<String, UserHand> {
    let mut out = BTreeMap::new();
    for (name, mut t) in r.definitions(root, "hand") {
        let path = format!("hand.{name}");
        let hand = UserHand {
            mjcf: r.asset_path(&mut t, &path, "mjcf", &["xml"]),
            taxels: r.asset_path(&mut t, &path, "taxels", &["csv"]),
            files: r.asset_paths(&mut t, &path, "files", asset::HAND_MESH_EXTENSIONS, asset::MAX_HAND_FILES),
        };
        r.finish(t, &path, &["mjcf", "taxels", "files"]);
        if catalog::hand(&name).is_some() {
            r.error(&path, Value::String(name), "must not reuse the name of a built-in hand");
        } else {
            out.insert(name, hand);
        }
    }
    out
}

/// `[object.NAME]` tables: a mesh file, its sidecar files, unit, mass, material and symmetry.
fn read_user_objects(r: &mut Reader, root: &mut Table) -> BTreeMap<String, UserObject> {
    let mut out = BTreeMap::new();
    let units: Vec<&str> = MESH_UNITS.iter().map(|(u, _)| *u).collect();
    let mut obj_ids: BTreeMap<u32, String> = BTreeMap::new();
    for (name, mut t) in r.definitions(root, "object") {
        let path = format!("object.{name}");
        let explicit = t.contains_key("symmetries_continuous") || t.contains_key("symmetries_discrete");
        if explicit && t.contains_key("symmetry") {
            let value = t.get("symmetry").cloned().unwrap_or(Value::Boolean(true));
            r.error(&format!("{path}.symmetry"), value, "must not be given with symmetries_continuous/_discrete");
        }
        let obj_id = t.remove("obj_id").and_then(|v| {
            let id = r.int_value(
                &format!("{path}.obj_id"),
                v,
                i64::from(object::BOP_OBJ_ID.min)..=i64::from(object::BOP_OBJ_ID.max),
            )? as u32;
            if let Some(other) = obj_ids.insert(id, name.clone()) {
                let rule = format!("must differ from object.{other}.obj_id (each obj_id names one model)");
                r.error(&format!("{path}.obj_id"), Value::Integer(i64::from(id)), rule);
            }
            Some(id)
        });
        let symmetries = explicit.then(|| read_symmetries(r, &mut t, &path));
        let object = UserObject {
            mesh: r.asset_path(&mut t, &path, "mesh", asset::MESH_EXTENSIONS),
            files: r.asset_paths(&mut t, &path, "files", asset::SIDECAR_EXTENSIONS, asset::MAX_SIDECARS),
            unit: r.choice(&mut t, &path, "unit", &units, None),
            mass_kg: r.float(
                &mut t,
                &format!("{path}.mass_kg"),
                "mass_kg",
                (object::MASS_KG.min, object::MASS_KG.max),
                None,
            ),
            material: r.tag(&mut t, &path, "material", &object::Material::ALL, None),
            symmetry: r.tag(&mut t, &path, "symmetry", &object::Symmetry::ALL, Some(object::Symmetry::None)),
            obj_id,
            symmetries,
        };
        r.finish(
            t,
            &path,
            &[
                "mesh",
                "files",
                "unit",
                "mass_kg",
                "material",
                "symmetry",
                "obj_id",
                "symmetries_continuous",
                "symmetries_discrete",
            ],
        );
        if catalog::object(&name).is_some() {
            r.error(&path, Value::String(name), "must not reuse the name of a built-in object");
        } else {
            out.insert(name, object);
        }
    }
    out
}

/// Most symmetries of each kind an object may list (T-LESS's most symmetric model has 4 discrete).
const MAX_SYMMETRIES: usize = 64;
/// How far a symmetry's rotation may be from orthonormal (and its axis from unit length).
const ORTHONORMAL_TOLERANCE: f64 = 1e-6;

/// `symmetries_continuous` (`{ axis = [x, y, z], offset = [x, y, z] }`, a unit axis, metres) and
/// `symmetries_discrete` (16 numbers: a row-major rigid transform, translation in metres) of an
/// object table, in the form and with the checks the engines apply.
fn read_symmetries(
    r: &mut Reader,
    t: &mut Table,
    parent: &str,
) -> (Vec<object::ContinuousSymmetry>, Vec<object::DiscreteSymmetry>) {
    let mut list = |key: &str| -> Vec<(String, Value)> {
        let path = join(parent, key);
        match t.remove(key) {
            None => Vec::new(),
            Some(Value::Array(items)) if items.len() <= MAX_SYMMETRIES => {
                items.into_iter().enumerate().map(|(i, v)| (format!("{path}[{i}]"), v)).collect()
            }
            Some(v) => {
                r.error(&path, v, format!("must be an array of at most {MAX_SYMMETRIES} symmetries"));
                Vec::new()
            }
        }
    };
    let (continuous_items, discrete_items) = (list("symmetries_continuous"), list("symmetries_discrete"));
    let position = (object::POSITION_M.min, object::POSITION_M.max);
    let numbers = |r: &mut Reader, path: &str, v: Value, n: usize, bounds: (f64, f64)| -> Option<Vec<f64>> {
        match v {
            Value::Array(items) if items.len() == n => {
                let parsed: Vec<Option<f64>> = items
                    .into_iter()
                    .enumerate()
                    .map(|(k, x)| r.float_value(&format!("{path}[{k}]"), x, bounds))
                    .collect();
                parsed.into_iter().collect()
            }
            v => {
                r.error(path, v, format!("must be an array of {n} numbers"));
                None
            }
        }
    };
    let mut continuous = Vec::new();
    for (path, v) in continuous_items {
        let Value::Table(mut entry) = v else {
            r.error(&path, v, "must be a table { axis = [x, y, z], offset = [x, y, z] } (metres)");
            continue;
        };
        let axis = entry.remove("axis").and_then(|a| numbers(r, &format!("{path}.axis"), a, 3, (-1.0, 1.0)));
        let offset = match entry.remove("offset") {
            None => Some(vec![0.0; 3]),
            Some(o) => numbers(r, &format!("{path}.offset"), o, 3, position),
        };
        r.finish(entry, &path, &["axis", "offset"]);
        let (Some(axis), Some(offset)) = (axis, offset) else { continue };
        let norm = axis.iter().map(|x| x * x).sum::<f64>().sqrt();
        if (norm - 1.0).abs() > ORTHONORMAL_TOLERANCE {
            r.error(&format!("{path}.axis"), Value::Float(norm), "must be a unit vector (its length is shown)");
            continue;
        }
        continuous.push(object::ContinuousSymmetry {
            axis: [axis[0], axis[1], axis[2]],
            offset: [offset[0], offset[1], offset[2]],
        });
    }
    let mut discrete = Vec::new();
    for (path, v) in discrete_items {
        let Some(m) = numbers(r, &path, v, 16, (-1e3, 1e3)) else { continue };
        if !is_rigid(&m) {
            r.error(
                &path,
                Value::String(format!("{m:?}")),
                "must be a rigid transform: a rotation (orthonormal, det +1) and a translation in metres, row-major, the last row 0 0 0 1",
            );
            continue;
        }
        let mut transform = [0.0; 16];
        transform.copy_from_slice(&m);
        discrete.push(transform);
    }
    (continuous, discrete)
}

/// A row-major 4×4 whose rotation is orthonormal with det +1 and whose last row is `0 0 0 1`.
fn is_rigid(m: &[f64]) -> bool {
    let r = |i: usize, j: usize| m[4 * i + j];
    let orthonormal = (0..3).all(|a| {
        (0..3).all(|b| {
            let dot: f64 = (0..3).map(|k| r(k, a) * r(k, b)).sum();
            (dot - if a == b { 1.0 } else { 0.0 }).abs() <= ORTHONORMAL_TOLERANCE
        })
    });
    let det = r(0, 0) * (r(1, 1) * r(2, 2) - r(1, 2) * r(2, 1)) - r(0, 1) * (r(1, 0) * r(2, 2) - r(1, 2) * r(2, 0))
        + r(0, 2) * (r(1, 0) * r(2, 1) - r(1, 1) * r(2, 0));
    orthonormal && (det - 1.0).abs() <= ORTHONORMAL_TOLERANCE && m[12..16] == [0.0, 0.0, 0.0, 1.0]
}

const ENVIRONMENT_RULE: &str = "one of Blender's bundled HDRIs (city, courtyard, forest, interior, night, studio, \
     sunrise, sunset) or a { name, file } table (your own HDRI)";

/// `render.environments`: names or tables (`{ name, rotation_deg, strength, file }`), or the same
/// tables as `[[render.environment]]`; default `["studio"]`. A table with a `file` (a `.hdr` or
/// `.exr` relative to the spec) is the user's own HDRI, under a name no bundled one has.
fn read_environments(r: &mut Reader, rd: &mut Table) -> Vec<Environment> {
    let (path, items) = match (rd.remove("environments"), rd.remove("environment")) {
        (Some(_), Some(v)) => {
            r.error("render.environment", v, "give render.environments or [[render.environment]], not both");
            return Vec::new();
        }
        (Some(v), None) => ("render.environments", v),
        (None, Some(v)) => ("render.environment", v),
        (None, None) => return vec![Environment::bundled("studio")],
    };
    let items = match items {
        Value::Array(a) if !a.is_empty() => a,
        v => {
            r.error(path, v, "must be a non-empty array of environment names or tables");
            return Vec::new();
        }
    };
    let mut out: Vec<Environment> = Vec::new();
    for (i, item) in items.into_iter().enumerate() {
        let p = format!("{path}[{i}]");
        let (name_path, env) = match item {
            Value::Table(mut t) => {
                let file = t.contains_key("file").then(|| {
                    let field = format!("{p}.file");
                    let path = r.asset_path(&mut t, &p, "file", HDRI_EXTENSIONS);
                    AssetUse { field, path }
                });
                let name = r.name(&mut t, &p, "name", None);
                let rotation_deg = r.number(&mut t, &p, "rotation_deg", render_contract::ROTATION_DEG);
                let strength = r.number(&mut t, &p, "strength", render_contract::STRENGTH);
                r.finish(t, &p, &["name", "rotation_deg", "strength", "file"]);
                if file.as_ref().is_some_and(|f| f.path.is_empty()) {
                    continue; // a bad path, already reported
                }
                (format!("{p}.name"), Environment { name, rotation_deg, strength, file })
            }
            v => match r.check_name(&p, v) {
                Some(name) => (p, Environment::bundled(&name)),
                None => continue,
            },
        };
        let bundled = catalog::ENVIRONMENTS.contains(&env.name.as_str());
        if env.name.is_empty() {
            continue; // already reported
        } else if env.file.is_some() && bundled {
            r.error(&name_path, Value::String(env.name), "must not reuse the name of a bundled HDRI");
        } else if env.file.is_none() && !bundled {
            let hint = did_you_mean(&env.name, catalog::ENVIRONMENTS);
            r.error(&name_path, Value::String(env.name), format!("must be {ENVIRONMENT_RULE}{hint}"));
        } else if out.iter().any(|e| e.name == env.name) {
            r.error(&name_path, Value::String(env.name), "must not repeat an earlier environment");
        } else {
            out.push(env);
        }
    }
    out
}

/// `[render.bounces]`: Cycles' caps, each 0..=1024.
fn read_bounces(r: &mut Reader, rd: &mut Table) -> Bounces {
    let mut b = render_subtable(r, rd, "bounces");
    let defaults = Bounces::default();
    let mut cap =
        |key: &str, default: u32| r.count(&mut b, "render.bounces", key, Bound { default, ..render_contract::BOUNCES });
    let bounces = Bounces {
        total: cap("total", defaults.total),
        diffuse: cap("diffuse", defaults.diffuse),
        glossy: cap("glossy", defaults.glossy),
        transmission: cap("transmission", defaults.transmission),
        transparent: cap("transparent", defaults.transparent),
    };
    r.finish(b, "render.bounces", &["total", "diffuse", "glossy", "transmission", "transparent"]);
    bounces
}

/// `[render.KEY]` taken out of `[render]`: empty when absent, an error when not a table.
fn render_subtable(r: &mut Reader, rd: &mut Table, key: &str) -> Table {
    match rd.remove(key) {
        None => Table::new(),
        Some(Value::Table(t)) => t,
        Some(v) => {
            r.error(&format!("render.{key}"), v, "must be a table");
            Table::new()
        }
    }
}

/// `[render.scene]`: the table, the flange and the distractors around the grasp.
fn read_scene(r: &mut Reader, rd: &mut Table) -> render_contract::Scene {
    let mut t = render_subtable(r, rd, "scene");
    let defaults = render_contract::Scene::default();
    let scene = render_contract::Scene {
        table: r.boolean(&mut t, "render.scene.table", "table", defaults.table),
        table_gap_m: r.number(&mut t, "render.scene", "table_gap_m", render_contract::TABLE_GAP_M),
        flange: r.boolean(&mut t, "render.scene.flange", "flange", defaults.flange),
        distractors: r.count(&mut t, "render.scene", "distractors", render_contract::DISTRACTORS),
    };
    r.finish(t, "render.scene", &["table", "table_gap_m", "flange", "distractors"]);
    if scene.distractors > 0 && !scene.table {
        let value = Value::Integer(i64::from(scene.distractors));
        r.error("render.scene.distractors", value, "needs the table to stand on (render.scene.table = true)");
    }
    scene
}

/// `[render.light]`: per-view randomisation of the environment's light.
fn read_light(r: &mut Reader, rd: &mut Table) -> render_contract::Light {
    let mut t = render_subtable(r, rd, "light");
    let light = render_contract::Light {
        strength_ev_sigma: r.number(&mut t, "render.light", "strength_ev_sigma", render_contract::STRENGTH_EV_SIGMA),
        rotation_jitter_deg: r.number(
            &mut t,
            "render.light",
            "rotation_jitter_deg",
            render_contract::ROTATION_JITTER_DEG,
        ),
        temperature_k: r.float_range(
            &mut t,
            "render.light",
            "temperature_k",
            render_contract::TEMPERATURE_K,
            render_contract::TEMPERATURE_K_DEFAULT,
        ),
    };
    r.finish(t, "render.light", &["strength_ev_sigma", "rotation_jitter_deg", "temperature_k"]);
    light
}

/// `[render.sensor]`: the colour camera's sensor model.
fn read_sensor(r: &mut Reader, rd: &mut Table) -> render_contract::Sensor {
    let mut t = render_subtable(r, rd, "sensor");
    let on = render_contract::Sensor::default();
    let sensor = render_contract::Sensor {
        enabled: r.boolean(&mut t, "render.sensor.enabled", "enabled", on.enabled),
        exposure_ev_sigma: r.number(&mut t, "render.sensor", "exposure_ev_sigma", render_contract::EXPOSURE_EV_SIGMA),
        white_balance_sigma: r.number(
            &mut t,
            "render.sensor",
            "white_balance_sigma",
            render_contract::WHITE_BALANCE_SIGMA,
        ),
        shot_noise: r.number(&mut t, "render.sensor", "shot_noise", render_contract::SHOT_NOISE),
        read_noise: r.number(&mut t, "render.sensor", "read_noise", render_contract::READ_NOISE),
    };
    r.finish(t, "render.sensor", &["enabled", "exposure_ev_sigma", "white_balance_sigma", "shot_noise", "read_noise"]);
    sensor
}

/// ` (did you mean `NAME`?)` for the known name nearest to an unknown `name`, or nothing.
fn did_you_mean(name: &str, known: &[&str]) -> String {
    suggest::nearest(name, known.iter().copied()).map(|s| format!(" (did you mean `{s}`?)")).unwrap_or_default()
}

/// Collects errors while taking values out of TOML tables; what is left in a table at `finish` is
/// an unknown key.
#[derive(Default)]
struct Reader {
    errors: Vec<SpecError>,
}

fn join(parent: &str, key: &str) -> String {
    if parent.is_empty() { key.to_string() } else { format!("{parent}.{key}") }
}

fn shown(v: &Value) -> String {
    match v {
        Value::String(s) => format!("{s:?}"),
        Value::Table(_) => "a table".to_string(),
        other => other.to_string(),
    }
}

impl Reader {
    fn error(&mut self, path: &str, value: Value, rule: impl Into<String>) {
        self.errors.push(SpecError { path: path.to_string(), value: shown(&value), rule: rule.into() });
    }

    fn missing(&mut self, path: &str) {
        self.errors.push(SpecError { path: path.to_string(), value: "nothing".into(), rule: "is required".into() });
    }

    /// Removes and returns a sub-table; a missing one is empty (all defaults).
    fn section(&mut self, root: &mut Table, key: &str) -> Table {
        match root.remove(key) {
            None => Table::new(),
            Some(Value::Table(t)) => t,
            Some(v) => {
                self.error(key, v, "must be a table");
                Table::new()
            }
        }
    }

    fn finish(&mut self, rest: Table, parent: &str, known: &[&str]) {
        for (k, v) in rest {
            if known.contains(&k.as_str()) {
                continue; // already reported (e.g. wrong type) when taken
            }
            let hint = suggest::nearest(&k, known.iter().copied())
                .map(|s| format!("did you mean `{s}`? "))
                .unwrap_or_default();
            self.error(&join(parent, &k), v, format!("unknown key ({hint}known keys: {})", known.join(", ")));
        }
    }

    fn int(
        &mut self,
        t: &mut Table,
        path: &str,
        key: &str,
        range: std::ops::RangeInclusive<i64>,
        default: Option<i64>,
    ) -> i64 {
        let fallback = default.unwrap_or(*range.start());
        match t.remove(key) {
            None => {
                if default.is_none() {
                    self.missing(path);
                }
                fallback
            }
            Some(v) => self.int_value(path, v, range).unwrap_or(fallback),
        }
    }

    /// An integer within `range`; `None` (reported) otherwise.
    fn int_value(&mut self, path: &str, v: Value, range: std::ops::RangeInclusive<i64>) -> Option<i64> {
        match v {
            Value::Integer(i) if range.contains(&i) => Some(i),
            v @ Value::Integer(_) => {
                self.error(path, v, format!("must be {}..={}", range.start(), range.end()));
                None
            }
            v => {
                self.error(path, v, "must be an integer");
                None
            }
        }
    }

    fn boolean(&mut self, t: &mut Table, path: &str, key: &str, default: bool) -> bool {
        match t.remove(key) {
            None => default,
            Some(Value::Boolean(b)) => b,
            Some(v) => {
                self.error(path, v, "must be true or false");
                default
            }
        }
    }

    fn float_value(&mut self, path: &str, v: Value, (lo, hi): (f64, f64)) -> Option<f64> {
        let x = match v {
            Value::Float(x) => x,
            Value::Integer(i) => i as f64,
            other => {
                self.error(path, other, "must be a number");
                return None;
            }
        };
        if !x.is_finite() {
            self.error(path, Value::Float(x), "must be a finite number");
            None
        } else if !(lo..=hi).contains(&x) {
            self.error(path, Value::Float(x), format!("must be in [{lo}, {hi}]"));
            None
        } else {
            Some(x)
        }
    }

    fn float(&mut self, t: &mut Table, path: &str, key: &str, bounds: (f64, f64), default: Option<f64>) -> f64 {
        let fallback = default.unwrap_or(bounds.0);
        match t.remove(key) {
            None => {
                if default.is_none() {
                    self.missing(path);
                }
                fallback
            }
            Some(v) => self.float_value(path, v, bounds).unwrap_or(fallback),
        }
    }

    /// A two-element array `[lo, hi]` with `lo <= hi`, both within `bounds`.
    fn float_range(
        &mut self,
        t: &mut Table,
        parent: &str,
        key: &str,
        bound: Bound<f64>,
        default: [f64; 2],
    ) -> [f64; 2] {
        let bounds = (bound.min, bound.max);
        let path = join(parent, key);
        let Some(items) = self.pair(t, &path, key) else {
            return default;
        };
        let mut out = default;
        let mut all_valid = true;
        for (i, v) in items.into_iter().enumerate() {
            match self.float_value(&format!("{path}[{i}]"), v, bounds) {
                Some(x) => out[i] = x,
                None => all_valid = false,
            }
        }
        // Order is only meaningful between two valid values (a rejected one was reported).
        if all_valid && out[0] > out[1] {
            self.error(
                &path,
                Value::Array(vec![Value::Float(out[0]), Value::Float(out[1])]),
                "must be [low, high] with low <= high",
            );
        }
        out
    }

    /// `float_range`, or a single number `x` within `bound` meaning `[x, x]` (a range that was a
    /// number before: specs that set one value keep their meaning).
    fn float_range_or_number(
        &mut self,
        t: &mut Table,
        parent: &str,
        key: &str,
        bound: Bound<f64>,
        default: [f64; 2],
    ) -> [f64; 2] {
        match t.get(key) {
            Some(Value::Float(_) | Value::Integer(_)) => {
                let x = self.number(t, parent, key, bound);
                [x, x]
            }
            _ => self.float_range(t, parent, key, bound, default),
        }
    }

    /// A two-element array of counts, each within its own bound (e.g. width and height).
    fn int_pair(&mut self, t: &mut Table, parent: &str, key: &str, bounds: [Bound<u32>; 2]) -> [u32; 2] {
        let path = join(parent, key);
        let default = [bounds[0].default, bounds[1].default];
        let Some(items) = self.pair(t, &path, key) else {
            return default;
        };
        let mut out = default;
        for (i, v) in items.into_iter().enumerate() {
            let p = format!("{path}[{i}]");
            out[i] = self.count_value(&p, v, bounds[i]).unwrap_or(bounds[i].default);
        }
        out
    }

    /// A count `parent.key` within `bound`; its default when absent.
    fn count(&mut self, t: &mut Table, parent: &str, key: &str, bound: Bound<u32>) -> u32 {
        match t.remove(key) {
            None => bound.default,
            Some(v) => self.count_value(&join(parent, key), v, bound).unwrap_or(bound.default),
        }
    }

    fn count_value(&mut self, path: &str, v: Value, bound: Bound<u32>) -> Option<u32> {
        let i = self.int_value(path, v, i64::from(bound.min)..=i64::from(bound.max))?;
        u32::try_from(i).ok()
    }

    /// A number `parent.key` within `bound`; its default when absent.
    fn number(&mut self, t: &mut Table, parent: &str, key: &str, bound: Bound<f64>) -> f64 {
        self.float(t, &join(parent, key), key, (bound.min, bound.max), Some(bound.default))
    }

    fn pair(&mut self, t: &mut Table, path: &str, key: &str) -> Option<Vec<Value>> {
        match t.remove(key)? {
            Value::Array(a) if a.len() == 2 => Some(a),
            v => {
                self.error(path, v, "must be an array of two numbers");
                None
            }
        }
    }

    /// A lowercase identifier: `[a-z0-9_]`, 1 to 64 characters (it becomes part of paths and ids).
    fn check_name(&mut self, path: &str, v: Value) -> Option<String> {
        match v {
            Value::String(s)
                if !s.is_empty()
                    && s.len() <= 64
                    && s.bytes().all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_') =>
            {
                Some(s)
            }
            v @ Value::String(_) => {
                self.error(path, v, "must be 1 to 64 characters of a-z, 0-9 and _");
                None
            }
            v => {
                self.error(path, v, "must be a string");
                None
            }
        }
    }

    fn name(&mut self, t: &mut Table, parent: &str, key: &str, default: Option<&str>) -> String {
        let path = join(parent, key);
        match t.remove(key) {
            None => {
                if default.is_none() {
                    self.missing(&path);
                }
                default.unwrap_or_default().to_string()
            }
            Some(v) => self.check_name(&path, v).unwrap_or_default(),
        }
    }

    /// A table of named definitions (`[hand.NAME]`): each name a valid identifier, each value a
    /// table. A missing table defines nothing.
    fn definitions(&mut self, root: &mut Table, key: &str) -> Vec<(String, Table)> {
        let mut out = Vec::new();
        for (name, v) in self.section(root, key) {
            let path = join(key, &name);
            if self.check_name(&path, Value::String(name.clone())).is_none() {
                continue;
            }
            match v {
                Value::Table(t) => out.push((name, t)),
                v => self.error(&path, v, "must be a table"),
            }
        }
        out
    }

    /// A file path relative to the spec file, with one of `extensions` (any case).
    fn asset_path(&mut self, t: &mut Table, parent: &str, key: &str, extensions: &[&str]) -> String {
        let path = join(parent, key);
        let s = match t.remove(key) {
            None => {
                self.missing(&path);
                return String::new();
            }
            Some(Value::String(s)) => s,
            Some(v) => {
                self.error(&path, v, "must be a string (a path relative to the spec file)");
                return String::new();
            }
        };
        let ext = s.rsplit_once('.').map(|(_, e)| e.to_ascii_lowercase()).unwrap_or_default();
        if s.is_empty() || s.len() > 1024 || s.starts_with('/') || s.contains('\\') || s.contains('\0') {
            self.error(&path, Value::String(s), "must be a path relative to the spec file, with / separators");
            String::new()
        } else if !extensions.contains(&ext.as_str()) {
            let list: Vec<String> = extensions.iter().map(|e| format!(".{e}")).collect();
            self.error(&path, Value::String(s), format!("must name a {} file", list.join(", ")));
            String::new()
        } else {
            s
        }
    }

    /// An optional array of at most `max` distinct file paths relative to the spec file (each as
    /// `asset_path` checks it); empty when absent.
    fn asset_paths(&mut self, t: &mut Table, parent: &str, key: &str, extensions: &[&str], max: usize) -> Vec<String> {
        let path = join(parent, key);
        let items = match t.remove(key) {
            None => return Vec::new(),
            Some(Value::Array(items)) if items.len() <= max => items,
            Some(v) => {
                self.error(&path, v, format!("must be an array of at most {max} paths relative to the spec file"));
                return Vec::new();
            }
        };
        let mut out: Vec<String> = Vec::new();
        for (i, item) in items.into_iter().enumerate() {
            let name = format!("{key}[{i}]");
            let mut one = Table::new();
            one.insert(name.clone(), item);
            let file = self.asset_path(&mut one, parent, &name, extensions);
            if out.contains(&file) {
                self.error(&join(parent, &name), Value::String(file), "must not repeat a file");
            } else if !file.is_empty() {
                out.push(file);
            }
        }
        out
    }

    /// One of `choices`; `default` when absent (required when there is none).
    fn choice(&mut self, t: &mut Table, parent: &str, key: &str, choices: &[&str], default: Option<&str>) -> String {
        let path = join(parent, key);
        match t.remove(key) {
            None => {
                if default.is_none() {
                    self.missing(&path);
                }
                default.unwrap_or_default().to_string()
            }
            Some(Value::String(s)) if choices.contains(&s.as_str()) => s,
            Some(v) => {
                self.error(&path, v, format!("must be one of {}", choices.join(", ")));
                default.unwrap_or_default().to_string()
            }
        }
    }

    /// One of an enum's `choices`, by its serde name; `default` when absent (required when none).
    fn tag<T: Serialize + Copy>(
        &mut self,
        t: &mut Table,
        parent: &str,
        key: &str,
        choices: &[T],
        default: Option<T>,
    ) -> T {
        let names: Vec<String> = choices.iter().map(object::name_of).collect();
        let names: Vec<&str> = names.iter().map(String::as_str).collect();
        let fallback = default.map(|d| object::name_of(&d));
        let chosen = self.choice(t, parent, key, &names, fallback.as_deref());
        // A bad value was reported; the value returned then does not matter.
        names.iter().position(|n| *n == chosen).map(|i| choices[i]).or(default).unwrap_or(choices[0])
    }

    /// A non-empty list of distinct names, each one of `known`; an unknown one is reported with
    /// the known name nearest to it.
    fn name_list(
        &mut self,
        t: &mut Table,
        parent: &str,
        key: &str,
        default: &[&str],
        known: &[&str],
        rule: &str,
    ) -> Vec<String> {
        let path = join(parent, key);
        let items = match t.remove(key) {
            None if default.is_empty() => {
                self.missing(&path);
                return Vec::new();
            }
            None => return default.iter().map(|s| s.to_string()).collect(),
            Some(Value::Array(a)) if a.is_empty() => {
                self.error(&path, Value::Array(a), "must name at least one");
                return Vec::new();
            }
            Some(Value::Array(a)) => a,
            Some(v) => {
                self.error(&path, v, "must be an array of strings");
                return Vec::new();
            }
        };
        let mut out: Vec<String> = Vec::new();
        for (i, v) in items.into_iter().enumerate() {
            let p = format!("{path}[{i}]");
            let Some(name) = self.check_name(&p, v) else {
                continue;
            };
            if !known.contains(&name.as_str()) {
                let hint = did_you_mean(&name, known);
                self.error(&p, Value::String(name), format!("must be {rule}{hint}"));
            } else if out.contains(&name) {
                self.error(&p, Value::String(name), "must not repeat an earlier entry");
            } else {
                out.push(name);
            }
        }
        out
    }
}
