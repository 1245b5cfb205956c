//! Every spec rule, as a user meets it: one bad value in, one precise message out.

use vint_core::DatasetSpec;

const TINY: &str = include_str!("../../../examples/tiny.toml");

/// Errors of `text` as display strings.
fn errors(text: &str) -> Vec<String> {
    match DatasetSpec::parse(text) {
        Ok(_) => vec![],
        Err(e) => e.0.iter().map(|e| e.to_string()).collect(),
    }
}

/// `tiny.toml` with one line replaced.
fn tiny_with(old: &str, new: &str) -> String {
    assert!(TINY.contains(old), "tiny.toml lacks {old:?}");
    TINY.replacen(old, new, 1)
}

fn assert_single_error(text: &str, expected: &str) {
    let errs = errors(text);
    assert_eq!(errs, vec![expected.to_string()], "spec:\n{text}");
}

#[test]
fn tiny_example_is_valid() {
    let spec = DatasetSpec::parse(TINY).unwrap();
    assert_eq!(spec.dataset.name, "tiny");
    assert_eq!(spec.render.resolution, [128, 128]);
}

#[test]
fn resolution_out_of_range_names_field_value_and_rule() {
    assert_single_error(
        &tiny_with("resolution = [128, 128]", "resolution = [0, 128]"),
        "render.resolution[0]: must be 16..=8192, got 0",
    );
    assert_single_error(
        &tiny_with("resolution = [128, 128]", "resolution = [128, 100000]"),
        "render.resolution[1]: must be 16..=8192, got 100000",
    );
}

#[test]
fn every_problem_is_reported_at_once() {
    let text = tiny_with("resolution = [128, 128]", "resolution = [0, 0]")
        .replace("samples = 16", "samples = -3")
        .replace("dropout = 0.01", "dropout = nan")
        .replace("seed = 7", "seed = \"seven\"");
    let errs = errors(&text);
    assert_eq!(errs.len(), 5, "{errs:#?}");
    assert!(errs.contains(&"dataset.seed: must be an integer, got \"seven\"".to_string()));
    assert!(errs.contains(&"render.samples: must be 1..=65536, got -3".to_string()));
    assert!(errs.contains(&"noise.dropout: must be a finite number, got nan".to_string()));
}

#[test]
fn unknown_keys_are_errors_at_every_level() {
    let text = tiny_with("samples = 16", "samples = 16\nsampels = 16").replace("hands = [", "handz = 1\nhands = [");
    let errs = errors(&text);
    assert_eq!(errs.len(), 2, "{errs:#?}");
    assert!(errs.iter().any(|e| e.starts_with("render.sampels: unknown key")));
    assert!(errs.iter().any(|e| e.starts_with("handz: unknown key")));
}

#[test]
fn wrong_types_are_errors() {
    assert_single_error(&tiny_with("samples = 16", "samples = 16.5"), "render.samples: must be an integer, got 16.5");
    assert_single_error(
        &tiny_with("fov_deg = 50.0", "fov_deg = \"wide\""),
        "render.fov_deg: must be a number, got \"wide\"",
    );
    assert_single_error(
        &tiny_with("resolution = [128, 128]", "resolution = 128"),
        "render.resolution: must be an array of two numbers, got 128",
    );
    assert_single_error(
        &tiny_with("hands = [\"trx3\", \"allegro\"]", "hands = \"trx3\""),
        "hands: must be an array of strings, got \"trx3\"",
    );
    assert_single_error(
        "grasp = 3\nobjects = [\"tomato_soup_can\", \"mustard_bottle\", \"mug\"]\n[dataset]\nname = \"t\"\nseed = 1\n",
        "grasp: must be a table, got 3",
    );
}

#[test]
fn nan_and_infinity_are_rejected() {
    assert_single_error(
        &tiny_with("timestep_s = 0.002", "timestep_s = nan"),
        "grasp.timestep_s: must be a finite number, got nan",
    );
    assert_single_error(&tiny_with("hold_s = 0.5", "hold_s = inf"), "grasp.hold_s: must be a finite number, got inf");
}

#[test]
fn negative_and_absurd_values_are_rejected() {
    assert_single_error(&tiny_with("seed = 7", "seed = -1"), "dataset.seed: must be 0..=9223372036854775807, got -1");
    assert_single_error(
        &tiny_with("timestep_s = 0.002", "timestep_s = -0.002"),
        "grasp.timestep_s: must be in [0.0001, 0.01], got -0.002",
    );
    assert_single_error(
        &tiny_with("timestep_s = 0.002", "timestep_s = 5.0"),
        "grasp.timestep_s: must be in [0.0001, 0.01], got 5.0",
    );
    assert_single_error(
        &tiny_with("views_per_grasp = 2", "views_per_grasp = 100000"),
        "render.views_per_grasp: must be 1..=256, got 100000",
    );
    assert_single_error(
        &tiny_with("trials_per_pair = 2", "trials_per_pair = 0"),
        "grasp.trials_per_pair: must be 1..=1000000, got 0",
    );
    assert_single_error(
        &tiny_with("chunk_size = 2", "chunk_size = 5000"),
        "grasp.chunk_size: must be 1..=1024, got 5000",
    );
    assert_single_error(&tiny_with("dropout = 0.01", "dropout = 1.5"), "noise.dropout: must be in [0, 1], got 1.5");
    assert_single_error(
        &tiny_with("sigma_base_m = 0.0005", "sigma_base_m = -0.1"),
        "noise.sigma_base_m: must be in [0, 0.1], got -0.1",
    );
    assert_single_error(
        &tiny_with("fov_deg = 50.0", "fov_deg = 180.0"),
        "render.fov_deg: must be in [5, 170], got 180.0",
    );
    assert_single_error(
        &tiny_with("lift_height_m = 0.10", "lift_height_m = 1e9"),
        "grasp.lift_height_m: must be in [0, 1], got 1000000000.0",
    );
    assert_single_error(
        &tiny_with("max_drop_m = 0.02", "max_drop_m = 0.0"),
        "grasp.max_drop_m: must be in [0.001, 0.5], got 0.0",
    );
}

#[test]
fn ranges_must_be_ordered_and_bounded() {
    assert_single_error(
        &tiny_with("radius_m = [0.35, 0.5]", "radius_m = [0.5, 0.35]"),
        "render.radius_m: must be [low, high] with low <= high, got [0.5, 0.35]",
    );
    assert_single_error(
        &tiny_with("elevation_deg = [15.0, 75.0]", "elevation_deg = [15.0, 95.0]"),
        "render.elevation_deg[1]: must be in [-90, 90], got 95.0",
    );
    assert_single_error(
        &tiny_with("min_range_m = 0.25", "min_range_m = 4.0"),
        "noise.max_range_m: must be greater than noise.min_range_m (4), got 3.86",
    );
}

#[test]
fn names_must_be_known_identifiers() {
    assert_single_error(
        &tiny_with("objects = [\"tomato_soup_can\", \"mustard_bottle\", \"mug\"]", "objects = [\"unobtainium\"]"),
        "objects[0]: must be an object in the built-in catalog, got \"unobtainium\"",
    );
    assert_single_error(
        &tiny_with("hands = [\"trx3\", \"allegro\"]", "hands = [\"trx3\", \"trx3\"]"),
        "hands[1]: must not repeat an earlier entry, got \"trx3\"",
    );
    assert_single_error(
        &tiny_with("objects = [\"tomato_soup_can\", \"mustard_bottle\", \"mug\"]", "objects = []"),
        "objects: must name at least one, got []",
    );
    assert_single_error(
        &tiny_with("name = \"tiny\"", "name = \"Tiny Set\""),
        "dataset.name: must be 1 to 64 characters of a-z, 0-9 and _, got \"Tiny Set\"",
    );
    assert_single_error(
        &tiny_with("environments = [\"studio\", \"forest\"]", "environments = [\"moon\"]"),
        "render.environments[0]: must be one of Blender's bundled HDRIs (city, courtyard, forest, interior, night, studio, sunrise, sunset), got \"moon\"",
    );
    assert_single_error(
        &tiny_with(
            "modalities = [\"rgb\", \"depth\", \"depth_noisy\", \"mask\", \"pose\"]",
            "modalities = [\"rgb\", \"normals\"]",
        ),
        "outputs.modalities[1]: must be one of rgb, depth, depth_noisy, mask, pose, got \"normals\"",
    );
}

#[test]
fn required_fields_must_be_present() {
    let errs = errors("hands = [\"trx3\"]\n");
    assert_eq!(
        errs,
        vec![
            "dataset.name: is required, got nothing",
            "dataset.seed: is required, got nothing",
            "objects: is required, got nothing"
        ]
    );
}

#[test]
fn malformed_toml_is_one_clear_error() {
    let errs = errors("[dataset\nname = 1");
    assert_eq!(errs.len(), 1);
    assert!(errs[0].starts_with("not valid TOML"), "{}", errs[0]);
}

#[test]
fn oversized_specs_are_refused() {
    let big = format!("{TINY}\n# {}", "x".repeat(2 << 20));
    let errs = errors(&big);
    assert_eq!(errs.len(), 1);
    assert!(errs[0].contains("larger than"));
}

#[test]
fn touch_settings_have_defaults_and_ranges() {
    let spec = DatasetSpec::parse("objects = [\"mug\"]\n[dataset]\nname = \"t\"\nseed = 1\n").unwrap();
    assert_eq!(spec.touch.sensing_depth_m, 0.003, "default");
    let text = tiny_with("sensing_depth_m = 0.003", "sensing_depth_m = 0.0")
        .replace("aging = 1.0", "aging = 1.5")
        .replace("min_active_taxels = 3", "min_active_taxels = -1");
    let errs = errors(&text);
    assert_eq!(
        errs,
        vec![
            "touch.sensing_depth_m: must be in [0.0001, 0.02], got 0.0",
            "touch.aging: must be in [0.01, 1], got 1.5",
            "touch.min_active_taxels: must be 0..=10000, got -1",
        ]
    );
}

#[test]
fn grasp_procedure_settings_are_checked() {
    let text =
        TINY.replace("max_drop_m = 0.02", "max_drop_m = 0.02\nstandoff_ratio = [0.2, -0.5]\nshake_accel_mps2 = -1.0");
    let errs = errors(&text);
    assert_eq!(
        errs,
        vec![
            "grasp.standoff_ratio[1]: must be in [-0.2, 1], got -0.5",
            "grasp.shake_accel_mps2: must be in [0, 100], got -1.0"
        ]
    );
}
