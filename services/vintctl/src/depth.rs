//! The one rule by which `vintctl` reads a native depth file (`depth.*`, `depth_noisy.*` of a
//! sample; `vint_core::contract::depth` defines both formats): a 16-bit PNG counts steps of
//! `PNG_UNIT_M` (0 = no reading), a `.npy` holds float32 metres. Either reads as metres, so `diff`
//! and the exports treat a dataset of either kind alike.

use std::io::Cursor;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use vint_core::contract::depth::{self, DepthFormat};

use crate::diff::npy::{self, Array};

/// The names a sample's depth files have before their extension.
pub const STEMS: [&str; 2] = ["depth", "depth_noisy"];

/// Whether `name` (a file within a sample, or a path ending in one) is a native depth file.
pub fn is_depth_file(name: &str) -> bool {
    let file = name.rsplit('/').next().unwrap_or(name);
    file.rsplit_once('.').is_some_and(|(stem, _)| STEMS.contains(&stem)) && DepthFormat::of_file(file).is_some()
}

/// A depth file's bytes as metres (`Array` of dtype `f4`, shape [height, width]; 0 = no reading).
pub fn decode(name: &str, bytes: &[u8]) -> anyhow::Result<Array> {
    match DepthFormat::of_file(name) {
        Some(DepthFormat::Png) => decode_png_depth(bytes),
        Some(DepthFormat::Npy) => {
            let array = npy::parse(bytes)?;
            if !array.is_float() || array.shape.len() != 2 {
                bail!("expected a float32 image of metres, found {} {:?}", array.dtype, array.shape);
            }
            Ok(array)
        }
        None => bail!("{name}: not a depth file (.png or .npy)"),
    }
}

fn decode_png_depth(bytes: &[u8]) -> anyhow::Result<Array> {
    let decoder = png::Decoder::new(Cursor::new(bytes));
    let mut reader = decoder.read_info().context("reading the PNG header")?;
    let (color, bit_depth) = reader.output_color_type();
    if (color, bit_depth) != (png::ColorType::Grayscale, png::BitDepth::Sixteen) {
        bail!("a depth PNG is 16-bit grayscale, this one is {bit_depth:?}-bit {color:?}");
    }
    let size = reader.output_buffer_size().context("PNG too large for memory")?;
    let mut buffer = vec![0; size];
    let frame = reader.next_frame(&mut buffer).context("decoding the PNG")?;
    buffer.truncate(frame.buffer_size());
    let values = buffer.chunks_exact(2).map(|c| depth::png_metres(u16::from_be_bytes([c[0], c[1]]))).collect();
    Ok(Array { dtype: "f4", shape: vec![frame.height as usize, frame.width as usize], values })
}

/// A difference of two PNG depths (metres), as the whole number of steps it is.
pub fn whole_steps(metres: f64) -> f64 {
    (metres / depth::PNG_UNIT_M).round() * depth::PNG_UNIT_M
}

/// The depth file at `path`, as metres.
pub fn read(path: &Path) -> anyhow::Result<Array> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    decode(&path.to_string_lossy(), &bytes).with_context(|| format!("{}", path.display()))
}

/// The depth file `stem` (`depth`, `depth_noisy`) of the sample directory `sample`: whichever
/// format it was written in, or `None` when the sample has none.
pub fn find(sample: &Path, stem: &str) -> Option<PathBuf> {
    DepthFormat::ALL.iter().map(|f| sample.join(format!("{stem}.{}", f.extension()))).find(|p| p.is_file())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 16-bit grayscale PNG of `units`.
    fn png16(width: u32, height: u32, units: &[u16]) -> Vec<u8> {
        let mut out = Vec::new();
        let mut encoder = png::Encoder::new(&mut out, width, height);
        encoder.set_color(png::ColorType::Grayscale);
        encoder.set_depth(png::BitDepth::Sixteen);
        let mut writer = encoder.write_header().expect("png header");
        let samples: Vec<u8> = units.iter().flat_map(|u| u.to_be_bytes()).collect();
        writer.write_image_data(&samples).expect("png data");
        writer.finish().expect("png end");
        out
    }

    #[test]
    fn a_png_and_an_npy_of_one_depth_read_as_the_same_metres_within_half_a_step() {
        let metres = [0.0f32, 0.512_34, 1.0, 6.5535];
        let units: Vec<u16> = metres.iter().map(|&m| depth::png_units(f64::from(m))).collect();
        let png = decode("s/depth.png", &png16(2, 2, &units)).expect("png");
        let floats: Vec<u8> = metres.iter().flat_map(|m| m.to_le_bytes()).collect();
        let npy = decode("s/depth_noisy.npy", &npy::encode("<f4", &[2, 2], &floats)).expect("npy");
        assert_eq!((png.shape.as_slice(), npy.shape.as_slice()), (&[2usize, 2][..], &[2usize, 2][..]));
        for (p, n) in png.values.iter().zip(&npy.values) {
            assert!((p - n).abs() <= depth::PNG_UNIT_M / 2.0 + 1e-7, "{p} vs {n}");
        }
        assert_eq!(png.values[0], 0.0, "0 stays no reading");
    }

    #[test]
    fn only_single_channel_16_bit_pngs_and_float_arrays_are_depth() {
        let rgb = crate::diff::pixels::encode_png(1, 1, 3, &[1, 2, 3]);
        assert!(format!("{:#}", decode("depth.png", &rgb).unwrap_err()).contains("16-bit grayscale"));
        let grey8 = crate::diff::pixels::encode_png(1, 1, 1, &[7]);
        assert!(format!("{:#}", decode("depth.png", &grey8).unwrap_err()).contains("Eight-bit Grayscale"));
        let labels = npy::encode("|u1", &[1, 1], &[3]);
        assert!(format!("{:#}", decode("depth.npy", &labels).unwrap_err()).contains("float32"));
    }

    #[test]
    fn depth_files_are_named_depth_or_depth_noisy_with_a_depth_format() {
        for name in ["depth.png", "depth_noisy.npy", "a.v00/depth.npy", "a.v00/depth_noisy.png"] {
            assert!(is_depth_file(name), "{name}");
        }
        for name in ["rgb.png", "depth.json", "segmentation.png", "depth_noisy", "mydepth.png"] {
            assert!(!is_depth_file(name), "{name}");
        }
    }

    #[test]
    fn a_sample_is_read_in_whichever_format_it_has() {
        let dir = std::env::temp_dir().join(format!("vint-depth-find-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        std::fs::write(dir.join("depth.png"), png16(1, 1, &[12_345])).expect("png");
        std::fs::write(dir.join("depth_noisy.npy"), npy::encode("<f4", &[1, 1], &1.5f32.to_le_bytes())).expect("npy");
        let depth = read(&find(&dir, "depth").expect("depth.png")).expect("reads");
        assert!((depth.values[0] - 1.2345).abs() < 1e-9);
        assert_eq!(read(&find(&dir, "depth_noisy").expect("depth_noisy.npy")).expect("reads").values, [1.5]);
        assert!(find(&dir, "rgb").is_none());
        std::fs::remove_dir_all(&dir).expect("clean up");
    }
}
