//! A misspelt key or name is reported with the name that was probably meant.

use vint_core::DatasetSpec;

const TINY: &str = include_str!("../../../examples/tiny.toml");

/// The errors of `tiny.toml` with `old` replaced by `new`, as display strings.
fn errors_with(old: &str, new: &str) -> Vec<String> {
    assert!(TINY.contains(old), "tiny.toml lacks {old:?}");
    match DatasetSpec::parse(&TINY.replacen(old, new, 1)) {
        Ok(_) => vec![],
        Err(e) => e.0.iter().map(|e| e.to_string()).collect(),
    }
}

#[test]
fn a_misspelt_key_suggests_the_known_key() {
    let errs = errors_with("hold_s = 0.5", "hold = 0.5");
    assert_eq!(errs.len(), 1, "{errs:#?}");
    assert!(errs[0].starts_with("grasp.hold: unknown key (did you mean `hold_s`? known keys: "), "{}", errs[0]);
    assert!(errs[0].ends_with(", got 0.5"), "{}", errs[0]);
    let top = errors_with("hands = [", "handz = 1\nhands = [");
    assert!(top[0].starts_with("handz: unknown key (did you mean `hands`?"), "{top:?}");
}

#[test]
fn a_misspelt_object_hand_modality_or_environment_suggests_the_known_name() {
    let objects = "objects = [\"tomato_soup_can\", \"mustard_bottle\", \"mug\"]";
    assert_eq!(
        errors_with(objects, "objects = [\"tomato_soup\"]"),
        ["objects[0]: must be an object in the built-in catalog or one an [object.NAME] table defines \
          (did you mean `tomato_soup_can`?), got \"tomato_soup\""]
    );
    let hands = errors_with("hands = [\"trx3\", \"allegro\"]", "hands = [\"alegro\"]");
    assert!(hands[0].contains("(did you mean `allegro`?)"), "{hands:?}");
    let modalities = errors_with("\"depth_noisy\",", "\"depth_noisey\",");
    assert!(modalities[0].contains("(did you mean `depth_noisy`?)"), "{modalities:?}");
    let environments = errors_with("name = \"forest\"", "name = \"forrest\"");
    assert!(environments[0].contains("(did you mean `forest`?)"), "{environments:?}");
}

#[test]
fn nothing_is_suggested_for_a_name_unlike_any_known_one() {
    let errs = errors_with("hold_s = 0.5", "colour = \"red\"");
    assert!(errs[0].starts_with("grasp.colour: unknown key (known keys: "), "{errs:?}");
}
