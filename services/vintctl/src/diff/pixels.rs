//! Image and array comparisons: RGB images by channel levels, label images (masks, segmentation)
//! by the share of pixels whose label differs, depth maps (float32 metres) by the largest
//! difference where both have a return and the share of pixels valid in only one.

use std::io::Cursor;

use anyhow::{Context, bail};

use super::npy::Array;
use super::{Finding, Measure, Tolerances};

/// A decoded image: `channels` samples per pixel, row-major, widened to u16.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub samples: Vec<u16>,
}

impl Image {
    /// Colour images are compared as RGB; single-channel ones hold labels (masks, segmentation).
    pub fn is_colour(&self) -> bool {
        self.channels >= 3
    }

    fn size(&self) -> String {
        format!("{}×{}×{}", self.width, self.height, self.channels)
    }
}

pub fn decode_png(bytes: &[u8]) -> anyhow::Result<Image> {
    let mut decoder = png::Decoder::new(Cursor::new(bytes));
    decoder.set_transformations(png::Transformations::EXPAND); // palettes and low bit depths to 8 bits
    let mut reader = decoder.read_info().context("reading the PNG header")?;
    let size = reader.output_buffer_size().context("PNG too large for memory")?;
    let mut buffer = vec![0; size];
    let frame = reader.next_frame(&mut buffer).context("decoding the PNG")?;
    buffer.truncate(frame.buffer_size());
    let samples: Vec<u16> = match frame.bit_depth {
        png::BitDepth::Eight => buffer.iter().map(|&b| u16::from(b)).collect(),
        png::BitDepth::Sixteen => buffer.chunks_exact(2).map(|c| u16::from_be_bytes([c[0], c[1]])).collect(),
        depth => bail!("unexpected PNG bit depth {depth:?} after expansion"),
    };
    let (width, height) = (frame.width as usize, frame.height as usize);
    let channels = samples.len() / (width * height).max(1);
    Ok(Image { width, height, channels, samples })
}

/// RGB: within tolerance when no channel differs by more than `rgb_levels` and at most
/// `rgb_share` of the pixels differ at all.
pub fn compare_rgb(a: &Image, b: &Image, tolerances: &Tolerances) -> Finding {
    if (a.width, a.height, a.channels) != (b.width, b.height, b.channels) {
        return Finding::structural(format!("image size {} in A, {} in B", a.size(), b.size()));
    }
    let (mut worst, mut worst_at, mut differing) = (0u16, 0usize, 0usize);
    for (pixel, (pa, pb)) in a.samples.chunks_exact(a.channels).zip(b.samples.chunks_exact(b.channels)).enumerate() {
        let largest = pa.iter().zip(pb).map(|(x, y)| x.abs_diff(*y)).max().unwrap_or(0);
        differing += usize::from(largest > 0);
        if largest > worst {
            (worst, worst_at) = (largest, pixel);
        }
    }
    let pixels = a.width * a.height;
    Finding::measured(vec![
        Measure::new("max_abs_levels", f64::from(worst), f64::from(tolerances.rgb_levels), "levels")
            .at(pixel_at(worst_at, a.width)),
        Measure::new("differing_share", share(differing, pixels), tolerances.rgb_share, "share")
            .at(format!("{differing} of {pixels} pixels")),
    ])
}

/// Label images: within tolerance when at most `label_share` of the pixels carry another label.
pub fn compare_labels(a: &Image, b: &Image, tolerances: &Tolerances) -> Finding {
    if (a.width, a.height, a.channels) != (b.width, b.height, b.channels) {
        return Finding::structural(format!("image size {} in A, {} in B", a.size(), b.size()));
    }
    let differs =
        |i: usize| a.samples[i * a.channels..(i + 1) * a.channels] != b.samples[i * b.channels..(i + 1) * b.channels];
    labels_finding((0..a.width * a.height).filter(|&i| differs(i)), a.width * a.height, a.width, tolerances)
}

/// Integer arrays (`.npy` of uint8/uint16) are labels too.
pub fn compare_label_arrays(a: &Array, b: &Array, tolerances: &Tolerances) -> Finding {
    if a.shape != b.shape {
        return Finding::structural(format!("shape {:?} in A, {:?} in B", a.shape, b.shape));
    }
    let width = a.shape.last().copied().unwrap_or(1).max(1);
    let differing = a.values.iter().zip(&b.values).enumerate().filter(|(_, (x, y))| x != y).map(|(i, _)| i);
    labels_finding(differing, a.values.len(), width, tolerances)
}

fn labels_finding(
    differing: impl Iterator<Item = usize>,
    pixels: usize,
    width: usize,
    tolerances: &Tolerances,
) -> Finding {
    let (mut count, mut first) = (0usize, None);
    for i in differing {
        count += 1;
        first.get_or_insert(i);
    }
    let at = match first {
        Some(i) => format!("{count} of {pixels} pixels, first at {}", pixel_at(i, width)),
        None => format!("0 of {pixels} pixels"),
    };
    Finding::measured(vec![
        Measure::new("differing_share", share(count, pixels), tolerances.label_share, "share").at(at),
    ])
}

/// Depth maps (float32 metres, 0 or non-finite = no return): the largest difference over pixels
/// valid in both, and the share of pixels valid in only one.
pub fn compare_depth(a: &Array, b: &Array, tolerances: &Tolerances) -> Finding {
    if a.shape != b.shape {
        return Finding::structural(format!("shape {:?} in A, {:?} in B", a.shape, b.shape));
    }
    let width = a.shape.last().copied().unwrap_or(1).max(1);
    let valid = |v: f64| v.is_finite() && v > 0.0;
    let (mut worst, mut worst_at, mut one_sided, mut first_one_sided) = (0.0f64, 0usize, 0usize, None);
    for (i, (&x, &y)) in a.values.iter().zip(&b.values).enumerate() {
        match (valid(x), valid(y)) {
            (true, true) if (x - y).abs() > worst => (worst, worst_at) = ((x - y).abs(), i),
            (true, false) | (false, true) => {
                one_sided += 1;
                first_one_sided.get_or_insert(i);
            }
            _ => {}
        }
    }
    let pixels = a.values.len();
    let one_sided_at = match first_one_sided {
        Some(i) => format!("{one_sided} of {pixels} pixels, first at {}", pixel_at(i, width)),
        None => format!("0 of {pixels} pixels"),
    };
    Finding::measured(vec![
        Measure::new("max_abs_m", worst, tolerances.depth_m, "m").at(pixel_at(worst_at, width)),
        Measure::new("valid_in_one_share", share(one_sided, pixels), tolerances.depth_invalid_share, "share")
            .at(one_sided_at),
    ])
}

fn share(count: usize, of: usize) -> f64 {
    if of == 0 { 0.0 } else { count as f64 / of as f64 }
}

/// Pixel `index` of a row-major image `width` wide, as (u, v): column, row.
fn pixel_at(index: usize, width: usize) -> String {
    format!("pixel (u={}, v={})", index % width, index / width)
}

/// Test helper: a PNG of 8-bit samples, `channels` per pixel (1: grey, 3: RGB).
#[cfg(test)]
pub fn encode_png(width: u32, height: u32, channels: usize, samples: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(&mut out, width, height);
    encoder.set_color(if channels == 3 { png::ColorType::Rgb } else { png::ColorType::Grayscale });
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header().expect("png header");
    writer.write_image_data(samples).expect("png data");
    writer.finish().expect("png end");
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diff::npy;

    fn rgb(width: u32, height: u32, edit: impl Fn(&mut [u8])) -> Image {
        let mut samples: Vec<u8> = (0..width * height * 3).map(|i| (i * 7 % 251) as u8).collect();
        edit(&mut samples);
        decode_png(&encode_png(width, height, 3, &samples)).expect("decodes")
    }

    #[test]
    fn a_pixel_one_level_off_is_within_the_default_rgb_tolerance_and_forty_levels_off_is_not() {
        let tolerances = Tolerances::default();
        let reference = rgb(64, 48, |_| {});
        let one_level = rgb(64, 48, |s| s[3 * (10 * 64 + 5) + 1] ^= 1);
        let finding = compare_rgb(&reference, &one_level, &tolerances);
        assert!(finding.within(), "{finding:?}");
        assert_eq!(finding.measures[0].value, 1.0);

        let forty = rgb(64, 48, |s| {
            let green = &mut s[3 * (10 * 64 + 5) + 1];
            *green = if *green >= 128 { *green - 40 } else { *green + 40 };
        });
        let finding = compare_rgb(&reference, &forty, &tolerances);
        assert!(!finding.within());
        assert_eq!(finding.measures[0].value, 40.0);
        assert_eq!(finding.measures[0].at.as_deref(), Some("pixel (u=5, v=10)"));
    }

    #[test]
    fn one_pixel_twelve_levels_off_as_measured_across_cpus_is_within_the_default() {
        let reference = rgb(128, 128, |_| {});
        let flipped = rgb(128, 128, |s| {
            let red = &mut s[3 * (59 * 128 + 75)];
            *red = if *red >= 12 { *red - 12 } else { *red + 12 };
        });
        let finding = compare_rgb(&reference, &flipped, &Tolerances::default());
        assert!(finding.within(), "{finding:?}");
    }

    #[test]
    fn many_pixels_a_level_off_are_over_the_share_tolerance() {
        let reference = rgb(64, 48, |_| {});
        let tinted = rgb(64, 48, |s| s.iter_mut().step_by(3).for_each(|r| *r ^= 1));
        let finding = compare_rgb(&reference, &tinted, &Tolerances::default());
        assert!(!finding.within());
        assert_eq!(finding.measures[1].value, 1.0, "every pixel differs");
    }

    #[test]
    fn images_of_different_sizes_differ_structurally() {
        let finding = compare_rgb(&rgb(64, 48, |_| {}), &rgb(32, 48, |_| {}), &Tolerances::default());
        assert!(!finding.within());
        assert_eq!(finding.notes, ["image size 64×48×3 in A, 32×48×3 in B"]);
    }

    #[test]
    fn label_images_count_the_pixels_whose_label_changed() {
        let mask = |flip: usize| {
            let mut samples = vec![0u8; 100 * 100];
            samples[4000..6000].fill(255);
            samples[..flip].fill(255);
            decode_png(&encode_png(100, 100, 1, &samples)).expect("decodes")
        };
        assert!(!mask(0).is_colour());
        let tolerances = Tolerances::default();
        let one = compare_labels(&mask(0), &mask(1), &tolerances);
        assert!(one.within(), "one pixel of 10000 is 0.01 %: {one:?}");
        let many = compare_labels(&mask(0), &mask(500), &tolerances);
        assert!(!many.within());
        assert_eq!(many.measures[0].value, 0.05);
        assert_eq!(many.measures[0].at.as_deref(), Some("500 of 10000 pixels, first at pixel (u=0, v=0)"));
    }

    fn depth(edit: impl Fn(&mut [f32])) -> Array {
        let mut values: Vec<f32> = (0..32 * 32).map(|i| 0.4 + (i % 32) as f32 * 1e-3).collect();
        values[..32].fill(0.0); // a row without returns
        edit(&mut values);
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        npy::parse(&npy::encode("<f4", &[32, 32], &bytes)).expect("parses")
    }

    #[test]
    fn depth_a_micrometre_off_is_within_tolerance_and_a_millimetre_off_is_not() {
        let tolerances = Tolerances::default();
        let micrometre = compare_depth(&depth(|_| {}), &depth(|d| d[40] += 1e-6), &tolerances);
        assert!(micrometre.within(), "{micrometre:?}");
        let millimetre = compare_depth(&depth(|_| {}), &depth(|d| d[40] += 1e-3), &tolerances);
        assert!(!millimetre.within());
        assert!((millimetre.measures[0].value - 1e-3).abs() < 1e-6);
        assert_eq!(millimetre.measures[0].at.as_deref(), Some("pixel (u=8, v=1)"));
    }

    #[test]
    fn depth_pixels_valid_in_only_one_map_are_counted_not_measured() {
        let holes = compare_depth(&depth(|_| {}), &depth(|d| d[100..200].fill(0.0)), &Tolerances::default());
        assert_eq!(holes.measures[0].value, 0.0, "a hole is no distance");
        assert!((holes.measures[1].value - 100.0 / 1024.0).abs() < 1e-12);
        assert!(!holes.within());
        let nan = compare_depth(&depth(|_| {}), &depth(|d| d[0] = f32::NAN), &Tolerances::default());
        assert!(nan.within(), "no return either way: {nan:?}");
    }
}
