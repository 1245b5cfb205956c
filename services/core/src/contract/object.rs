//! A graspable object as task parameters carry it: the schema of `catalog/objects.toml`'s entries
//! (documented at the top of that file), typed. The grasp stage receives one; the engines build
//! geometry from it (`vint_engines/objects`), which also checks what a schema cannot (a revolved
//! profile that crosses itself, a mesh that is not watertight).

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::Bound;

/// Any single dimension of a shape: half a millimetre to a metre.
pub const LENGTH_M: Bound<f64> = Bound::new(0.0005, 1.0, 0.05);
/// An object's mass.
pub const MASS_KG: Bound<f64> = Bound::new(0.0005, 20.0, 0.1);
/// Where a compound's part may sit (each coordinate, metres).
pub const POSITION_M: Bound<f64> = Bound::new(-1.0, 1.0, 0.0);
/// A part's rotation about each fixed axis (degrees).
pub const EULER_DEG: Bound<f64> = Bound::new(-360.0, 360.0, 0.0);
/// A profile point's radius (may be 0 at the ends) and height (metres).
pub const PROFILE_R_M: Bound<f64> = Bound::new(0.0, 1.0, 0.0);
pub const PROFILE_Z_M: Bound<f64> = Bound::new(-1.0, 1.0, 0.0);
/// Points of a revolved profile, parts of a compound.
pub const PROFILE_POINTS: Bound<u32> = Bound::new(2, 256, 2);
pub const PARTS: Bound<u32> = Bound::new(1, 32, 1);
/// File units to metres of a mesh file.
pub const MESH_SCALE: Bound<f64> = Bound::new(1e-6, 1e3, 1.0);

/// An object: a catalog entry, or a spec's own mesh object in the same schema.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ObjectEntry {
    #[schemars(regex(pattern = r"^[a-z0-9_]{1,64}$"))]
    pub name: String,
    /// YCB object number, "" when not a YCB object.
    pub ycb_id: String,
    #[schemars(range(min = MASS_KG.min, max = MASS_KG.max))]
    pub mass_kg: f64,
    /// Surface class the renderer maps to a material.
    pub material: Material,
    /// Symmetry about the object's z axis (BOP-style; pose metrics use it: ADD-S when symmetric).
    pub symmetry: Symmetry,
    pub description: String,
    pub shape: Shape,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Material {
    Plastic,
    Metal,
    Glass,
    Paper,
    Cardboard,
    Wood,
    Ceramic,
    Rubber,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Symmetry {
    #[default]
    None,
    ContinuousZ,
    DiscreteZ2,
    DiscreteZ4,
}

/// An object's shape, in metres, in the object's frame (see `catalog/objects.toml`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum Shape {
    /// Axis +z, centred on its origin.
    Cylinder {
        #[schemars(range(min = LENGTH_M.min, max = LENGTH_M.max))]
        radius_m: f64,
        #[schemars(range(min = LENGTH_M.min, max = LENGTH_M.max))]
        height_m: f64,
    },
    /// Full edge lengths along x, y, z.
    Box {
        #[schemars(inner(range(min = LENGTH_M.min, max = LENGTH_M.max)))]
        size_m: [f64; 3],
    },
    /// The solid swept by the `[r, z]` profile (bottom to top) about +z, closed along the axis.
    Revolved {
        #[schemars(length(min = PROFILE_POINTS.min, max = PROFILE_POINTS.max))]
        profile_m: Vec<ProfilePoint>,
    },
    /// The union of overlapping parts.
    Compound {
        #[schemars(length(min = PARTS.min, max = PARTS.max))]
        parts: Vec<Part>,
    },
    /// A triangle mesh file: `path` relative to `catalog/` (built-in objects) or `asset`, the
    /// SHA-256 of a file submitted with the job (a spec's own objects).
    Mesh {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        path: Option<String>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        #[schemars(regex(pattern = r"^[0-9a-f]{64}$"))]
        asset: Option<String>,
        #[schemars(range(min = MESH_SCALE.min, max = MESH_SCALE.max))]
        scale: f64,
    },
}

/// `[r, z]`: radius (≥ 0; only the first and last point may lie on the axis) and height.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct ProfilePoint(
    #[schemars(range(min = PROFILE_R_M.min, max = PROFILE_R_M.max))] pub f64,
    #[schemars(range(min = PROFILE_Z_M.min, max = PROFILE_Z_M.max))] pub f64,
);

/// A part of a compound: its shape, rotated by `euler_deg` (about the fixed x, then y, then z
/// axes), then moved to `pos_m`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum Part {
    Cylinder {
        #[schemars(range(min = LENGTH_M.min, max = LENGTH_M.max))]
        radius_m: f64,
        #[schemars(range(min = LENGTH_M.min, max = LENGTH_M.max))]
        height_m: f64,
        #[schemars(inner(range(min = POSITION_M.min, max = POSITION_M.max)))]
        pos_m: [f64; 3],
        #[serde(default)]
        #[schemars(inner(range(min = EULER_DEG.min, max = EULER_DEG.max)))]
        euler_deg: [f64; 3],
    },
    Box {
        #[schemars(inner(range(min = LENGTH_M.min, max = LENGTH_M.max)))]
        size_m: [f64; 3],
        #[schemars(inner(range(min = POSITION_M.min, max = POSITION_M.max)))]
        pos_m: [f64; 3],
        #[serde(default)]
        #[schemars(inner(range(min = EULER_DEG.min, max = EULER_DEG.max)))]
        euler_deg: [f64; 3],
    },
    Revolved {
        #[schemars(length(min = PROFILE_POINTS.min, max = PROFILE_POINTS.max))]
        profile_m: Vec<ProfilePoint>,
        #[schemars(inner(range(min = POSITION_M.min, max = POSITION_M.max)))]
        pos_m: [f64; 3],
        #[serde(default)]
        #[schemars(inner(range(min = EULER_DEG.min, max = EULER_DEG.max)))]
        euler_deg: [f64; 3],
    },
}

impl Material {
    pub const ALL: [Material; 8] = [
        Material::Plastic,
        Material::Metal,
        Material::Glass,
        Material::Paper,
        Material::Cardboard,
        Material::Wood,
        Material::Ceramic,
        Material::Rubber,
    ];
}

impl Symmetry {
    pub const ALL: [Symmetry; 4] = [Symmetry::None, Symmetry::ContinuousZ, Symmetry::DiscreteZ2, Symmetry::DiscreteZ4];
}

impl Shape {
    /// The shape's `type` tag (`cylinder`, `box`, …).
    pub fn kind(&self) -> &'static str {
        match self {
            Shape::Cylinder { .. } => "cylinder",
            Shape::Box { .. } => "box",
            Shape::Revolved { .. } => "revolved",
            Shape::Compound { .. } => "compound",
            Shape::Mesh { .. } => "mesh",
        }
    }
}

impl std::fmt::Display for Material {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.pad(&name_of(self))
    }
}

impl std::fmt::Display for Symmetry {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.pad(&name_of(self))
    }
}

/// The snake_case name serde gives a unit enum variant (`Material::Ceramic` → `ceramic`).
pub fn name_of<T: Serialize>(value: &T) -> String {
    match serde_json::to_value(value) {
        Ok(serde_json::Value::String(s)) => s,
        _ => String::new(),
    }
}
