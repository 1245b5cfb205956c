//! The dataset-level files BOP keeps beside its splits, from what each image's records say:
//! `camera.json` (the sensor, for simulating it: `inout.load_cam_params`) and the test targets of
//! the BOP Challenge, `test_targets_bop19.json` (6D localization: per image, the objects at least
//! 10 % visible and their instance counts, as `scripts/enumerate_test_targets.py` enumerates them)
//! and `test_targets_bop24.json` (6D detection: every test image).

use serde_json::{Value, json};

use super::{DEPTH_SCALE_MM, UNIT_DECIMALS, round};

/// BOP 19's visibility threshold for a localization target (`min_visib_fract`).
pub const MIN_VISIB_FRACT: f64 = 0.1;

/// What the dataset-level files need of one image.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageFacts {
    pub scene_id: u64,
    pub im_id: u64,
    pub obj_id: u64,
    /// `scene_gt_info`'s `visib_fract` (`None` without masks: the visibility is unknown).
    pub visib_fract: Option<f64>,
    /// fx, fy, cx, cy in pixels.
    pub intrinsics: [f64; 4],
    pub size: (usize, usize),
}

/// `camera.json`: the images' camera when they share one; when the views' intrinsics vary
/// (`render.intrinsics_jitter`), each parameter's median over the images, the sensor they scatter
/// around (the images' own cameras are in `scene_camera.json`). `None` with no image.
pub fn camera(images: &[ImageFacts]) -> Option<(Value, bool)> {
    let first = images.first()?;
    let shared = images.iter().all(|i| i.intrinsics == first.intrinsics && i.size == first.size);
    let median = |k: usize| {
        let mut v: Vec<f64> = images.iter().map(|i| i.intrinsics[k]).collect();
        v.sort_by(f64::total_cmp);
        let n = v.len();
        if n % 2 == 1 { v[n / 2] } else { (v[n / 2 - 1] + v[n / 2]) / 2.0 }
    };
    let [fx, fy, cx, cy] = [0, 1, 2, 3].map(median);
    let camera = json!({
        "cx": round(cx, UNIT_DECIMALS),
        "cy": round(cy, UNIT_DECIMALS),
        "depth_scale": DEPTH_SCALE_MM,
        "fx": round(fx, UNIT_DECIMALS),
        "fy": round(fy, UNIT_DECIMALS),
        "height": first.size.1,
        "width": first.size.0,
    });
    Some((camera, shared))
}

/// `test_targets_bop19.json` over the test split's images: one target per (image, object) whose
/// instances at least `MIN_VISIB_FRACT` visible number `inst_count`; `None` when an image has no
/// visibility (no masks were made), as then no target can be chosen by BOP's rule.
pub fn bop19(test_images: &[ImageFacts]) -> Option<Value> {
    let mut targets: Vec<(u64, u64, u64, u64)> = Vec::new();
    for image in test_images {
        if image.visib_fract? < MIN_VISIB_FRACT {
            continue;
        }
        match targets.iter_mut().find(|t| (t.0, t.1, t.2) == (image.scene_id, image.im_id, image.obj_id)) {
            Some(t) => t.3 += 1,
            None => targets.push((image.scene_id, image.im_id, image.obj_id, 1)),
        }
    }
    targets.sort();
    Some(Value::Array(
        targets
            .into_iter()
            .map(|(scene_id, im_id, obj_id, inst_count)| {
                json!({"im_id": im_id, "inst_count": inst_count, "obj_id": obj_id, "scene_id": scene_id})
            })
            .collect(),
    ))
}

/// `test_targets_bop24.json`: every test image, once (detection is scored on all of them).
pub fn bop24(test_images: &[ImageFacts]) -> Value {
    let mut ims: Vec<(u64, u64)> = test_images.iter().map(|i| (i.scene_id, i.im_id)).collect();
    ims.sort();
    ims.dedup();
    Value::Array(ims.into_iter().map(|(scene_id, im_id)| json!({"im_id": im_id, "scene_id": scene_id})).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(scene_id: u64, im_id: u64, visib_fract: Option<f64>, fx: f64) -> ImageFacts {
        ImageFacts { scene_id, im_id, obj_id: 5, visib_fract, intrinsics: [fx, fx, 320.0, 240.0], size: (640, 480) }
    }

    #[test]
    fn localization_targets_keep_images_at_least_a_tenth_visible() {
        let images = [image(2, 1, Some(0.1), 600.0), image(0, 3, Some(0.09), 600.0), image(0, 0, Some(1.0), 600.0)];
        assert_eq!(
            bop19(&images),
            Some(json!([
                {"im_id": 0, "inst_count": 1, "obj_id": 5, "scene_id": 0},
                {"im_id": 1, "inst_count": 1, "obj_id": 5, "scene_id": 2},
            ]))
        );
        assert_eq!(bop19(&[image(0, 0, None, 600.0)]), None, "no masks, no localization targets");
        assert_eq!(
            bop24(&images),
            json!([{"im_id": 0, "scene_id": 0}, {"im_id": 3, "scene_id": 0}, {"im_id": 1, "scene_id": 2}])
        );
    }

    #[test]
    fn the_camera_is_the_shared_one_or_the_median_of_varying_ones() {
        let (cam, shared) = camera(&[image(0, 0, None, 600.0), image(0, 1, None, 600.0)]).unwrap();
        assert!(shared);
        assert_eq!(cam["fx"], json!(600.0));
        assert_eq!((cam["width"].clone(), cam["height"].clone()), (json!(640), json!(480)));
        let (cam, shared) =
            camera(&[image(0, 0, None, 590.0), image(0, 1, None, 640.0), image(0, 2, None, 600.0)]).unwrap();
        assert!(!shared);
        assert_eq!(cam["fy"], json!(600.0));
        assert_eq!(camera(&[]), None);
    }
}
