//! Every spec rule, as a user meets it: one bad value in, one precise message out.

use vint_core::DatasetSpec;
use vint_core::contract::render::PalmSide;

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
fn grasp_type_defaults_to_the_papers_power_grasp_and_names_its_choices() {
    use vint_core::contract::grasp::GraspType;
    assert!(!TINY.lines().any(|line| line.starts_with("type = ")), "tiny.toml takes the spec's default grasp");
    assert_eq!(DatasetSpec::parse(TINY).unwrap().grasp.r#type, GraspType::Power, "VinT-6D App. A.1.3");
    let spec = DatasetSpec::parse(&tiny_with("max_drop_m = 0.02", "max_drop_m = 0.02\ntype = \"precision\"")).unwrap();
    assert_eq!(spec.grasp.r#type, GraspType::Precision);
    assert_single_error(
        &tiny_with("max_drop_m = 0.02", "max_drop_m = 0.02\ntype = \"pinch\""),
        "grasp.type: must be one of power, precision, any, got \"pinch\"",
    );
    assert_single_error(
        &tiny_with("max_drop_m = 0.02", "max_drop_m = 0.02\ntype = 1"),
        "grasp.type: must be one of power, precision, any, got 1",
    );
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
        .replace("sigma_scale = 1.0", "sigma_scale = nan")
        .replace("seed = 7", "seed = \"seven\"");
    let errs = errors(&text);
    assert_eq!(errs.len(), 5, "{errs:#?}");
    assert!(errs.contains(&"dataset.seed: must be an integer, got \"seven\"".to_string()));
    assert!(errs.contains(&"render.samples: must be 1..=65536, got -3".to_string()));
    assert!(errs.contains(&"noise.sigma_scale: must be a finite number, got nan".to_string()));
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
        &tiny_with("views_per_environment = 3", "views_per_environment = 100000"),
        "render.views_per_environment: must be 1..=100, got 100000",
    );
    assert_single_error(
        &tiny_with("views_per_environment = 3", "views_per_environment = 60"),
        "render.views_per_environment: times 2 environments must be at most 100 views per grasp, got 60",
    );
    assert_single_error(
        &tiny_with("trials_per_pair = 2", "trials_per_pair = 0"),
        "grasp.trials_per_pair: must be 1..=1000000, got 0",
    );
    assert_single_error(
        &tiny_with("chunk_size = 2", "chunk_size = 5000"),
        "grasp.chunk_size: must be 1..=1024, got 5000",
    );
    assert_single_error(
        &tiny_with("sigma_scale = 1.0", "sigma_scale = 11"),
        "noise.sigma_scale: must be in [0, 10], got 11.0",
    );
    assert_single_error(
        &tiny_with("sigma_scale = 1.0", "sigma_scale = 1.0\nflying_invalid_share = -0.1"),
        "noise.flying_invalid_share: must be in [0, 1], got -0.1",
    );
    assert_single_error(
        &tiny_with("fov_deg = 50.0", "fov_deg = 180.0"),
        "render.fov_deg: must be in [5, 150], got 180.0",
    );
    // Both validated before the bounds came from the stage contracts, and then failed every task.
    assert_single_error(
        &tiny_with("fov_deg = 50.0", "fov_deg = 160"),
        "render.fov_deg: must be in [5, 150], got 160.0",
    );
    assert_single_error(&tiny_with("hold_s = 0.5", "hold_s = 45"), "grasp.hold_s: must be in [0, 30], got 45.0");
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
}

#[test]
fn lens_distortion_is_bounded_per_coefficient_and_must_stay_invertible_over_the_image() {
    assert_eq!(DatasetSpec::parse(TINY).unwrap().render.distortion, [0.0; 5], "a pinhole unless asked");
    let with = |value: &str| tiny_with("fov_deg = 50.0", &format!("fov_deg = 50.0\ndistortion = {value}"));
    // A colour camera's mild lens, in OpenCV's order.
    let kinect = DatasetSpec::parse(&with("[0.08, -0.06, 0.0007, -0.0003, 0.02]")).unwrap();
    assert_eq!(kinect.render.distortion, [0.08, -0.06, 0.0007, -0.0003, 0.02]);
    assert_single_error(&with("[0, 0, 0.2, 0, 0]"), "render.distortion[2]: must be in [-0.1, 0.1], got 0.2");
    assert_single_error(&with("[1.5, 0, 0, 0, 0]"), "render.distortion[0]: must be in [-1, 1], got 1.5");
    assert_single_error(&with("[0, 0, 0, 0, nan]"), "render.distortion[4]: must be a finite number, got nan");
    assert_single_error(
        &with("[0, 0, 0, 0]"),
        "render.distortion: must be an array of five numbers [k1, k2, p1, p2, k3] (OpenCV's order), got [0, 0, 0, 0]",
    );
    // tiny's corners lie at radius 0.654 (128×128 at 50°); k1 = -0.6 folds the map back at 0.49.
    let errs = errors(&with("[-0.6, 0, 0, 0, 0]"));
    assert_eq!(errs.len(), 1, "{errs:#?}");
    assert!(
        errs[0].starts_with("render.distortion: must stay invertible out to the image's corners: with resolution 128×128 and fov_deg 50 they lie at radius 0.654"),
        "{errs:#?}"
    );
    assert!(errs[0].contains("at radius 0.489") && errs[0].ends_with("got [-0.6, 0.0, 0.0, 0.0, 0.0]"), "{errs:#?}");
    // The same lens over a narrower view is fine: the fold lies outside the image.
    let narrow = tiny_with("fov_deg = 50.0", "fov_deg = 30.0\ndistortion = [-0.6, 0, 0, 0, 0]");
    assert_eq!(DatasetSpec::parse(&narrow).unwrap().render.distortion[0], -0.6);
}

#[test]
fn noise_modes_are_named_and_the_old_gaussian_fields_are_refused_with_a_pointer() {
    assert_single_error(
        &tiny_with("mode = \"wfov_2x2binned\"", "mode = \"kinect\""),
        "noise.mode: must be one of nfov_unbinned, nfov_2x2binned, wfov_2x2binned, wfov_unbinned, got \"kinect\"",
    );
    assert_single_error(&tiny_with("lateral = true", "lateral = 1"), "noise.lateral: must be true or false, got 1");
    let errs = errors(&tiny_with("sigma_scale = 1.0", "sigma_scale = 1.0\nsigma_base_m = 0.0005"));
    assert_eq!(errs.len(), 1, "{errs:#?}");
    assert!(
        errs[0].starts_with("noise.sigma_base_m: was removed: the noise model is an Azure Kinect mode"),
        "{errs:#?}"
    );
}

#[test]
fn cameras_nearer_than_the_modes_minimum_range_are_refused_when_noisy_depth_is_requested() {
    // tiny.toml: radius 0.35-0.5 m, wfov_2x2binned (0.25 m minimum) is valid; the narrow modes
    // start at 0.5 m.
    let narrow = tiny_with("mode = \"wfov_2x2binned\"", "mode = \"nfov_unbinned\"");
    let errs = errors(&narrow);
    assert_eq!(errs.len(), 1, "{errs:#?}");
    assert!(
        errs[0].starts_with(
            "render.radius_m[0]: must be at least 0.5 m, the minimum range of noise.mode \"nfov_unbinned\""
        ) && errs[0].ends_with("got 0.35"),
        "{errs:#?}"
    );
    // The user may accept the invalid readings, or stand the camera further out.
    DatasetSpec::parse(&narrow.replace("materials = true", "materials = true\nignore_min_range = true"))
        .expect("ignore_min_range accepts a near camera");
    DatasetSpec::parse(&narrow.replace("radius_m = [0.35, 0.5]", "radius_m = [0.5, 0.6]")).expect("0.5 m is in range");
    // Without depth_noisy no noise is made, so the range does not matter.
    DatasetSpec::parse(&narrow.replace("\"depth_noisy\", ", "")).expect("no noisy depth, no range rule");
    // The defaults are consistent: the default mode (nfov_unbinned) and the default radius.
    let defaults = DatasetSpec::parse(
        "hands = [\"trx3\"]\nobjects = [\"mug\"]\n[dataset]\nname = \"d\"\nseed = 1\n[outputs]\nmodalities = [\"depth_noisy\"]\n",
    )
    .expect("the default spec with noisy depth validates");
    assert_eq!(defaults.noise.model.mode.figures().min_range_m, 0.5);
    assert!(defaults.render.radius_m[0] >= 0.5);
}

#[test]
fn depth_is_png_by_default_npy_on_request_and_png_refuses_a_camera_beyond_what_it_holds() {
    use vint_core::contract::depth::DepthFormat;
    let default = DatasetSpec::parse(&TINY.replace("depth_format = \"png\"", "")).unwrap();
    assert_eq!(default.outputs.depth_format, DepthFormat::Png);
    let npy = tiny_with("depth_format = \"png\"", "depth_format = \"npy\"");
    assert_eq!(DatasetSpec::parse(&npy).unwrap().outputs.depth_format, DepthFormat::Npy);
    let errs = errors(&tiny_with("depth_format = \"png\"", "depth_format = \"exr\""));
    assert_eq!(errs.len(), 1, "{errs:#?}");
    assert!(
        errs[0].starts_with("outputs.depth_format: ") && errs[0].contains("png") && errs[0].contains("npy"),
        "{errs:#?}"
    );
    assert!(errs[0].ends_with("got \"exr\""), "{errs:#?}");

    // A camera up to 7 m away: the farthest views' depth would not fit 16 bits of 0.1 mm.
    let far = tiny_with("radius_m = [0.35, 0.5]", "radius_m = [0.5, 7.0]");
    assert_single_error(
        &far,
        "render.radius_m[1]: must be at most 6.5535 m with outputs.depth_format = \"png\" (16-bit steps of 0.1 mm \
         hold no farther depth): move the camera in, or set outputs.depth_format = \"npy\", got 7.0",
    );
    DatasetSpec::parse(&far.replace("depth_format = \"png\"", "depth_format = \"npy\"")).expect("npy holds any depth");
    let no_depth = far.replace("\"depth\", \"depth_noisy\", ", "");
    DatasetSpec::parse(&no_depth).expect("no depth requested, no range rule");
    DatasetSpec::parse(&tiny_with("radius_m = [0.35, 0.5]", "radius_m = [0.5, 6.5535]")).expect("6.5535 m fits");
}

#[test]
fn names_must_be_known_identifiers() {
    assert_single_error(
        &tiny_with("objects = [\"tomato_soup_can\", \"mustard_bottle\", \"mug\"]", "objects = [\"unobtainium\"]"),
        "objects[0]: must be an object in the built-in catalog or one an [object.NAME] table defines, got \"unobtainium\"",
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
        &tiny_with(
            "environments = [\"studio\", { name = \"forest\", rotation_deg = 0.0, strength = 1.2 }]",
            "environments = [\"moon\"]",
        ),
        "render.environments[0]: must be one of Blender's bundled HDRIs (city, courtyard, forest, interior, night, studio, sunrise, sunset) or a { name, file } table (your own HDRI), got \"moon\"",
    );
    assert_single_error(
        &tiny_with(
            "modalities = [\"rgb\", \"depth\", \"depth_noisy\", \"mask\", \"segmentation\", \"pose\"]",
            "modalities = [\"rgb\", \"normals\"]",
        ),
        "outputs.modalities[1]: must be one of rgb, depth, depth_noisy, mask, segmentation, pose, got \"normals\"",
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
    assert_eq!(spec.touch.contact_margin_m, 0.0005, "default");
    assert_eq!(spec.touch.contact_window_s, 0.004, "default");
    let text = tiny_with("contact_margin_m = 0.0005", "contact_margin_m = 0.003")
        .replace("contact_window_s = 0.004", "contact_window_s = -0.001")
        .replace("aging = [1.0, 1.0]", "aging = 1.5")
        .replace("min_active_taxels = 3", "min_active_taxels = -1");
    let errs = errors(&text);
    assert_eq!(
        errs,
        vec![
            "touch.contact_margin_m: must be in [0, 0.002], got 0.003",
            "touch.contact_window_s: must be in [0, 0.064], got -0.001",
            "touch.aging: must be in [0.01, 1], got 1.5",
            "touch.min_active_taxels: must be 0..=10000, got -1",
        ]
    );
    // Aging is a range drawn per grasp; a single number is the range [x, x].
    assert_eq!(spec.touch.aging, [1.0, 1.0], "default: a new sensor");
    assert_eq!(spec.touch.position_sigma_m, 0.0003, "default");
    assert_eq!(DatasetSpec::parse(TINY).unwrap().touch.aging, [1.0, 1.0]);
    let ranged = DatasetSpec::parse(&tiny_with("aging = [1.0, 1.0]", "aging = [0.6, 0.9]").replacen(
        "position_sigma_m = 0.0003",
        "position_sigma_m = 0.0",
        1,
    ))
    .unwrap();
    assert_eq!((ranged.touch.aging, ranged.touch.position_sigma_m), ([0.6, 0.9], 0.0));
    let fixed = DatasetSpec::parse(&tiny_with("aging = [1.0, 1.0]", "aging = 0.7")).unwrap();
    assert_eq!(fixed.touch.aging, [0.7, 0.7]);
    let errs = errors(&tiny_with("aging = [1.0, 1.0]", "aging = [0.9, 0.6]").replacen(
        "position_sigma_m = 0.0003",
        "position_sigma_m = 0.003",
        1,
    ));
    assert_eq!(
        errs,
        vec![
            "touch.aging: must be [low, high] with low <= high, got [0.9, 0.6]",
            "touch.position_sigma_m: must be in [0, 0.002], got 0.003",
        ]
    );
    let errs = errors(&tiny_with("aging = [1.0, 1.0]", "aging = [0.5, 1.2]").replacen(
        "position_sigma_m = 0.0003",
        "position_sigma_m = -0.0001",
        1,
    ));
    assert_eq!(
        errs,
        vec![
            "touch.aging[1]: must be in [0.01, 1], got 1.2",
            "touch.position_sigma_m: must be in [0, 0.002], got -0.0001"
        ]
    );
    let errs = errors(&tiny_with("aging = [1.0, 1.0]", "aging = [0.5]"));
    assert_eq!(errs, vec!["touch.aging: must be an array of two numbers, got [0.5]"]);
    // The footprint around MuJoCo's contact points is gone: each taxel is its own contact element.
    let old = tiny_with("contact_margin_m = 0.0005", "contact_margin_m = 0.0005\nfootprint_radius_m = 0.006");
    let errs = errors(&old);
    assert_eq!(errs.len(), 1, "{errs:#?}");
    assert!(errs[0].starts_with("touch.footprint_radius_m: was removed: every taxel within"), "{errs:#?}");
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

/// A spec with a user hand and a user object, plus `extra` lines at the end.
fn custom(extra: &str) -> String {
    format!(
        "hands = [\"grip\", \"trx3\"]\nobjects = [\"vase\", \"mug\"]\n[dataset]\nname = \"c\"\nseed = 1\n\
         [hand.grip]\nmjcf = \"assets/grip.xml\"\ntaxels = \"assets/grip_taxels.csv\"\n\
         [object.vase]\nmesh = \"assets/vase.obj\"\nunit = \"mm\"\nmass_kg = 0.25\nmaterial = \"ceramic\"\n\
         symmetry = \"continuous_z\"\n{extra}"
    )
}

#[test]
fn user_hands_and_objects_are_defined_by_tables_and_name_their_files() {
    let spec = DatasetSpec::parse(&custom("")).unwrap();
    assert_eq!(spec.hand_defs["grip"].mjcf, "assets/grip.xml");
    assert_eq!(spec.object_defs["vase"].scale(), 0.001);
    let uses: Vec<String> = spec.asset_uses().iter().map(|u| format!("{}={}", u.field, u.path)).collect();
    assert_eq!(
        uses,
        [
            "hand.grip.mjcf=assets/grip.xml",
            "hand.grip.taxels=assets/grip_taxels.csv",
            "object.vase.mesh=assets/vase.obj"
        ]
    );
    // Built-in names alone need no files.
    assert!(DatasetSpec::parse(TINY).unwrap().asset_paths().is_empty());
}

#[test]
fn a_user_objects_sidecar_files_are_listed_paths_of_known_kinds() {
    let spec = DatasetSpec::parse(&custom("").replace(
        "mesh = \"assets/vase.obj\"",
        "mesh = \"assets/vase.glb\"\nfiles = [\"assets/vase.bin\", \"assets/tex/vase.JPG\"]",
    ))
    .unwrap();
    assert_eq!(spec.object_defs["vase"].files, ["assets/vase.bin", "assets/tex/vase.JPG"]);
    let uses: Vec<String> = spec.asset_uses().iter().skip(2).map(|u| format!("{}={}", u.field, u.path)).collect();
    assert_eq!(
        uses,
        [
            "object.vase.mesh=assets/vase.glb",
            "object.vase.files[0]=assets/vase.bin",
            "object.vase.files[1]=assets/tex/vase.JPG"
        ]
    );
    let bad = custom("").replace(
        "mesh = \"assets/vase.obj\"",
        "mesh = \"assets/vase.obj\"\nfiles = [\"assets/vase.mtl\", \"../vase.tga\", \"assets/vase.mtl\"]",
    );
    assert_eq!(
        errors(&bad),
        vec![
            "object.vase.files[1]: must name a .mtl, .png, .jpg, .jpeg, .bin file, got \"../vase.tga\"",
            "object.vase.files[2]: must not repeat a file, got \"assets/vase.mtl\"",
        ]
    );
    assert_single_error(
        &custom("").replace("mesh = \"assets/vase.obj\"", "mesh = \"assets/vase.obj\"\nfiles = \"assets/vase.mtl\""),
        "object.vase.files: must be an array of at most 64 paths relative to the spec file, got \"assets/vase.mtl\"",
    );
}

#[test]
fn a_listed_name_must_be_built_in_or_defined() {
    let text = custom("").replace("hands = [\"grip\", \"trx3\"]", "hands = [\"gripper\"]");
    assert_single_error(
        &text,
        "hands[0]: must be a hand in `vintctl hands` or one a [hand.NAME] table defines (did you mean `grip`?), \
         got \"gripper\"",
    );
}

#[test]
fn a_user_definition_may_not_shadow_a_built_in_name() {
    let text = custom(
        "[hand.trx3]\nmjcf = \"a.xml\"\ntaxels = \"a.csv\"\n[object.mug]\nmesh = \"m.stl\"\nunit = \"m\"\nmass_kg = 0.3\nmaterial = \"ceramic\"\n",
    );
    assert_eq!(
        errors(&text),
        vec![
            "hand.trx3: must not reuse the name of a built-in hand, got \"trx3\"",
            "object.mug: must not reuse the name of a built-in object, got \"mug\"",
        ]
    );
}

#[test]
fn user_definitions_check_paths_units_and_tags() {
    let text = custom("")
        .replace("unit = \"mm\"", "unit = \"inch\"")
        .replace("mjcf = \"assets/grip.xml\"", "mjcf = \"/abs/grip.xml\"")
        .replace("taxels = \"assets/grip_taxels.csv\"", "taxels = \"assets/grip_taxels.txt\"")
        .replace("material = \"ceramic\"", "material = \"cheese\"")
        .replace("mass_kg = 0.25", "mass_kg = 0.25\ncolour = \"red\"");
    assert_eq!(
        errors(&text),
        vec![
            "hand.grip.mjcf: must be a path relative to the spec file, with / separators, got \"/abs/grip.xml\"",
            "hand.grip.taxels: must name a .csv file, got \"assets/grip_taxels.txt\"",
            "object.vase.unit: must be one of m, cm, mm, got \"inch\"",
            "object.vase.material: must be one of plastic, metal, glass, paper, cardboard, wood, ceramic, rubber, got \"cheese\"",
            "object.vase.colour: unknown key (known keys: mesh, files, unit, mass_kg, material, symmetry, obj_id, \
             symmetries_continuous, symmetries_discrete), got \"red\"",
        ]
    );
    let missing = custom("").replace("mesh = \"assets/vase.obj\"\n", "").replace("[hand.grip]", "[hand.Grip]");
    assert_eq!(
        errors(&missing),
        vec![
            "hand.Grip: must be 1 to 64 characters of a-z, 0-9 and _, got \"Grip\"",
            "object.vase.mesh: is required, got nothing",
            "hands[0]: must be a hand in `vintctl hands` or one a [hand.NAME] table defines, got \"grip\"",
        ]
    );
}

#[test]
fn environments_are_names_or_tables_with_rotation_and_strength() {
    let spec = DatasetSpec::parse(TINY).unwrap();
    let envs: Vec<(&str, f64, f64)> =
        spec.render.environments.iter().map(|e| (e.name.as_str(), e.rotation_deg, e.strength)).collect();
    assert_eq!(envs, [("studio", 0.0, 1.0), ("forest", 0.0, 1.2)]);
    assert_eq!(spec.render.views_per_grasp(), 6);

    let start = TINY.find("environments = [").unwrap();
    let end = start + TINY[start..].find('\n').unwrap();
    let tables = format!(
        "{}{}",
        TINY.replacen(&TINY[start..end], "", 1),
        "[[render.environment]]\nname = \"studio\"\nrotation_deg = 30\nstrength = 1.2\n\
         [[render.environment]]\nname = \"night\"\n"
    );
    let spec = DatasetSpec::parse(&tables).unwrap();
    assert_eq!(spec.render.environments[0].rotation_deg, 30.0);
    assert_eq!(spec.render.environments[1].name, "night");

    assert_single_error(
        &tiny_with("rotation_deg = 0.0", "rotation_deg = 900.0"),
        "render.environments[1].rotation_deg: must be in [-360, 360], got 900.0",
    );
    assert_single_error(
        &tiny_with("views_per_environment = 3", "views_per_grasp = 3"),
        "render.views_per_grasp: was renamed: set render.views_per_environment (a grasp gets \
         views_per_environment × environments views), got 3",
    );
}

#[test]
fn a_user_hdri_is_an_environment_table_with_a_file() {
    let text = tiny_with(
        "{ name = \"forest\", rotation_deg = 0.0, strength = 1.2 }",
        "{ name = \"lab\", file = \"assets/lab.hdr\", rotation_deg = 45.0, strength = 1.5 }, \
         { name = \"hall\", file = \"hdri/Hall.EXR\" }",
    );
    let spec = DatasetSpec::parse(&text).unwrap();
    let lab = &spec.render.environments[1];
    assert_eq!((lab.name.as_str(), lab.rotation_deg, lab.strength), ("lab", 45.0, 1.5));
    assert_eq!(spec.render.views_per_grasp(), 9);
    let uses: Vec<String> = spec.asset_uses().iter().map(|u| format!("{}={}", u.field, u.path)).collect();
    assert_eq!(uses, ["render.environments[1].file=assets/lab.hdr", "render.environments[2].file=hdri/Hall.EXR"]);
    // The spec as `vintctl validate --json` shows it: the file as written, bundled ones without one.
    let shown = serde_json::to_value(&spec.render.environments).unwrap();
    assert_eq!(shown[1]["file"], "assets/lab.hdr");
    assert!(shown[0].get("file").is_none());

    // As [[render.environment]] tables the field paths follow.
    let start = TINY.find("environments = [").unwrap();
    let end = start + TINY[start..].find('\n').unwrap();
    let tables = format!(
        "{}[[render.environment]]\nname = \"lab\"\nfile = \"lab.exr\"\n",
        TINY.replacen(&TINY[start..end], "", 1)
    );
    assert_eq!(DatasetSpec::parse(&tables).unwrap().asset_uses()[0].field, "render.environment[0].file");
}

#[test]
fn a_user_hdri_needs_an_hdr_or_exr_file_and_a_name_of_its_own() {
    let with = |entry: &str| tiny_with("{ name = \"forest\", rotation_deg = 0.0, strength = 1.2 }", entry);
    assert_single_error(
        &with("{ name = \"lab\", file = \"assets/lab.png\" }"),
        "render.environments[1].file: must name a .hdr, .exr file, got \"assets/lab.png\"",
    );
    assert_single_error(
        &with("{ name = \"lab\", file = \"/hdri/lab.hdr\" }"),
        "render.environments[1].file: must be a path relative to the spec file, with / separators, got \"/hdri/lab.hdr\"",
    );
    assert_single_error(
        &with("{ name = \"forest\", file = \"forest.hdr\" }"),
        "render.environments[1].name: must not reuse the name of a bundled HDRI, got \"forest\"",
    );
    assert_single_error(
        &with("{ name = \"lab\", file = \"a.hdr\" }, { name = \"lab\", file = \"b.hdr\", strength = 2.0 }"),
        "render.environments[2].name: must not repeat an earlier environment, got \"lab\"",
    );
    assert_single_error(&with("{ file = \"a.hdr\" }"), "render.environments[1].name: is required, got nothing");
    assert_single_error(
        &with("{ name = \"Lab Room\", file = \"a.hdr\" }"),
        "render.environments[1].name: must be 1 to 64 characters of a-z, 0-9 and _, got \"Lab Room\"",
    );
    assert_single_error(
        &with("\"lab\""),
        &format!("render.environments[1]: must be {}, got \"lab\"", ENVIRONMENT_RULE),
    );
    // One file may light two environments (e.g. turned two ways); it travels once.
    let twice = DatasetSpec::parse(&with(
        "{ name = \"lab\", file = \"a.hdr\" }, { name = \"lab_turned\", file = \"a.hdr\", rotation_deg = 180 }",
    ))
    .unwrap();
    assert_eq!((twice.asset_uses().len(), twice.asset_paths().len()), (2, 1));
}

const ENVIRONMENT_RULE: &str = "one of Blender's bundled HDRIs (city, courtyard, forest, interior, night, studio, \
                                sunrise, sunset) or a { name, file } table (your own HDRI)";

#[test]
fn cycles_settings_have_defaults_and_ranges() {
    let spec = DatasetSpec::parse(TINY).unwrap();
    assert!(spec.render.denoise, "the denoiser is what reaches 35 dB on the foreground");
    assert_eq!(spec.render.despeckle, 0.3, "the firefly filter stays on behind it");
    assert_eq!(spec.render.clamp_indirect, 10.0);
    assert_eq!(spec.render.roll_deg, [-5.0, 5.0], "a robot's camera is mounted upright");
    assert_eq!((spec.render.scene.table, spec.render.scene.flange), (true, true));
    assert_eq!((spec.render.bounces.total, spec.render.bounces.transmission), (12, 12));
    let text = tiny_with(
        "samples = 16",
        "samples = 16\ndenoise = false\nbounces = { glossy = 2, transparent = 0 }\nscene = { table = false }",
    );
    let spec = DatasetSpec::parse(&text).unwrap();
    assert!(!spec.render.denoise);
    assert!(!spec.render.scene.table && spec.render.scene.flange);
    assert_eq!((spec.render.bounces.glossy, spec.render.bounces.transparent), (2, 0));
    assert_single_error(
        &tiny_with("samples = 16", "samples = 16\nbounces = { diffuse = 5000 }"),
        "render.bounces.diffuse: must be 0..=1024, got 5000",
    );
    assert_single_error(
        &tiny_with("samples = 16", "samples = 16\ndenoise = 1"),
        "render.denoise: must be true or false, got 1",
    );
    assert_single_error(
        &tiny_with("samples = 16", "samples = 16\noffcentre = 0.95"),
        "render.offcentre: must be in [0, 0.9], got 0.95",
    );
    assert_single_error(
        &tiny_with("samples = 16", "samples = 16\nscene = { table_gap_m = -0.1 }"),
        "render.scene.table_gap_m: must be in [0, 1], got -0.1",
    );
    assert_single_error(
        &tiny_with("samples = 16", "samples = 16\nlight = { temperature_k = [1000.0, 6504.0] }"),
        "render.light.temperature_k[0]: must be in [1667, 25000], got 1000.0",
    );
    assert_single_error(
        &tiny_with("samples = 16", "samples = 16\nscene = { tabel = true }"),
        "render.scene.tabel: unknown key (did you mean `table`? known keys: table, table_gap_m, flange, distractors), got true",
    );
    assert_eq!(DatasetSpec::parse(TINY).unwrap().render.scene.distractors, 0, "scenery is asked for");
    let text = tiny_with("samples = 16", "samples = 16\nscene = { distractors = 3 }");
    assert_eq!(DatasetSpec::parse(&text).unwrap().render.scene.distractors, 3);
    assert_single_error(
        &tiny_with("samples = 16", "samples = 16\nscene = { distractors = 9 }"),
        "render.scene.distractors: must be 0..=8, got 9",
    );
    assert_single_error(
        &tiny_with("samples = 16", "samples = 16\nscene = { table = false, distractors = 2 }"),
        "render.scene.distractors: needs the table to stand on (render.scene.table = true), got 2",
    );
}

#[test]
fn split_fractions_must_sum_to_one_and_held_out_names_must_be_the_specs() {
    assert_single_error(
        &format!("{TINY}\n[split]\ntrain = 0.7\nval = 0.2\ntest = 0.2\n"),
        "split: split.train + split.val + split.test must sum to 1, got 1.0999999999999999",
    );
    assert_single_error(
        &format!("{TINY}\n[split]\nheld_out_objects = [\"banana\"]\n"),
        "split.held_out_objects[0]: must be one of the spec's objects, got \"banana\"",
    );
    let spec = DatasetSpec::parse(&format!(
        "{TINY}\n[split]\ntrain = 0.6\nval = 0.2\ntest = 0.2\nheld_out_hands = [\"trx3\"]\n"
    ))
    .expect("a valid split");
    assert_eq!((spec.split.train, spec.split.held_out_hands.as_slice()), (0.6, ["trx3".to_string()].as_slice()));
}

/// The paper's recipe (issue 11 plans and costs it): 26 objects × 2 hands × 2,500 accepted grasps
/// × 4 environments × 3 views.
#[test]
fn the_vint_sim_recipe_is_valid_and_asks_for_one_and_a_half_million_samples() {
    let spec = DatasetSpec::parse(include_str!("../../../examples/vint-sim.toml")).expect("vint-sim.toml is valid");
    assert_eq!((spec.objects.len(), spec.hands.len()), (26, 2));
    assert_eq!(spec.objects.len(), vint_core::catalog::objects().len(), "every built-in object");
    assert_eq!(spec.grasp.accepted_per_pair, Some(2500));
    assert_eq!(spec.max_samples(), 26 * 2 * 2500 * 4 * 3);
}

#[test]
fn a_bop_model_keeps_its_obj_id_and_explicit_symmetries() {
    let bop = "[object.vase]\nmesh = \"assets/vase.obj\"\nunit = \"mm\"\nmass_kg = 0.25\nmaterial = \"ceramic\"\n";
    let text =
        |extra: &str| custom("").replace(&format!("{bop}symmetry = \"continuous_z\"\n"), &format!("{bop}{extra}"));
    let spec = DatasetSpec::parse(&text(
        "obj_id = 5\nsymmetries_continuous = [{ axis = [0, 0, 1], offset = [0, 0, 0.01] }]\n\
         symmetries_discrete = [[-1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1, 0.002, 0, 0, 0, 1]]\n",
    ))
    .unwrap();
    let vase = &spec.object_defs["vase"];
    assert_eq!(vase.obj_id, Some(5));
    let (continuous, discrete) = vase.symmetry_sets();
    assert_eq!((continuous[0].axis, continuous[0].offset), ([0.0, 0.0, 1.0], [0.0, 0.0, 0.01]));
    assert_eq!(discrete[0][11], 0.002);
    // Without explicit sets, the shorthand says them.
    assert_eq!(DatasetSpec::parse(&custom("")).unwrap().object_defs["vase"].symmetry_sets().0.len(), 1);

    assert_eq!(
        errors(&text(
            "obj_id = 101\nsymmetry = \"none\"\nsymmetries_discrete = [[1, 0, 0, 0, 0, 2, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]]\n\
             symmetries_continuous = [{ axis = [0, 0.5, 0] }]\n"
        )),
        vec![
            "object.vase.symmetry: must not be given with symmetries_continuous/_discrete, got \"none\"",
            "object.vase.obj_id: must be 1..=100, got 101",
            "object.vase.symmetries_continuous[0].axis: must be a unit vector (its length is shown), got 0.5",
            "object.vase.symmetries_discrete[0]: must be a rigid transform: a rotation (orthonormal, det +1) and a \
             translation in metres, row-major, the last row 0 0 0 1, got \"[1.0, 0.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, \
             0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]\"",
        ]
    );
    let twice = text("obj_id = 5\n").replace("objects = [\"vase\", \"mug\"]", "objects = [\"vase\", \"cup\"]")
        + "[object.cup]\nmesh = \"assets/cup.obj\"\nunit = \"mm\"\nmass_kg = 0.2\nmaterial = \"ceramic\"\nobj_id = 5\n";
    assert_single_error(
        &twice,
        "object.vase.obj_id: must differ from object.cup.obj_id (each obj_id names one model), got 5",
    );
}

#[test]
fn occlusion_range_defaults_to_the_papers_and_is_ordered_within_zero_and_one() {
    let spec = DatasetSpec::parse(TINY).unwrap();
    assert_eq!(spec.render.occlusion, [0.1, 0.9], "VinT-6D §3.3.7: occlusion by the fingers 10-90 %");
    assert_eq!(spec.render.palm_side, PalmSide::Any);
    let spec =
        DatasetSpec::parse(&tiny_with("samples = 16", "samples = 16\nocclusion = [0.0, 0.5]\npalm_side = \"front\""))
            .unwrap();
    assert_eq!((spec.render.occlusion, spec.render.palm_side), ([0.0, 0.5], PalmSide::Front));
    assert_single_error(
        &tiny_with("samples = 16", "samples = 16\nocclusion = [0.9, 0.1]"),
        "render.occlusion: must be [low, high] with low <= high, got [0.9, 0.1]",
    );
    assert_single_error(
        &tiny_with("samples = 16", "samples = 16\nocclusion = [0.1, 1.5]"),
        "render.occlusion[1]: must be in [0, 1], got 1.5",
    );
    assert_single_error(
        &tiny_with("samples = 16", "samples = 16\nocclusion = [-0.1, 0.9]"),
        "render.occlusion[0]: must be in [0, 1], got -0.1",
    );
    assert_single_error(
        &tiny_with("samples = 16", "samples = 16\nocclusion = 0.5"),
        "render.occlusion: must be an array of two numbers, got 0.5",
    );
    assert_single_error(
        &tiny_with("samples = 16", "samples = 16\npalm_side = \"back\""),
        "render.palm_side: must be one of any, front, got \"back\"",
    );
}
