//! User asset files: the files a spec names for its own hands (MJCF model, taxel layout), objects
//! (mesh) and environments (HDRI). They travel with the submission, are stored content-addressed, and task
//! parameters name them by SHA-256, so a task still means the same thing when the file on the
//! user's disk changes.
//!
//! This module only describes them and their limits; reading files is the client's job, storing
//! them the coordinator's.

use serde::{Deserialize, Serialize};

/// Largest single asset file accepted.
pub const MAX_ASSET_BYTES: u64 = 8 << 20;
/// Largest total of a spec's asset files (they travel in one submission message).
pub const MAX_ASSETS_TOTAL_BYTES: u64 = 24 << 20;

/// Where a spec names an asset: the field (`hand.gripper.mjcf`) and its path, relative to the
/// spec file, exactly as written.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct AssetUse {
    pub field: String,
    pub path: String,
}

/// An asset as submitted and stored: its spec path, content hash and size.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Asset {
    pub path: String,
    pub sha256: String,
    pub size: u64,
}

impl Asset {
    /// The file's name without its directories (engines stage it under this name, so its
    /// extension still tells the format).
    pub fn file_name(&self) -> &str {
        file_name(&self.path)
    }
}

pub fn file_name(path: &str) -> &str {
    path.rsplit('/').next().unwrap_or(path)
}

/// The media type recorded for an asset, from its extension.
pub fn media_type(path: &str) -> &'static str {
    let lower = file_name(path).to_ascii_lowercase();
    match lower.rsplit_once('.').map(|(_, ext)| ext) {
        Some("xml") => "application/xml",
        Some("csv") => "text/csv",
        Some("obj") => "model/obj",
        Some("stl") => "model/stl",
        Some("ply") => "application/x-ply",
        Some("hdr") => "image/vnd.radiance",
        Some("exr") => "image/x-exr",
        _ => "application/octet-stream",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn media_types_follow_the_extension() {
        assert_eq!(media_type("assets/Gripper.XML"), "application/xml");
        assert_eq!(media_type("bowl.obj"), "model/obj");
        assert_eq!(media_type("assets/lab.HDR"), "image/vnd.radiance");
        assert_eq!(media_type("x"), "application/octet-stream");
        assert_eq!(file_name("a/b/c.csv"), "c.csv");
    }
}
