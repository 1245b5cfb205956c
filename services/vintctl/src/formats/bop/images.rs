//! The export's pixels: depth in BOP's uint16 encoding, masks as 0/255 PNGs, and what
//! `scene_gt_info.json` says about a mask (pixel count, bounding box).

use anyhow::{Context, bail};

use crate::diff::pixels::decode_png;

/// `depth_png × DEPTH_SCALE_MM = millimetres`: BOP's encoding is native PNG depth's
/// (`vint_core::contract::depth`, 0.1 mm steps to 6553.5 mm), at a resolution well below any depth
/// sensor's noise.
pub const DEPTH_SCALE_MM: f64 = 0.1;

/// A depth value in BOP's units (0.1 mm), or 0 — BOP's "no data" — where the native depth has no
/// return (0, negative, NaN or infinite) or lies beyond what uint16 holds (6553.5 mm, reachable
/// only by `.npy` depth): a clipped value would be a wrong depth, a missing one is only a hole.
pub fn depth_units(metres: f64) -> u16 {
    vint_core::contract::depth::png_units(metres)
}

/// A binary image, row-major.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Mask {
    pub width: usize,
    pub height: usize,
    pub pixels: Vec<bool>,
}

impl Mask {
    /// Any single-channel PNG; a pixel is set where its value is not 0.
    pub fn decode(bytes: &[u8]) -> anyhow::Result<Mask> {
        let image = decode_png(bytes)?;
        if image.channels != 1 {
            bail!("a mask must have one channel, this PNG has {}", image.channels);
        }
        Ok(Mask { width: image.width, height: image.height, pixels: image.samples.iter().map(|&v| v != 0).collect() })
    }

    pub fn count(&self) -> u64 {
        self.pixels.iter().filter(|&&p| p).count() as u64
    }

    /// The pixels set in either.
    pub fn union(&self, other: &Mask) -> Mask {
        let pixels = self.pixels.iter().zip(&other.pixels).map(|(a, b)| *a || *b).collect();
        Mask { width: self.width, height: self.height, pixels }
    }

    /// COCO's uncompressed run-length encoding (`pycoco_utils.binary_mask_to_rle`): the lengths
    /// of the alternating runs of unset and set pixels in column-major order, starting with the
    /// unset (a leading 0 when the first pixel is set).
    pub fn coco_rle(&self) -> Vec<u64> {
        let mut counts = Vec::new();
        let (mut current, mut run) = (false, 0u64);
        for x in 0..self.width {
            for y in 0..self.height {
                let p = self.pixels[y * self.width + x];
                if p == current {
                    run += 1;
                } else {
                    counts.push(run);
                    (current, run) = (p, 1);
                }
            }
        }
        counts.push(run);
        counts
    }

    /// COCO's `[x, y, w, h]` (`pycoco_utils.bbox_from_binary_mask`: w and h count pixels, so one
    /// pixel is 1 × 1); `None` for an empty mask.
    pub fn coco_bbox(&self) -> Option<[i64; 4]> {
        let [x, y, w, h] = self.bbox();
        (x >= 0).then_some([x, y, w + 1, h + 1])
    }

    /// `[x, y, w, h]` as the BOP toolkit computes it (`misc.calc_2d_bbox`): (x, y) the top-left
    /// set pixel's column and row, `w = x_max − x_min`, `h = y_max − y_min` (so a single pixel has
    /// w = h = 0); `[-1, -1, -1, -1]` for an empty mask.
    pub fn bbox(&self) -> [i64; 4] {
        let mut lo = [usize::MAX; 2];
        let mut hi = [0usize; 2];
        for (i, _) in self.pixels.iter().enumerate().filter(|(_, p)| **p) {
            let (x, y) = (i % self.width, i / self.width);
            lo = [lo[0].min(x), lo[1].min(y)];
            hi = [hi[0].max(x), hi[1].max(y)];
        }
        if lo[0] == usize::MAX {
            return [-1; 4];
        }
        [lo[0] as i64, lo[1] as i64, (hi[0] - lo[0]) as i64, (hi[1] - lo[1]) as i64]
    }

    /// 8-bit grayscale PNG, 255 where set.
    pub fn encode(&self) -> anyhow::Result<Vec<u8>> {
        let samples: Vec<u8> = self.pixels.iter().map(|&p| if p { 255 } else { 0 }).collect();
        encode_gray(self.width, self.height, png::BitDepth::Eight, &samples)
    }
}

/// A 16-bit grayscale PNG; PNG stores 16-bit samples big-endian.
pub fn encode_depth(width: usize, height: usize, units: &[u16]) -> anyhow::Result<Vec<u8>> {
    let samples: Vec<u8> = units.iter().flat_map(|v| v.to_be_bytes()).collect();
    encode_gray(width, height, png::BitDepth::Sixteen, &samples)
}

fn encode_gray(width: usize, height: usize, depth: png::BitDepth, samples: &[u8]) -> anyhow::Result<Vec<u8>> {
    let mut bytes = Vec::new();
    let (w, h) = (u32::try_from(width).context("image too wide")?, u32::try_from(height).context("image too tall")?);
    let mut encoder = png::Encoder::new(&mut bytes, w, h);
    encoder.set_color(png::ColorType::Grayscale);
    encoder.set_depth(depth);
    let mut writer = encoder.write_header().context("writing a PNG header")?;
    writer.write_image_data(samples).context("encoding a PNG")?;
    writer.finish().context("finishing a PNG")?;
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mask(width: usize, rows: &[&str]) -> Mask {
        let pixels: Vec<bool> = rows.iter().flat_map(|r| r.chars().map(|c| c == '#')).collect();
        Mask { width, height: rows.len(), pixels }
    }

    #[test]
    fn depth_is_tenths_of_a_millimetre_rounded_with_zero_for_no_data() {
        assert_eq!(DEPTH_SCALE_MM, vint_core::contract::depth::PNG_UNIT_M * 1000.0);
        assert_eq!(depth_units(0.5), 5000);
        assert_eq!(depth_units(0.123_456), 1235); // 1234.56 → 1235
        assert_eq!(depth_units(0.123_44), 1234);
        assert_eq!(depth_units(6.5535), 65535);
        assert_eq!(depth_units(6.5536), 0, "beyond uint16: no data, not a clipped depth");
        for none in [0.0, -0.2, f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 1e-6] {
            assert_eq!(depth_units(none), 0, "{none}");
        }
    }

    #[test]
    fn bbox_follows_the_toolkit_width_convention() {
        let m = mask(5, &[".....", "..#..", ".###.", "....."]);
        assert_eq!(m.bbox(), [1, 1, 2, 1]);
        assert_eq!(m.count(), 4);
        assert_eq!(mask(3, &["...", ".#."]).bbox(), [1, 1, 0, 0]);
        assert_eq!(mask(2, &["..", ".."]).bbox(), [-1; 4]);
        let corner = mask(3, &["#..", "...", "..#"]);
        assert_eq!(corner.bbox(), [0, 0, 2, 2]);
    }

    #[test]
    fn masks_and_depth_survive_a_png_round_trip() {
        let m = mask(4, &["#..#", ".##.", "...."]);
        let back = Mask::decode(&m.encode().expect("encode")).expect("decode");
        assert_eq!(back, m);
        let units = [0u16, 1, 255, 256, 5000, 65535];
        let decoded = decode_png(&encode_depth(3, 2, &units).expect("encode")).expect("decode");
        assert_eq!((decoded.width, decoded.height, decoded.channels), (3, 2, 1));
        assert_eq!(decoded.samples, units, "16-bit samples are big-endian in the PNG");
    }

    #[test]
    fn coco_runs_go_down_the_columns_and_its_box_counts_pixels() {
        // Columns, top to bottom: "#.", "##", ".#": set 1, unset 1, set 2, unset 1, set 1.
        let m = mask(3, &["##.", ".##"]);
        assert_eq!(m.coco_rle(), [0, 1, 1, 2, 1, 1]);
        assert_eq!(m.coco_bbox(), Some([0, 0, 3, 2]));
        assert_eq!(mask(2, &["..", ".."]).coco_rle(), [4], "all unset: one run");
        assert_eq!(mask(2, &["..", ".#"]).coco_rle(), [3, 1]);
        assert_eq!(mask(3, &["...", ".#."]).coco_bbox(), Some([1, 1, 1, 1]));
        assert_eq!(mask(2, &["..", ".."]).coco_bbox(), None);
    }

    #[test]
    fn the_union_holds_both_masks() {
        let a = mask(3, &["#..", "..."]);
        let b = mask(3, &["...", "..#"]);
        assert_eq!(a.union(&b), mask(3, &["#..", "..#"]));
    }
}
