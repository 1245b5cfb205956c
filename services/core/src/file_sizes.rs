//! How big each file a stage writes is, as measured on real runs: the one place the cost model
//! (`vintctl validate` / `vintctl plan`) and the timing-only worker (`vint-worker --engine-mode
//! timing-only`, which writes files of these sizes instead of running engines) read them from.
//!
//! Images scale with their pixels; JSON documents with what they describe. Each figure names its
//! source so that it can be re-derived when `docs/benchmarks.md` is re-measured.

use crate::contract::render::ViewFile;

/// Bytes per pixel of each image file. docs/benchmarks.md, "Output size per sample": medians of
/// tiny.toml's 72 samples (128×128, 16 spp). An RGB PNG shrinks as samples per pixel rise (less
/// noise to compress); depth is float32 `.npy`.
pub const RGB_BYTES_PER_PIXEL: f64 = 1.8; // rgb.png, median 29 916 B
pub const DEPTH_BYTES_PER_PIXEL: f64 = 4.0; // depth.npy and depth_noisy.npy, 65 664 B each
pub const MASKS_BYTES_PER_PIXEL: f64 = 0.05; // mask.png + mask_full.png, 383 + 398 B
pub const SEGMENTATION_BYTES_PER_PIXEL: f64 = 0.045; // segmentation.png, 707 B
/// A `.npy` file's header before its float32 data.
pub const NPY_HEADER_BYTES: u64 = 128;
pub const META_JSON_BYTES: f64 = 4_417.0; // meta.json, median (4.1–4.7 KB): the view alone
pub const GRASP_RECORD_BYTES: f64 = 37_053.0; // <grasp_id>/grasp.json, median (26–50 KB), once per grasp

/// The grasp and render stages' JSON and model files, from the artifacts of a real `vintctl run
/// examples/tiny.toml` job (2026-11-25, commit `687edb3`; `scripts/measure_db_bytes.py` prints
/// them): `grasps.json` and `touch.json` per trial the chunk ran (medians over its 6 chunks of 2
/// trials; rejected trials write less), `object.ply` per object (content-addressed: one object
/// for every chunk and hand; median of tiny's 3 objects, 5–18 KB), a view's `camera.json`
/// (median of 60).
pub const GRASPS_JSON_BYTES_PER_TRIAL: f64 = 8_505.0;
pub const TOUCH_JSON_BYTES_PER_TRIAL: f64 = 7_279.0;
pub const OBJECT_PLY_BYTES: f64 = 11_306.0;
pub const CAMERA_JSON_BYTES: f64 = 1_612.0;

/// The size of one view's file at `pixels` pixels per image.
pub fn view_file_bytes(file: ViewFile, pixels: u64) -> u64 {
    let px = pixels as f64;
    let bytes = match file {
        ViewFile::Rgb => RGB_BYTES_PER_PIXEL * px,
        ViewFile::Depth => return 4 * pixels + NPY_HEADER_BYTES,
        ViewFile::Mask | ViewFile::MaskFull => MASKS_BYTES_PER_PIXEL / 2.0 * px,
        ViewFile::Segmentation => SEGMENTATION_BYTES_PER_PIXEL * px,
        ViewFile::Camera => CAMERA_JSON_BYTES,
    };
    bytes.round().max(1.0) as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn view_files_reproduce_the_measured_tiny_sizes() {
        let px = 128 * 128;
        assert_eq!(view_file_bytes(ViewFile::Depth, px), 65_664, "a 128×128 float32 .npy");
        let rgb = view_file_bytes(ViewFile::Rgb, px) as f64;
        assert!((rgb - 29_916.0).abs() / 29_916.0 < 0.02, "{rgb}");
        assert_eq!(view_file_bytes(ViewFile::Camera, px), view_file_bytes(ViewFile::Camera, 4 * px));
        assert!(view_file_bytes(ViewFile::Mask, 16) >= 1, "no empty file, however small the image");
    }
}
