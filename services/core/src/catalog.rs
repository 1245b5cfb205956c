//! Built-in objects and hands that a spec can name.
//!
//! Dimensions and masses are those published for the YCB objects. The hand models themselves live
//! with the grasp engine (`workers/engines/vint_engines/grasp`); this catalog only names them so a
//! spec can be validated without starting an engine.

use serde::Serialize;

/// A graspable object, as the grasp and render engines receive it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ObjectModel {
    pub name: &'static str,
    /// Primitive the engines build: `cylinder` (radius, height).
    pub shape: &'static str,
    pub radius: f64,
    pub height: f64,
    /// kg
    pub mass: f64,
    /// Surface class the renderer maps to a material.
    pub material: &'static str,
}

pub const OBJECTS: &[ObjectModel] = &[
    // YCB 005: 66.2 mm diameter, 101.8 mm tall, 349 g.
    ObjectModel {
        name: "tomato_soup_can",
        shape: "cylinder",
        radius: 0.0331,
        height: 0.1018,
        mass: 0.349,
        material: "metal",
    },
    // YCB 002: 102 mm diameter, 140 mm tall, 414 g (a coffee can; still a power grasp for trx3).
    ObjectModel {
        name: "master_chef_can",
        shape: "cylinder",
        radius: 0.051,
        height: 0.140,
        mass: 0.414,
        material: "metal",
    },
    // YCB 007: 85.6 mm diameter, 33.5 mm tall, 171 g.
    ObjectModel {
        name: "tuna_fish_can",
        shape: "cylinder",
        radius: 0.0428,
        height: 0.0335,
        mass: 0.171,
        material: "metal",
    },
];

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct HandModel {
    pub name: &'static str,
    pub fingers: u32,
    pub dof: u32,
}

pub const HANDS: &[HandModel] = &[HandModel {
    name: "trx3",
    fingers: 3,
    dof: 9,
}];

pub fn object(name: &str) -> Option<&'static ObjectModel> {
    OBJECTS.iter().find(|o| o.name == name)
}

pub fn hand(name: &str) -> Option<&'static HandModel> {
    HANDS.iter().find(|h| h.name == name)
}

/// HDRI environments bundled with Blender (`studiolights/world`).
pub const ENVIRONMENTS: &[&str] = &[
    "city",
    "courtyard",
    "forest",
    "interior",
    "night",
    "studio",
    "sunrise",
    "sunset",
];

/// Modalities a spec can request.
pub const MODALITIES: &[&str] = &["rgb", "depth", "depth_noisy", "mask", "pose"];
