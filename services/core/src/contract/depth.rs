//! How a depth image is stored: the render stage's `vNN_depth.*`, the noise stage's
//! `vNN_depth_noisy.*` and a packaged sample's `depth.*` / `depth_noisy.*` are one of two files.
//!
//! - `.png`: 16-bit grayscale, one step per `PNG_UNIT_M` (0.1 mm, BOP's
//!   `depth_scale` 0.1), 0 where there is no reading. A depth is rounded to the nearest step, so it
//!   reads back within half a step (0.05 mm); one beyond `PNG_MAX_M` stores as 0 (no reading): a
//!   clipped value would be a wrong depth, a missing one is only a hole.
//! - `.npy`: float32 metres, 0 where there is no reading; exact, and about 4× the bytes.
//!
//! Readers tell the two apart by the extension (`DepthFormat::of_file`) and accept either, so a
//! dataset of either kind reads the same.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

/// Metres per step of a depth PNG: 0.1 mm, well below any depth sensor's noise (the Azure Kinect's
/// σ is ≥ 0.5 mm) and the unit of the BOP export's depth (`depth_scale` 0.1), so both agree.
pub const PNG_UNIT_M: f64 = 1e-4;

/// The farthest depth a PNG holds: 65 535 steps of `PNG_UNIT_M`, 6.5535 m. Farther surfaces store
/// as 0 (no reading), as a real sensor's far field does (the Azure Kinect reaches at most 5.46 m).
pub const PNG_MAX_M: f64 = 6.5535; // u16::MAX × PNG_UNIT_M, written out: the product rounds to 6.5535000000000005

/// A depth file's format. PNG is the default: a fraction of `.npy`'s bytes, within 0.05 mm.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum DepthFormat {
    /// 16-bit grayscale PNG, 0.1 mm per step, 0 = no reading (beyond 6.5535 m too).
    #[default]
    Png,
    /// float32 metres as a NumPy `.npy`, 0 = no reading.
    Npy,
}

impl DepthFormat {
    pub const ALL: [DepthFormat; 2] = [DepthFormat::Png, DepthFormat::Npy];

    pub fn as_str(self) -> &'static str {
        match self {
            DepthFormat::Png => "png",
            DepthFormat::Npy => "npy",
        }
    }

    /// The file extension, which is also the name in `as_str`.
    pub fn extension(self) -> &'static str {
        self.as_str()
    }

    /// The format of a depth file named `name`, by its extension; `None` for another kind of file.
    pub fn of_file(name: &str) -> Option<DepthFormat> {
        let (_, extension) = name.rsplit_once('.')?;
        DepthFormat::ALL.into_iter().find(|f| f.extension() == extension)
    }
}

/// A depth in PNG steps: rounded to the nearest `PNG_UNIT_M`, 0 (no reading) for no return (0,
/// negative, NaN or infinite) and beyond `PNG_MAX_M`.
pub fn png_units(metres: f64) -> u16 {
    let units = (metres / PNG_UNIT_M).round();
    if units.is_finite() && units > 0.0 && units <= f64::from(u16::MAX) { units as u16 } else { 0 }
}

/// The depth a PNG step count stands for (metres; 0 = no reading).
pub fn png_metres(units: u16) -> f64 {
    f64::from(units) * PNG_UNIT_M
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_depth_reads_back_within_half_a_step_and_out_of_range_is_no_reading() {
        for metres in [0.000_05, 0.123_456_7, 0.5, 1.234_55, 3.86, 6.553_5] {
            let back = png_metres(png_units(metres));
            assert!((back - metres).abs() <= PNG_UNIT_M / 2.0 + 1e-12, "{metres} → {back}");
        }
        for none in [0.0, -0.1, f64::NAN, f64::INFINITY, PNG_MAX_M + PNG_UNIT_M, 1e10] {
            assert_eq!(png_units(none), 0, "{none}");
        }
        assert_eq!(png_units(PNG_MAX_M), u16::MAX);
    }

    #[test]
    fn a_file_says_its_format_by_its_extension() {
        assert_eq!(DepthFormat::of_file("v03_depth.png"), Some(DepthFormat::Png));
        assert_eq!(DepthFormat::of_file("a/depth_noisy.npy"), Some(DepthFormat::Npy));
        assert_eq!(DepthFormat::of_file("meta.json"), None);
        assert_eq!(serde_json::to_value(DepthFormat::Png).ok(), Some(serde_json::json!("png")));
    }
}
