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
/// A BOP dataset's own `obj_id` a spec's object may keep (ycbv's are 1–21, T-LESS's 1–30): below
/// the built-in objects' ids (`catalog::CATALOG_OBJECT_IDS`, 101 up) and the numbered user objects'
/// (`catalog::USER_OBJECT_IDS`, 1001 up), so no two sources can meet.
pub const BOP_OBJ_ID: Bound<u32> = Bound::new(1, 100, 1);

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
    /// Surface class the renderer maps to a material (the depth-noise model reads it too).
    pub material: Material,
    /// The printed or natural pattern on the surface (`docs/objects.md`); with the shape it decides
    /// which symmetries the object's appearance has.
    #[serde(default)]
    pub texture: Texture,
    /// The real product's colours, which the render engine paints the texture with. Absent (a
    /// spec's own objects), the renderer picks them from small palettes by the object's name.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub colours: Option<Colours>,
    /// Rotations about an axis by any angle that leave the textured object looking the same, as
    /// BOP's `models_info.json` lists them (metres, object frame).
    #[serde(default)]
    pub symmetries_continuous: Vec<ContinuousSymmetry>,
    /// Rigid transforms other than the identity that leave the textured object looking the same:
    /// 4×4 row-major, translation in metres in the object frame (BOP's `models_info.json` form,
    /// whose translations are millimetres).
    #[serde(default)]
    pub symmetries_discrete: Vec<DiscreteSymmetry>,
    pub description: String,
    pub shape: Shape,
    /// The BOP `obj_id` the exports give the object: a BOP dataset's model keeps its own. Absent:
    /// the exports number it (built-in objects from 101, a spec's own from 1001).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schemars(range(min = BOP_OBJ_ID.min, max = BOP_OBJ_ID.max))]
    pub obj_id: Option<u32>,
}

/// A continuous symmetry: rotation by any angle about `axis` (a unit vector) through `offset`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ContinuousSymmetry {
    #[schemars(inner(range(min = -1.0, max = 1.0)))]
    pub axis: [f64; 3],
    #[schemars(inner(range(min = POSITION_M.min, max = POSITION_M.max)))]
    pub offset: [f64; 3],
}

/// A discrete symmetry: a 4×4 rigid transform, row-major, the last row `0 0 0 1`.
pub type DiscreteSymmetry = [f64; 16];

/// An object's surface pattern, built by the render engine as a procedural shader in object
/// coordinates (`vint_engines/render/textures.py`), in the entry's `colours` (or, without them,
/// colours picked from the object's name).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Texture {
    /// One colour (glass stays clear).
    #[default]
    Plain,
    /// A label wrapped about the z axis between heights `band` (fractions of the object's height,
    /// bottom to top), ruled with lines mirrored about the band's middle. `print`: a logo and lines
    /// of text at one azimuth in the band's upper half.
    Label {
        #[schemars(inner(range(min = 0.0, max = 1.0)))]
        band: [f64; 2],
        print: bool,
    },
    /// A printed panel framed on every face, laid out the same way on each. `print`: text and a
    /// logo in the upper half of the object.
    Panels { print: bool },
    /// Growth rings about `axis` (through the object's centre), wavy along it.
    WoodGrain { axis: Axis },
    /// A glaze whose colour and gloss vary over the surface.
    Glaze,
    /// Brushed metal: fine streaks around the z axis, varying with height.
    Brushed,
    /// Small spots scattered over the surface (foam pores, fruit speckles).
    Speckle,
}

/// A linear-RGB colour (what the renderer's shader takes; not sRGB), each channel 0–1.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(transparent)]
pub struct Rgb(#[schemars(inner(range(min = 0.0, max = 1.0)))] pub [f64; 3]);

/// The colours an object's texture is painted in: the real product's, as photographs of it show
/// them (`catalog/objects.toml` names the fact per object). What each colour paints, per texture
/// kind (`docs/objects.md`): `base` is the body (outside a label's band, a box's face borders,
/// wood's earlywood, the metal, the glaze, the foam); `band` the second colour (a label's band, a
/// box's panels, wood's latewood, glaze's pools, brushed metal's dull streaks, speckle's spots;
/// default: `base` for a label or panels, else the kind's darker shade); `print` a label's edges
/// and logo, a box's inner panel and logo (default: `base`). Text and ruling stay ink.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Colours {
    pub base: Rgb,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub band: Option<Rgb>,
    /// A label band's lower half, when the label is two-toned (Campbell's red over white).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lower: Option<Rgb>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub print: Option<Rgb>,
    /// Everything above a height: a bottle's cap of another colour.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cap: Option<Cap>,
}

/// The top of an object in another colour: everything above `above` (a fraction of the object's
/// height, bottom to top).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Cap {
    #[schemars(range(min = 0.0, max = 1.0))]
    pub above: f64,
    pub colour: Rgb,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Axis {
    X,
    Y,
    Z,
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

/// A spec's shorthand for a user object's symmetries (`[object.NAME] symmetry = …`), expanded by
/// `Symmetry::expand` into the BOP-style sets an `ObjectEntry` carries.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Symmetry {
    #[default]
    None,
    /// Any turn about z.
    ContinuousZ,
    /// Any turn about z, and the half-turn about x (a plain cylinder).
    ContinuousZFlip,
    /// The half-turn about z.
    DiscreteZ2,
    /// Quarter turns about z.
    DiscreteZ4,
    /// The half-turns about x, y and z (a plain box with three different edges).
    DiscreteBox,
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
    pub const ALL: [Symmetry; 6] = [
        Symmetry::None,
        Symmetry::ContinuousZ,
        Symmetry::ContinuousZFlip,
        Symmetry::DiscreteZ2,
        Symmetry::DiscreteZ4,
        Symmetry::DiscreteBox,
    ];

    /// The continuous and discrete symmetries the tag stands for, about the object frame's origin.
    pub fn expand(self) -> (Vec<ContinuousSymmetry>, Vec<DiscreteSymmetry>) {
        let z = ContinuousSymmetry { axis: [0.0, 0.0, 1.0], offset: [0.0; 3] };
        let quarter = rotation_about(Axis::Z, 1);
        let half = |axis| rotation_about(axis, 2);
        match self {
            Symmetry::None => (vec![], vec![]),
            Symmetry::ContinuousZ => (vec![z], vec![]),
            Symmetry::ContinuousZFlip => (vec![z], vec![half(Axis::X)]),
            Symmetry::DiscreteZ2 => (vec![], vec![half(Axis::Z)]),
            Symmetry::DiscreteZ4 => (vec![], vec![quarter, half(Axis::Z), rotation_about(Axis::Z, 3)]),
            Symmetry::DiscreteBox => (vec![], vec![half(Axis::X), half(Axis::Y), half(Axis::Z)]),
        }
    }
}

/// `quarters` quarter turns about a coordinate axis, as a 4×4 row-major transform; exact (the
/// entries are 0 and ±1).
pub fn rotation_about(axis: Axis, quarters: u32) -> DiscreteSymmetry {
    let (c, s) = [(1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0)][(quarters % 4) as usize];
    let r = match axis {
        Axis::X => [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]],
        Axis::Y => [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]],
        Axis::Z => [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]],
    };
    let mut m = [0.0; 16];
    for (i, row) in r.iter().enumerate() {
        m[4 * i..4 * i + 3].copy_from_slice(row);
    }
    m[15] = 1.0;
    m
}

impl Axis {
    pub fn unit(self) -> [f64; 3] {
        match self {
            Axis::X => [1.0, 0.0, 0.0],
            Axis::Y => [0.0, 1.0, 0.0],
            Axis::Z => [0.0, 0.0, 1.0],
        }
    }
}

impl Texture {
    /// Whether the pattern looks the same after rotating the object by `r` (3×3, about the
    /// object frame's origin, the centre of its bounding box): the rule each kind's shader is
    /// built to obey (`vint_engines/render/textures.py`). A symmetry the pattern breaks must not
    /// be declared, whatever the shape allows.
    pub fn keeps_rotation(&self, r: [[f64; 3]; 3]) -> bool {
        let keeps_axis = |a: Axis, sign_too: bool| {
            let u = a.unit();
            let image = [0, 1, 2].map(|i| r[i][0] * u[0] + r[i][1] * u[1] + r[i][2] * u[2]);
            let along = image[0] * u[0] + image[1] * u[1] + image[2] * u[2];
            if sign_too { along > 1.0 - 1e-9 } else { along.abs() > 1.0 - 1e-9 }
        };
        let identity = (0..3).all(|i| (0..3).all(|j| (r[i][j] - if i == j { 1.0 } else { 0.0 }).abs() < 1e-9));
        match self {
            Texture::Plain | Texture::Panels { print: false } => true,
            // Mirrored ruling: a flip of z keeps it only when the band is centred in height.
            Texture::Label { print: false, band } => {
                keeps_axis(Axis::Z, true) || (keeps_axis(Axis::Z, false) && (band[0] + band[1] - 1.0).abs() < 1e-9)
            }
            Texture::WoodGrain { axis } => keeps_axis(*axis, false),
            Texture::Brushed => keeps_axis(Axis::Z, true),
            Texture::Label { print: true, .. }
            | Texture::Panels { print: true }
            | Texture::Glaze
            | Texture::Speckle => identity,
        }
    }

    /// Whether the pattern looks the same after any rotation about `axis` through the origin.
    pub fn keeps_turns_about(&self, axis: [f64; 3]) -> bool {
        let along_z = axis[0].abs() < 1e-9 && axis[1].abs() < 1e-9;
        match self {
            Texture::Plain | Texture::Panels { print: false } => true,
            Texture::Label { print: false, .. } | Texture::Brushed => along_z,
            Texture::WoodGrain { axis: a } => {
                let u = a.unit();
                (axis[0] * u[0] + axis[1] * u[1] + axis[2] * u[2]).abs() > 1.0 - 1e-9
            }
            Texture::Label { print: true, .. }
            | Texture::Panels { print: true }
            | Texture::Glaze
            | Texture::Speckle => false,
        }
    }

    /// The `kind` tag (`label`, `wood_grain`, …).
    pub fn kind(&self) -> &'static str {
        match self {
            Texture::Plain => "plain",
            Texture::Label { .. } => "label",
            Texture::Panels { .. } => "panels",
            Texture::WoodGrain { .. } => "wood_grain",
            Texture::Glaze => "glaze",
            Texture::Brushed => "brushed",
            Texture::Speckle => "speckle",
        }
    }
}

impl Colours {
    /// Whether the colouring looks the same after rotating the object by `r` (see
    /// `Texture::keeps_rotation`): a two-toned label or a cap depends on the height alone, so it
    /// keeps only the rotations that keep +z; the other colours follow the texture's pattern.
    pub fn keeps_rotation(&self, r: [[f64; 3]; 3]) -> bool {
        (self.lower.is_none() && self.cap.is_none()) || r[2][2] > 1.0 - 1e-9
    }

    /// Whether the colouring looks the same after any rotation about `axis` through the origin.
    pub fn keeps_turns_about(&self, axis: [f64; 3]) -> bool {
        (self.lower.is_none() && self.cap.is_none()) || (axis[0].abs() < 1e-9 && axis[1].abs() < 1e-9)
    }
}

impl ObjectEntry {
    /// Whether the object's appearance (texture and colours) looks the same after rotating it by
    /// `r`: a symmetry it breaks must not be declared, whatever the shape allows.
    pub fn looks_the_same_after(&self, r: [[f64; 3]; 3]) -> bool {
        self.texture.keeps_rotation(r) && self.colours.is_none_or(|c| c.keeps_rotation(r))
    }

    /// Whether the object's appearance looks the same after any rotation about `axis`.
    pub fn looks_the_same_turned_about(&self, axis: [f64; 3]) -> bool {
        self.texture.keeps_turns_about(axis) && self.colours.is_none_or(|c| c.keeps_turns_about(axis))
    }
}

/// The 3×3 rotation of a row-major 4×4 transform.
pub fn rotation_of(m: &DiscreteSymmetry) -> [[f64; 3]; 3] {
    [[m[0], m[1], m[2]], [m[4], m[5], m[6]], [m[8], m[9], m[10]]]
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
