//! The built-in objects and hands a spec can name.
//!
//! Both are data, defined once under `catalog/` at the repository root and compiled in here:
//! `catalog/objects.toml` (dimensions, masses, materials, textures, symmetries, procedural shapes) and
//! `catalog/hands.toml` with each hand's taxel layout (`catalog/hands/<hand>/taxels.csv`). The
//! engines build geometry from the same entries; this module only validates names and hands the
//! entries on in task parameters. It also owns the built-in objects' BOP ids and which YCB-Video
//! object each stands in for.

use std::collections::BTreeMap;
use std::sync::LazyLock;

use serde::{Deserialize, Serialize};

// `catalog` in this crate is a symbolic link to the repository's `catalog/`, so the files are
// inside the crate and `cargo package` puts them in its tarball.
const OBJECTS_TOML: &str = include_str!("../catalog/objects.toml");
const HANDS_TOML: &str = include_str!("../catalog/hands.toml");
/// Taxel layouts of the built-in hands, by the path `catalog/hands.toml` gives them.
const TAXEL_LAYOUTS: &[(&str, &str)] = &[
    ("hands/trx3/taxels.csv", include_str!("../catalog/hands/trx3/taxels.csv")),
    ("hands/allegro/taxels.csv", include_str!("../catalog/hands/allegro/taxels.csv")),
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

/// BOP `obj_id` of the first built-in object; the others follow in catalog order. The built-in
/// objects are procedural stand-ins, not YCB-Video's scanned models (another shape, another frame,
/// another texture), so they must never take ycbv's ids 1–21: a dataset mixed with ycbv would read
/// them as those models. `dataset.json` says which ycbv object each stands in for.
pub const CATALOG_OBJECT_IDS: u32 = 101;
/// BOP `obj_id` of a spec's own objects (in name order, from this one up); the catalog stays below.
pub const USER_OBJECT_IDS: u32 = 1001;

/// The BOP dataset the YCB objects' stand-ins name their originals in.
pub const YCBV: &str = "ycbv";
/// YCB number → `obj_id` of the 21 YCB-Video objects in BOP's `ycbv` (its
/// `models/obj_NNNNNN.ply` and `models_info.json`): fixed by that dataset, not by this catalog.
pub const YCBV_OBJ_IDS: [(&str, u32); 21] = [
    ("002", 1),
    ("003", 2),
    ("004", 3),
    ("005", 4),
    ("006", 5),
    ("007", 6),
    ("008", 7),
    ("009", 8),
    ("010", 9),
    ("011", 10),
    ("019", 11),
    ("021", 12),
    ("024", 13),
    ("025", 14),
    ("035", 15),
    ("036", 16),
    ("037", 17),
    ("040", 18),
    ("051", 19),
    ("052", 20),
    ("061", 21),
];

/// The real object a built-in object approximates: its id in another dataset.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct StandIn {
    pub dataset: &'static str,
    pub obj_id: u32,
    pub ycb_id: String,
}

/// The BOP `obj_id` of built-in object `name`: `CATALOG_OBJECT_IDS` + its catalog position.
pub fn obj_id(name: &str) -> Option<u32> {
    let position = OBJECTS.iter().position(|o| o.name == name)?;
    u32::try_from(position).ok().map(|p| CATALOG_OBJECT_IDS + p)
}

/// The YCB-Video object a built-in object stands in for (none for objects that are not in ycbv).
pub fn stand_in_for(entry: &ObjectEntry) -> Option<StandIn> {
    let (_, obj_id) = YCBV_OBJ_IDS.iter().find(|(ycb, _)| *ycb == entry.ycb_id)?;
    Some(StandIn { dataset: YCBV, obj_id: *obj_id, ycb_id: entry.ycb_id.clone() })
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
    use crate::contract::object::{Axis, Material, Rgb, Symmetry, Texture, rotation_about, rotation_of};

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
    fn every_object_states_its_real_products_colours() {
        for o in objects() {
            let c = o.colours.unwrap_or_else(|| panic!("{}: no colours", o.name));
            let all = [Some(c.base), c.band, c.lower, c.print, c.cap.map(|cap| cap.colour)];
            for Rgb(rgb) in all.into_iter().flatten() {
                assert!(rgb.iter().all(|v| (0.0..=1.0).contains(v)), "{}: {rgb:?}", o.name);
            }
            assert!(
                c.lower.is_none() || matches!(o.texture, Texture::Label { .. }),
                "{}: lower without a label",
                o.name
            );
            assert!(c.cap.is_none_or(|cap| cap.above > 0.0 && cap.above < 1.0), "{}: {:?}", o.name, c.cap);
        }
        // French's classic yellow mustard: a yellow bottle (red and green, no blue) with a red cap.
        let mustard = object("mustard_bottle").and_then(|o| o.colours).expect("mustard's colours");
        let Rgb([r, g, b]) = mustard.base;
        assert!(r > 0.8 && g > 0.4 && b < 0.1, "{:?}", mustard.base);
        let Rgb([r, g, b]) = mustard.cap.expect("a red cap").colour;
        assert!(r > 0.4 && g < 0.1 && b < 0.1);
    }

    #[test]
    fn declared_symmetries_are_rigid_and_kept_by_the_texture_and_colours() {
        for o in objects() {
            for c in &o.symmetries_continuous {
                let norm = c.axis.iter().map(|v| v * v).sum::<f64>().sqrt();
                assert!((norm - 1.0).abs() < 1e-9, "{}: axis {:?}", o.name, c.axis);
                assert!(
                    o.looks_the_same_turned_about(c.axis),
                    "{}: {:?} {:?} breaks turns about {:?}",
                    o.name,
                    o.texture,
                    o.colours,
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
                assert!(o.looks_the_same_after(r), "{}: {:?} {:?} breaks {m:?}", o.name, o.texture, o.colours);
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
    fn built_in_objects_never_take_a_ycbv_or_user_id_and_name_the_ycbv_object_they_stand_in_for() {
        let mut ids = std::collections::BTreeSet::new();
        for o in objects() {
            let id = obj_id(&o.name).expect("a catalog object has an id");
            assert!(!(1..=21).contains(&id), "{}: obj_id {id} is a ycbv id", o.name);
            assert!((CATALOG_OBJECT_IDS..USER_OBJECT_IDS).contains(&id), "{}: obj_id {id}", o.name);
            assert!(ids.insert(id), "{}: obj_id {id} twice", o.name);
            match stand_in_for(o) {
                Some(s) => {
                    assert_eq!((s.dataset, s.ycb_id.as_str()), (YCBV, o.ycb_id.as_str()), "{}", o.name);
                    let table = YCBV_OBJ_IDS.iter().find(|(ycb, _)| *ycb == o.ycb_id).map(|(_, id)| *id);
                    assert_eq!(Some(s.obj_id), table, "{}", o.name);
                }
                None => assert!(o.ycb_id.is_empty(), "{}: YCB {} is not in ycbv", o.name, o.ycb_id),
            }
        }
        assert_eq!(obj_id("master_chef_can"), Some(CATALOG_OBJECT_IDS), "the first object");
        assert_eq!(obj_id("no_such_object"), None);
    }

    #[test]
    fn the_ycbv_table_is_bops_and_covers_every_ycb_object_of_the_catalog() {
        // ycbv numbers its 21 models 1–21 in increasing YCB number.
        for (k, (ycb, id)) in YCBV_OBJ_IDS.iter().enumerate() {
            assert_eq!(usize::try_from(*id).ok(), Some(k + 1), "{ycb}");
            assert!(k == 0 || YCBV_OBJ_IDS[k - 1].0 < *ycb, "{ycb} out of order");
        }
        let id_of = |name: &str| object(name).and_then(stand_in_for).map(|s| s.obj_id);
        // As BOP's ycbv models_info.json has them.
        assert_eq!(id_of("master_chef_can"), Some(1));
        assert_eq!(id_of("tomato_soup_can"), Some(4));
        assert_eq!(id_of("mustard_bottle"), Some(5));
        assert_eq!(id_of("mug"), Some(14));
        assert_eq!(id_of("foam_brick"), Some(21));
        assert_eq!(id_of("wine_glass"), None);
        let stand_ins = objects().iter().filter_map(stand_in_for).count();
        assert_eq!(stand_ins, YCBV_OBJ_IDS.len(), "every ycbv object has its stand-in");
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
