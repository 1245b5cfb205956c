//! The built-in objects and hands a spec can name.
//!
//! Both are data, defined once under `catalog/` at the repository root and compiled in here:
//! `catalog/objects.toml` (dimensions, masses, materials, textures, symmetries, procedural shapes) and
//! `catalog/hands.toml` with each hand's taxel layout (`catalog/hands/<hand>/taxels.csv`). The
//! engines build geometry from the same entries; this module only validates names and hands the
//! entries on in task parameters.

use std::collections::BTreeMap;
use std::sync::LazyLock;

use serde::{Deserialize, Serialize};

const OBJECTS_TOML: &str = include_str!("../../../catalog/objects.toml");
const HANDS_TOML: &str = include_str!("../../../catalog/hands.toml");
/// Taxel layouts of the built-in hands, by the path `catalog/hands.toml` gives them.
const TAXEL_LAYOUTS: &[(&str, &str)] = &[
    ("hands/trx3/taxels.csv", include_str!("../../../catalog/hands/trx3/taxels.csv")),
    ("hands/allegro/taxels.csv", include_str!("../../../catalog/hands/allegro/taxels.csv")),
];

/// A graspable object, exactly as `catalog/objects.toml` describes it: the grasp stage's object
/// parameter (`contract::object`), so the catalog is checked against that schema when it loads.
pub use crate::contract::object::ObjectEntry;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HandEntry {
    pub name: String,
    pub fingers: u32,
    pub dof: u32,
    pub description: String,
    /// Taxel layout path relative to `catalog/`.
    pub taxels: String,
}

/// A hand with its taxel counts per region (tip, pulp, palm).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct HandModel {
    #[serde(flatten)]
    pub entry: HandEntry,
    pub taxels_per_region: BTreeMap<String, u32>,
}

impl HandModel {
    pub fn taxel_count(&self) -> u32 {
        self.taxels_per_region.values().sum()
    }
}

#[derive(Deserialize)]
struct ObjectsFile {
    object: Vec<ObjectEntry>,
}

#[derive(Deserialize)]
struct HandsFile {
    hand: Vec<HandEntry>,
}

/// The compiled-in catalog; `catalog_parses` (below) proves these files parse.
static OBJECTS: LazyLock<Vec<ObjectEntry>> = LazyLock::new(|| match toml::from_str::<ObjectsFile>(OBJECTS_TOML) {
    Ok(f) => f.object,
    Err(e) => panic!("catalog/objects.toml is invalid: {e}"),
});

static HANDS: LazyLock<Vec<HandModel>> = LazyLock::new(|| {
    let file: HandsFile = match toml::from_str(HANDS_TOML) {
        Ok(f) => f,
        Err(e) => panic!("catalog/hands.toml is invalid: {e}"),
    };
    file.hand
        .into_iter()
        .map(|entry| {
            let csv = TAXEL_LAYOUTS.iter().find(|(p, _)| *p == entry.taxels).map(|(_, c)| *c).unwrap_or("");
            HandModel { taxels_per_region: count_regions(csv), entry }
        })
        .collect()
});

/// Taxels per region of a layout CSV (`taxel,link,x,y,z,nx,ny,nz,region`).
fn count_regions(csv: &str) -> BTreeMap<String, u32> {
    let mut counts = BTreeMap::new();
    for line in csv.lines().skip(1).filter(|l| !l.trim().is_empty()) {
        if let Some(region) = line.rsplit(',').next() {
            *counts.entry(region.trim().to_string()).or_insert(0) += 1;
        }
    }
    counts
}

pub fn objects() -> &'static [ObjectEntry] {
    &OBJECTS
}

pub fn hands() -> &'static [HandModel] {
    &HANDS
}

pub fn object(name: &str) -> Option<&'static ObjectEntry> {
    OBJECTS.iter().find(|o| o.name == name)
}

pub fn hand(name: &str) -> Option<&'static HandModel> {
    HANDS.iter().find(|h| h.entry.name == name)
}

/// HDRI environments bundled with Blender (`studiolights/world`).
pub const ENVIRONMENTS: &[&str] = &["city", "courtyard", "forest", "interior", "night", "studio", "sunrise", "sunset"];

#[cfg(test)]
mod tests {
    use super::*;
    use crate::contract::object::{Axis, Material, Symmetry, Texture, rotation_about, rotation_of};

    #[test]
    fn catalog_has_the_papers_21_ycb_and_5_everyday_objects() {
        let ycb = objects().iter().filter(|o| !o.ycb_id.is_empty()).count();
        assert!(objects().len() >= 26, "VinT-Sim has 26 objects, the catalog {}", objects().len());
        assert_eq!(ycb, 21, "VinT-6D's YCB-Video objects");
        assert!(objects().len() - ycb >= 5, "VinT-6D's everyday objects");
        assert!(objects().iter().any(|o| o.material == Material::Glass && o.ycb_id.is_empty()), "a transparent one");
        assert!(objects().iter().any(|o| o.material == Material::Metal && o.ycb_id.is_empty()), "a reflective one");
        assert!(!hands().is_empty());
    }

    #[test]
    fn every_object_but_glass_carries_a_texture() {
        for o in objects() {
            assert_eq!(o.texture == Texture::Plain, o.material == Material::Glass, "{}: {:?}", o.name, o.texture);
        }
    }

    #[test]
    fn declared_symmetries_are_rigid_and_kept_by_the_texture() {
        for o in objects() {
            for c in &o.symmetries_continuous {
                let norm = c.axis.iter().map(|v| v * v).sum::<f64>().sqrt();
                assert!((norm - 1.0).abs() < 1e-9, "{}: axis {:?}", o.name, c.axis);
                assert!(
                    o.texture.keeps_turns_about(c.axis),
                    "{}: {:?} breaks turns about {:?}",
                    o.name,
                    o.texture,
                    c.axis
                );
            }
            for m in &o.symmetries_discrete {
                let r = rotation_of(m);
                for i in 0..3 {
                    for j in 0..3 {
                        let dot: f64 = (0..3).map(|k| r[k][i] * r[k][j]).sum();
                        assert!(
                            (dot - if i == j { 1.0 } else { 0.0 }).abs() < 1e-9,
                            "{}: {m:?} is not a rotation",
                            o.name
                        );
                    }
                }
                assert_eq!(m[12..], [0.0, 0.0, 0.0, 1.0], "{}", o.name);
                assert!(o.texture.keeps_rotation(r), "{}: {:?} breaks {m:?}", o.name, o.texture);
            }
        }
    }

    #[test]
    fn a_print_breaks_every_symmetry_and_a_plain_label_keeps_turns_about_z() {
        let printed = Texture::Label { band: [0.1, 0.9], print: true };
        assert!(!printed.keeps_turns_about([0.0, 0.0, 1.0]));
        assert!(!printed.keeps_rotation(rotation_of(&rotation_about(Axis::Z, 2))));
        let ruled = Texture::Label { band: [0.1, 0.9], print: false };
        assert!(ruled.keeps_turns_about([0.0, 0.0, 1.0]) && !ruled.keeps_turns_about([1.0, 0.0, 0.0]));
        assert!(ruled.keeps_rotation(rotation_of(&rotation_about(Axis::X, 2))), "a centred band survives the flip");
        let low = Texture::Label { band: [0.1, 0.6], print: false };
        assert!(!low.keeps_rotation(rotation_of(&rotation_about(Axis::X, 2))), "an off-centre band does not");
        for o in objects() {
            if matches!(o.texture, Texture::Label { print: true, .. } | Texture::Panels { print: true }) {
                assert!(o.symmetries_continuous.is_empty() && o.symmetries_discrete.is_empty(), "{}", o.name);
            }
        }
    }

    #[test]
    fn the_user_tag_expands_to_full_sets() {
        let (c, d) = Symmetry::ContinuousZFlip.expand();
        assert_eq!((c.len(), d), (1, vec![rotation_about(Axis::X, 2)]));
        assert_eq!(Symmetry::DiscreteZ4.expand().1.len(), 3);
        assert_eq!(Symmetry::DiscreteBox.expand().1.len(), 3);
        assert_eq!(Symmetry::None.expand(), (vec![], vec![]));
        // A quarter turn about z takes x to y.
        let q = rotation_about(Axis::Z, 1);
        assert_eq!([q[0], q[4], q[8]], [0.0, 1.0, 0.0]);
    }

    #[test]
    fn object_names_are_unique_identifiers() {
        let mut seen = std::collections::BTreeSet::new();
        for o in objects() {
            assert!(o.name.bytes().all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_'), "{}", o.name);
            assert!(seen.insert(&o.name), "duplicate {}", o.name);
            assert!(o.mass_kg > 0.0 && o.mass_kg < 10.0, "{}: mass {}", o.name, o.mass_kg);
            assert!(crate::contract::object::MASS_KG.contains(o.mass_kg), "{}: mass {}", o.name, o.mass_kg);
        }
    }

    #[test]
    fn every_hand_has_its_taxel_layout_compiled_in() {
        for h in hands() {
            assert!(
                TAXEL_LAYOUTS.iter().any(|(p, _)| *p == h.entry.taxels),
                "{}: layout {} not embedded",
                h.entry.name,
                h.entry.taxels
            );
            assert!(h.taxel_count() > 0);
            for region in h.taxels_per_region.keys() {
                assert!(["tip", "pulp", "palm"].contains(&region.as_str()), "{}: region {region}", h.entry.name);
            }
        }
    }

    #[test]
    fn built_in_hands_have_the_papers_taxel_counts() {
        assert_eq!(hand("allegro").map(HandModel::taxel_count), Some(679));
        assert_eq!(hand("trx3").map(HandModel::taxel_count), Some(620));
        assert_eq!(hand("allegro").map(|h| h.entry.dof), Some(16));
    }
}
