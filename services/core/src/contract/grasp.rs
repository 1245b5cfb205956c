//! The grasp stage: a chunk of grasp trials of one object by one hand, simulated in MuJoCo
//! (`vint_engines.grasp`). PROTOCOL.md describes the procedure and the output documents.

use std::collections::BTreeMap;

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::object::ObjectEntry;
use super::{Bound, SEED_MAX};
use crate::asset::Asset;

/// The trials' poses, hand geometry and metrics: what render tasks read.
pub const GRASPS_FILE: &str = "grasps.json";
/// Every accepted trial's full touch record: only the package stage reads it.
pub const TOUCH_FILE: &str = "touch.json";
/// The object's watertight model mesh (object frame, millimetres): what render tasks show.
pub const MODEL_FILE: &str = "object.ply";

/// Trials one task runs (the spec's `grasp.chunk_size`).
pub const TRIALS_PER_TASK: Bound<u32> = Bound::new(1, 1024, 8);

/// Default 1 ms: the cheapest step within the grasp study's tolerances once touch reads contact
/// forces (at 2 ms the active-taxel sets overlap the 0.25 ms reference's by 0.73; docs/physics.md).
pub const TIMESTEP_S: Bound<f64> = Bound::new(1e-4, 0.01, 0.001);
pub const LIFT_HEIGHT_M: Bound<f64> = Bound::new(0.0, 1.0, 0.10);
pub const HOLD_S: Bound<f64> = Bound::new(0.0, 30.0, 1.0);
pub const MAX_DROP_M: Bound<f64> = Bound::new(0.001, 0.5, 0.02);
/// Each end of the standoff range, as a fraction of the hand's finger length.
pub const STANDOFF_RATIO: Bound<f64> = Bound::new(-0.2, 1.0, 0.025);
pub const STANDOFF_RATIO_DEFAULT: [f64; 2] = [0.025, 0.10];
pub const IMPRATIO: Bound<f64> = Bound::new(1.0, 1000.0, 10.0);
pub const HAND_SOLREF_TIMECONST_S: Bound<f64> = Bound::new(1e-4, 0.1, 0.005);
pub const FORCE_SCALE: Bound<f64> = Bound::new(0.01, 100.0, 1.0);
pub const MASS_OVERRIDE_KG: Bound<f64> = Bound::new(0.001, 20.0, 0.1);
pub const MAX_RETRIES: Bound<u32> = Bound::new(0, 4, 2);
pub const MIN_TIMESTEP_S: Bound<f64> = Bound::new(1e-5, 0.01, 0.00025);
pub const MAX_PENETRATION_M: Bound<f64> = Bound::new(1e-4, 0.1, 0.004);
pub const MAX_OBJECT_SPEED_MPS: Bound<f64> = Bound::new(0.1, 100.0, 5.0);

pub const SHAKE_ACCEL_MPS2: Bound<f64> = Bound::new(0.0, 100.0, 5.0);
pub const SHAKE_DIRECTIONS: Bound<u32> = Bound::new(1, 32, 4);
pub const SHAKE_DURATION_S: Bound<f64> = Bound::new(0.01, 30.0, 1.0);

// The touch model and the sources of its defaults: docs/touch.md.
/// How close (m) to the object's surface a taxel on a link in contact must lie to touch it (each
/// taxel is a contact element) and share the link's contact force: the skin's compliance; MuJoCo's
/// soft contacts let surfaces interpenetrate by tenths of a millimetre under grasp forces.
pub const CONTACT_MARGIN_M: Bound<f64> = Bound::new(0.0, 0.002, 0.0005);
/// Time (s) over which contact forces are averaged: the capture and the simulation steps within
/// this window after it, `max(1, round(window / timestep))` samples in all, so the read-out means
/// the same at any timestep. 4 ms: one sample period of the paper's skin (it samples above 250 Hz,
/// VinT-6D App. A.2); 0 reads the capture alone.
pub const CONTACT_WINDOW_S: Bound<f64> = Bound::new(0.0, 0.064, 0.004);
/// Local force (N) below which a taxel reads nothing: an FSR's actuation force (Interlink FSR 400).
pub const ACTIVATION_FORCE_N: Bound<f64> = Bound::new(0.0, 10.0, 0.2);
/// Local force (N) at which a new taxel reads half its gain, where it is most sensitive: the
/// divider resistor matched to the median taxel force of the hands' power grasps (7–12 N, within
/// the FSR 400's 0.2–20 N range).
pub const HALF_FORCE_N: Bound<f64> = Bound::new(0.01, 100.0, 10.0);
/// Power of the FSR's conductance in force (conductance roughly proportional to force).
pub const RESPONSE_EXPONENT: Bound<f64> = Bound::new(0.2, 3.0, 1.0);
pub const GAIN_SIGMA: Bound<f64> = Bound::new(0.0, 1.0, 0.1);
/// Each end of the range a grasp's aging is drawn from (uniformly, per grasp): the sensitivity left,
/// 1 a new sensor. Default [1, 1]: a new sensor in every grasp.
pub const AGING: Bound<f64> = Bound::new(0.01, 1.0, 1.0);
pub const AGING_DEFAULT: [f64; 2] = [1.0, 1.0];
/// σ (m) of each taxel's displacement along each axis of its surface's tangent plane, drawn once
/// per hand instance: the placement deviations of a real skin ("slight deviations exist in each
/// sensor's tactile element distribution due to manufacturing precision constraints", VinT-6D
/// App. A.1.2). 0.3 mm is an assumption (≈ 7 % of the trx3 layout's 4.5 mm pitch), not a
/// measurement: docs/touch.md. 0: the layout's exact positions.
pub const POSITION_SIGMA_M: Bound<f64> = Bound::new(0.0, 0.002, 0.0003);
pub const MIN_ACTIVE_TAXELS: Bound<u32> = Bound::new(0, 10_000, 3);
/// The gain seed of a task that names none (the studies'); planned tasks always carry the hand's.
pub const GAIN_SEED_DEFAULT: u64 = 123;

/// A grasp task's parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
#[schemars(rename = "GraspParams")]
pub struct Params {
    pub object: ObjectEntry,
    pub hand: HandRef,
    #[schemars(length(min = TRIALS_PER_TASK.min, max = TRIALS_PER_TASK.max))]
    pub trials: Vec<Trial>,
    /// Stop once this many trials are accepted (the chunk's quota of a spec's
    /// `grasp.accepted_per_pair`); the trials run in the order listed. Absent: run them all.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schemars(range(min = TRIALS_PER_TASK.min, max = TRIALS_PER_TASK.max))]
    pub accept: Option<u32>,
    #[serde(default)]
    pub physics: Physics,
    #[serde(default)]
    pub touch: Touch,
    /// The job's files the hand or object names (by SHA-256); the worker stages each one.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub assets: Vec<Asset>,
}

/// A hand: a built-in one by name, or a spec's own with its MJCF model and taxel layout (the
/// SHA-256 of files submitted with the job).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct HandRef {
    #[schemars(regex(pattern = r"^[a-z0-9_]{1,64}$"))]
    pub name: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schemars(regex(pattern = r"^[0-9a-f]{64}$"))]
    pub mjcf: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schemars(regex(pattern = r"^[0-9a-f]{64}$"))]
    pub taxels: Option<String>,
}

/// One trial: its index within the (object, hand) pair and the seed of its random draws.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Trial {
    pub grasp_index: u32,
    #[schemars(range(max = SEED_MAX))]
    pub seed: u64,
}

/// MuJoCo settings, the grasp procedure's distances and durations, and the stability checks.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
#[schemars(rename = "GraspPhysics")]
pub struct Physics {
    /// Simulation timestep (s).
    #[schemars(range(min = TIMESTEP_S.min, max = TIMESTEP_S.max))]
    pub timestep: f64,
    /// How far the hand lifts the object (m).
    #[schemars(range(min = LIFT_HEIGHT_M.min, max = LIFT_HEIGHT_M.max))]
    pub lift_height: f64,
    /// How long the lifted hand holds still (s).
    #[schemars(range(min = HOLD_S.min, max = HOLD_S.max))]
    pub hold_s: f64,
    /// A grasp holds when the object slips less than this relative to the palm (m).
    #[schemars(range(min = MAX_DROP_M.min, max = MAX_DROP_M.max))]
    pub max_drop_m: f64,
    /// Palm standoff before closing, [min, max] fractions of the hand's finger length (min ≤ max).
    #[schemars(inner(range(min = STANDOFF_RATIO.min, max = STANDOFF_RATIO.max)))]
    pub standoff_ratio: [f64; 2],
    pub shake: Shake,
    /// MuJoCo's friction cone.
    pub cone: Cone,
    #[schemars(range(min = IMPRATIO.min, max = IMPRATIO.max))]
    pub impratio: f64,
    /// Time constant of every hand contact (s).
    #[schemars(range(min = HAND_SOLREF_TIMECONST_S.min, max = HAND_SOLREF_TIMECONST_S.max))]
    pub hand_solref_timeconst: f64,
    /// Multiplies every finger actuator's force limit.
    #[schemars(range(min = FORCE_SCALE.min, max = FORCE_SCALE.max))]
    pub force_scale: f64,
    /// The object's mass instead of the catalog's (its inertia scales with it).
    #[schemars(range(min = MASS_OVERRIDE_KG.min, max = MASS_OVERRIDE_KG.max))]
    pub mass_override_kg: Option<f64>,
    /// Reruns at half the timestep when the simulation misbehaves.
    #[schemars(range(min = MAX_RETRIES.min, max = MAX_RETRIES.max))]
    pub max_retries: u32,
    /// Reruns never go below this timestep (s).
    #[schemars(range(min = MIN_TIMESTEP_S.min, max = MIN_TIMESTEP_S.max))]
    pub min_timestep: f64,
    /// Deepest contact penetration accepted (m).
    #[schemars(range(min = MAX_PENETRATION_M.min, max = MAX_PENETRATION_M.max))]
    pub max_penetration_m: f64,
    /// Fastest object speed accepted (m/s); bounds the scene's kinetic energy too.
    #[schemars(range(min = MAX_OBJECT_SPEED_MPS.min, max = MAX_OBJECT_SPEED_MPS.max))]
    pub max_object_speed_mps: f64,
    /// Which grasps are kept (the spec's `grasp.type`): every type rejects a grasp that presses
    /// the object with a link's unsensorised (dorsal) side or lets it move in the hand.
    pub grasp_type: GraspType,
}

/// The kind of grasp a trial must end in (`vint_engines/grasp/trial.py`, `judge_type`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum GraspType {
    /// The paper's (VinT-6D App. A.1.3): the palm touches the object (palm taxels active) and the
    /// object's centre lies near the palm (`POWER_CENTRE_RATIO` of its bounding radius).
    #[default]
    Power,
    /// Fingertips only: every active taxel on a fingertip, on at least two fingers.
    Precision,
    /// Any hold that passes the checks every type makes.
    Any,
}

impl GraspType {
    pub const ALL: [GraspType; 3] = [GraspType::Power, GraspType::Precision, GraspType::Any];
}

impl Default for Physics {
    fn default() -> Physics {
        Physics {
            timestep: TIMESTEP_S.default,
            lift_height: LIFT_HEIGHT_M.default,
            hold_s: HOLD_S.default,
            max_drop_m: MAX_DROP_M.default,
            standoff_ratio: STANDOFF_RATIO_DEFAULT,
            shake: Shake::default(),
            cone: Cone::Elliptic,
            impratio: IMPRATIO.default,
            hand_solref_timeconst: HAND_SOLREF_TIMECONST_S.default,
            force_scale: FORCE_SCALE.default,
            mass_override_kg: None,
            max_retries: MAX_RETRIES.default,
            min_timestep: MIN_TIMESTEP_S.default,
            max_penetration_m: MAX_PENETRATION_M.default,
            max_object_speed_mps: MAX_OBJECT_SPEED_MPS.default,
            grasp_type: GraspType::default(),
        }
    }
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Cone {
    #[default]
    Elliptic,
    Pyramidal,
}

/// After the hold the arm shakes the hand: one sine period of peak acceleration `accel_mps2`
/// along each of `directions` fixed directions over the upper hemisphere, `duration_s` in all.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
#[schemars(rename = "GraspShake")]
pub struct Shake {
    pub enabled: bool,
    #[schemars(range(min = SHAKE_ACCEL_MPS2.min, max = SHAKE_ACCEL_MPS2.max))]
    pub accel_mps2: f64,
    #[schemars(range(min = SHAKE_DIRECTIONS.min, max = SHAKE_DIRECTIONS.max))]
    pub directions: u32,
    #[schemars(range(min = SHAKE_DURATION_S.min, max = SHAKE_DURATION_S.max))]
    pub duration_s: f64,
}

impl Default for Shake {
    fn default() -> Shake {
        Shake {
            enabled: false,
            accel_mps2: SHAKE_ACCEL_MPS2.default,
            directions: SHAKE_DIRECTIONS.default,
            duration_s: SHAKE_DURATION_S.default,
        }
    }
}

/// The whole-hand tactile sensor (`vint_engines/grasp/touch.py`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
#[schemars(rename = "GraspTouch")]
pub struct Touch {
    /// A taxel of a link in contact touches the object, and shares the link's contact force, within
    /// this distance of its surface (m).
    #[schemars(range(min = CONTACT_MARGIN_M.min, max = CONTACT_MARGIN_M.max))]
    pub contact_margin_m: f64,
    /// Time over which contact forces are averaged, from the capture on (s).
    #[schemars(range(min = CONTACT_WINDOW_S.min, max = CONTACT_WINDOW_S.max))]
    pub contact_window_s: f64,
    /// Local force below which a taxel reads nothing (N).
    #[schemars(range(min = ACTIVATION_FORCE_N.min, max = ACTIVATION_FORCE_N.max))]
    pub activation_force_n: f64,
    /// Local force at which a new taxel reads half its gain (N).
    #[schemars(range(min = HALF_FORCE_N.min, max = HALF_FORCE_N.max))]
    pub half_force_n: f64,
    /// Power law of the response in force.
    #[schemars(range(min = RESPONSE_EXPONENT.min, max = RESPONSE_EXPONENT.max))]
    pub response_exponent: f64,
    /// Log-normal spread of the per-taxel gains.
    #[schemars(range(min = GAIN_SIGMA.min, max = GAIN_SIGMA.max))]
    pub gain_sigma: f64,
    /// The range, [min, max] (min ≤ max), each grasp's aging is drawn from (uniformly, from the
    /// trial's seed): the sensitivity left (a taxel feels `aging` times the force), 1 a new sensor.
    #[schemars(inner(range(min = AGING.min, max = AGING.max)))]
    pub aging: [f64; 2],
    /// σ (m) of each taxel's displacement in its surface's tangent plane, per axis, drawn once per
    /// hand instance from `gain_seed` on a stream of its own; 0: the layout's exact positions.
    #[schemars(range(min = POSITION_SIGMA_M.min, max = POSITION_SIGMA_M.max))]
    pub position_sigma_m: f64,
    /// Seed of the per-taxel gains and position deviations: the hand's, not the trial's (a
    /// property of the sensor).
    #[schemars(range(max = SEED_MAX))]
    pub gain_seed: u64,
    /// A grasp needs at least this many active taxels to be accepted.
    #[schemars(range(min = MIN_ACTIVE_TAXELS.min, max = MIN_ACTIVE_TAXELS.max))]
    pub min_active_taxels: u32,
}

impl Default for Touch {
    fn default() -> Touch {
        Touch {
            contact_margin_m: CONTACT_MARGIN_M.default,
            contact_window_s: CONTACT_WINDOW_S.default,
            activation_force_n: ACTIVATION_FORCE_N.default,
            half_force_n: HALF_FORCE_N.default,
            response_exponent: RESPONSE_EXPONENT.default,
            gain_sigma: GAIN_SIGMA.default,
            aging: AGING_DEFAULT,
            position_sigma_m: POSITION_SIGMA_M.default,
            gain_seed: GAIN_SEED_DEFAULT,
            min_active_taxels: MIN_ACTIVE_TAXELS.default,
        }
    }
}

/// What a grasp engine answers: which trials were accepted (they become samples) and why the
/// others were not.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct GraspResult {
    /// Grasp indices of the accepted trials.
    pub accepted: Vec<u32>,
    /// Rejected trials by reason class (`no_contact`, `dropped`, `moved_in_hand`, `dorsal_contact`,
    /// `no_palm_contact`, `far_from_palm`, `not_fingertips`, `diverged`, …; PROTOCOL.md lists them).
    #[serde(default)]
    pub rejected: BTreeMap<String, u32>,
    /// Each accepted trial's active taxels per region of the hand's layout (`tip`, `pulp`,
    /// `palm`; every region, 0 included), in the order of `accepted`: the dashboard's
    /// `active_taxels` view reads them without opening `touch.json`.
    #[serde(default)]
    pub active_taxels: Vec<ActiveTaxels>,
}

/// An accepted trial's active taxels, counted per region of the hand's taxel layout.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ActiveTaxels {
    pub grasp_index: u32,
    pub by_region: BTreeMap<String, u32>,
}

/// The grasp stage's JSON and model files, from the artifacts of a real `vintctl run
/// examples/tiny.toml` job (2026-11-29, on commit `4c46d1c`; `scripts/measure_db_bytes.py`
/// prints them): `grasps.json` and `touch.json` per trial the chunk ran (medians over its 6 chunks
/// of 2 trials; rejected trials write less), `object.ply` per object (content-addressed: one
/// object for every chunk and hand; median of tiny's 3 objects, 5–18 KB).
pub const GRASPS_JSON_BYTES_PER_TRIAL: f64 = 7_709.0;
pub const TOUCH_JSON_BYTES_PER_TRIAL: f64 = 13_626.0;
pub const OBJECT_PLY_BYTES: f64 = 11_306.0;

/// A grasp task writes its three documents whatever it accepted.
pub fn files_written() -> u64 {
    [GRASPS_FILE, TOUCH_FILE, MODEL_FILE].len() as u64
}

/// CPU seconds per trial at the default 2 ms timestep with 2.25 s simulated (a 1 s hold).
/// docs/benchmarks.md, "Grasp engine": "a trial costs ~60–80 ms of CPU (2.25 s of simulated time
/// at 2 ms)".
const S_PER_TRIAL: f64 = 0.070;
const REFERENCE_SIM_S: f64 = 2.25;
const REFERENCE_HOLD_S: f64 = 1.0;
const REFERENCE_TIMESTEP_S: f64 = 0.002;

/// CPU seconds one trial costs at `physics`: the measured trial scaled by simulated time and
/// timestep.
pub fn s_per_trial(physics: &Physics) -> f64 {
    let shake_s = if physics.shake.enabled { physics.shake.duration_s } else { 0.0 };
    let simulated = REFERENCE_SIM_S - REFERENCE_HOLD_S + physics.hold_s + shake_s;
    S_PER_TRIAL * (simulated / REFERENCE_SIM_S) * (REFERENCE_TIMESTEP_S / physics.timestep)
}

/// Every trial of the bound run; two documents per trial and a model per object stored.
pub fn cost(work: &super::Workload, task: &Params) -> super::Cost {
    super::Cost {
        cpu_s: s_per_trial(&task.physics) * work.trials as f64,
        bytes: work.trials as f64 * (GRASPS_JSON_BYTES_PER_TRIAL + TOUCH_JSON_BYTES_PER_TRIAL)
            + work.objects as f64 * OBJECT_PLY_BYTES,
    }
}

/// A trial's acceptance in the timing-only worker: its seed is uniform over [0, 2^53), so this
/// accepts `rate` of them.
fn accepted_by_seed(seed: u64, rate: f64) -> bool {
    (seed as f64) / ((SEED_MAX as f64) + 1.0) < rate
}

/// The timing-only answer: trials accepted by their seeds (within the quota), the documents
/// sized by the trials run.
pub fn fake(task: &Params, accept_rate: f64) -> (GraspResult, Vec<super::FakeFile>) {
    use super::{FakeFile, FileKind};
    let mut result = GraspResult::default();
    let mut ran = 0u64;
    for trial in &task.trials {
        if task.accept.is_some_and(|quota| result.accepted.len() as u32 >= quota) {
            break;
        }
        ran += 1;
        if accepted_by_seed(trial.seed, accept_rate) {
            result.accepted.push(trial.grasp_index);
        } else {
            *result.rejected.entry("timing_only".into()).or_default() += 1;
        }
    }
    let per_trial = |bytes: f64| (bytes * ran as f64).round() as u64;
    let files = vec![
        FakeFile { name: GRASPS_FILE.into(), kind: FileKind::Json, size: per_trial(GRASPS_JSON_BYTES_PER_TRIAL) },
        FakeFile { name: TOUCH_FILE.into(), kind: FileKind::Json, size: per_trial(TOUCH_JSON_BYTES_PER_TRIAL) },
        FakeFile { name: MODEL_FILE.into(), kind: FileKind::Ply, size: OBJECT_PLY_BYTES as u64 },
    ];
    (result, files)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timing_only_acceptance_follows_the_rate_over_many_seeds() {
        let seeds = (0..10_000u32).map(|i| crate::seed::grasp_trial(7, "mug", "trx3", i));
        let share = seeds.filter(|&s| accepted_by_seed(s, 0.84)).count() as f64 / 10_000.0;
        assert!((share - 0.84).abs() < 0.02, "{share}");
        assert!(!accepted_by_seed(0, 0.0) && accepted_by_seed(SEED_MAX, 1.0));
    }
}
