//! The noise stage: a depth-sensor model applied to every depth image of one grasp's render task
//! (`vint_engines.noise`).

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::render::{VIEW_INDEX, ViewFile};
use super::{Bound, SEED_MAX};

pub const SIGMA_BASE_M: Bound<f64> = Bound::new(0.0, 0.1, 0.0005);
pub const SIGMA_PER_M: Bound<f64> = Bound::new(0.0, 0.1, 0.001);
/// The valid range of readings; `min_range_m` < `max_range_m`.
pub const MIN_RANGE_M: Bound<f64> = Bound::new(0.0, 20.0, 0.25);
pub const MAX_RANGE_M: Bound<f64> = Bound::new(0.0, 20.0, 3.86);
pub const EDGE_HOLE_JUMP_M: Bound<f64> = Bound::new(0.001, 10.0, 0.05);
pub const DROPOUT: Bound<f64> = Bound::new(0.0, 1.0, 0.01);

/// A noise task's parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
#[schemars(rename = "NoiseParams")]
pub struct Params {
    #[serde(default)]
    pub noise: NoiseModel,
    #[schemars(length(min = 1, max = super::render::MAX_VIEWS))]
    pub views: Vec<View>,
}

/// The depth-noise model (`vint_engines/noise/model.py` documents each term).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct NoiseModel {
    /// σ at 0.5 m and closer (m).
    #[schemars(range(min = SIGMA_BASE_M.min, max = SIGMA_BASE_M.max))]
    pub sigma_base_m: f64,
    /// σ growth per metre beyond 0.5 m.
    #[schemars(range(min = SIGMA_PER_M.min, max = SIGMA_PER_M.max))]
    pub sigma_per_m: f64,
    #[schemars(range(min = MIN_RANGE_M.min, max = MIN_RANGE_M.max))]
    pub min_range_m: f64,
    #[schemars(range(min = MAX_RANGE_M.min, max = MAX_RANGE_M.max))]
    pub max_range_m: f64,
    /// A pixel whose 3×3 neighbourhood spans more than this becomes a hole (m).
    #[schemars(range(min = EDGE_HOLE_JUMP_M.min, max = EDGE_HOLE_JUMP_M.max))]
    pub edge_hole_jump_m: f64,
    /// Probability that a pixel drops out.
    #[schemars(range(min = DROPOUT.min, max = DROPOUT.max))]
    pub dropout: f64,
}

impl Default for NoiseModel {
    fn default() -> NoiseModel {
        NoiseModel {
            sigma_base_m: SIGMA_BASE_M.default,
            sigma_per_m: SIGMA_PER_M.default,
            min_range_m: MIN_RANGE_M.default,
            max_range_m: MAX_RANGE_M.default,
            edge_hole_jump_m: EDGE_HOLE_JUMP_M.default,
            dropout: DROPOUT.default,
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

/// The noisy depth of view `view` (`v03_depth_noisy.npy`; float32 metres, 0 = invalid).
pub fn noisy_depth_file(view: u32) -> String {
    format!("v{view:02}_depth_noisy.npy")
}

/// A noise task reads its render task's depth images.
pub fn reads(file: &str) -> bool {
    file.starts_with('v') && file.ends_with(&ViewFile::Depth.name(0)[3..])
}

/// What a noise engine answers.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct NoiseResult {
    /// Views made noisy.
    pub views: u32,
}
