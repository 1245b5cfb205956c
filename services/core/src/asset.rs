//! User asset files: the files a spec names for its own hands (MJCF model, taxel layout), objects
//! (mesh and its sidecars: MTL, textures, glTF buffers) and environments (HDRI). They travel with
//! the submission, are stored content-addressed, and task parameters name them by SHA-256, so a
//! task still means the same thing when the file on the user's disk changes.
//!
//! This module only describes them and their limits; reading files is the client's job, storing
//! them the coordinator's.

use serde::{Deserialize, Serialize};

/// Largest single asset file accepted: a scanned model's 4096² PNG texture fits.
pub const MAX_ASSET_BYTES: u64 = 64 << 20;
/// Largest total of a spec's asset files (they travel in one submission message, which the
/// coordinator holds in memory while it stores them): a set of scanned models with their
/// textures fits.
pub const MAX_ASSETS_TOTAL_BYTES: u64 = 512 << 20;
/// Most triangles an object mesh may have (after polygons are split into triangles). A scanned
/// YCB model has ~16k–300k; convex decomposition and the render's mesh grow with the count.
/// The grasp engine holds the same number (`vint_engines/objects/meshio.py`).
pub const MAX_MESH_FACES: u64 = 500_000;
/// Most sidecar files one object may list.
pub const MAX_SIDECARS: usize = 64;

/// Mesh file formats an object's `mesh` may be.
pub const MESH_EXTENSIONS: &[&str] = &["obj", "stl", "ply", "gltf", "glb"];
/// Files an object's `files` may list: an OBJ's material library, texture images, a glTF's
/// binary buffers.
pub const SIDECAR_EXTENSIONS: &[&str] = &["mtl", "png", "jpg", "jpeg", "bin"];

/// Mesh file formats a hand MJCF's `<mesh file=…>` may be (MuJoCo reads these).
pub const HAND_MESH_EXTENSIONS: &[&str] = &["stl", "obj", "msh"];
/// Most mesh files one hand may list: a Menagerie or robosuite hand has 15–40.
pub const MAX_HAND_FILES: usize = 256;

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
        Some("gltf") => "model/gltf+json",
        Some("glb") => "model/gltf-binary",
        Some("mtl") => "model/mtl",
        Some("bin") => "application/octet-stream",
        Some("png") => "image/png",
        Some("jpg" | "jpeg") => "image/jpeg",
        Some("hdr") => "image/vnd.radiance",
        Some("exr") => "image/x-exr",
        _ => "application/octet-stream",
    }
}

/// The files a mesh or material file refers to, as it writes them (relative to its own
/// directory): an OBJ's `mtllib`, an MTL's texture maps, a PLY's `comment TextureFile`, a glTF's
/// (or GLB's) external buffer and image `uri`s. Unknown formats refer to nothing.
pub fn references(path: &str, content: &[u8]) -> Vec<String> {
    let lower = file_name(path).to_ascii_lowercase();
    let text = || String::from_utf8_lossy(content);
    let mut out: Vec<String> = match lower.rsplit_once('.').map(|(_, ext)| ext) {
        Some("obj") => text()
            .lines()
            .filter_map(|l| l.trim().strip_prefix("mtllib "))
            .map(|rest| rest.trim().to_string())
            .collect(),
        Some("mtl") => text()
            .lines()
            .filter_map(|l| {
                let mut words = l.split_whitespace();
                let key = words.next()?.to_ascii_lowercase();
                // Options (`-bm 1.0`, `-s 1 1 1`) come first; the file name is the last word.
                (key.starts_with("map_") || key == "bump" || key == "disp" || key == "decal" || key == "norm")
                    .then(|| words.last().map(str::to_string))
                    .flatten()
            })
            .collect(),
        Some("ply") => ply_header(content)
            .lines()
            .filter_map(|l| l.trim().strip_prefix("comment TextureFile "))
            .map(|rest| rest.trim().to_string())
            .collect(),
        Some("gltf") => gltf_uris(content),
        Some("glb") => glb_json(content).map(gltf_uris).unwrap_or_default(),
        _ => Vec::new(),
    };
    out.retain(|r| !r.is_empty());
    out.dedup();
    out
}

/// The triangles a mesh file holds, read from its header or counted from its records (polygons
/// count as fans); `None` for formats whose count needs a full parse (glTF, GLB).
pub fn mesh_faces(path: &str, content: &[u8]) -> Option<u64> {
    let lower = file_name(path).to_ascii_lowercase();
    match lower.rsplit_once('.').map(|(_, ext)| ext) {
        Some("obj") => Some(
            String::from_utf8_lossy(content)
                .lines()
                .filter_map(|l| l.trim_start().strip_prefix("f "))
                .map(|rest| rest.split_whitespace().count().saturating_sub(2) as u64)
                .sum(),
        ),
        Some("ply") => ply_header(content).lines().find_map(|l| {
            let rest = l.trim().strip_prefix("element face ")?;
            rest.trim().parse().ok()
        }),
        Some("stl") if !content.starts_with(b"solid") || !content.windows(5).any(|w| w == b"facet") => {
            content.get(80..84).map(|b| u64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])))
        }
        Some("stl") => Some(String::from_utf8_lossy(content).matches("facet normal").count() as u64),
        _ => None,
    }
}

fn ply_header(content: &[u8]) -> String {
    let end = content.windows(10).position(|w| w == b"end_header").unwrap_or(content.len().min(1 << 16));
    String::from_utf8_lossy(&content[..end]).into_owned()
}

fn glb_json(content: &[u8]) -> Option<&[u8]> {
    let length = u32::from_le_bytes(content.get(12..16)?.try_into().ok()?) as usize;
    (content.get(16..20)? == b"JSON").then(|| content.get(20..20 + length))?
}

fn gltf_uris(json: &[u8]) -> Vec<String> {
    let Ok(doc) = serde_json::from_slice::<serde_json::Value>(json) else { return Vec::new() };
    ["buffers", "images"]
        .iter()
        .filter_map(|key| doc.get(key)?.as_array())
        .flatten()
        .filter_map(|item| item.get("uri")?.as_str())
        .filter(|uri| !uri.starts_with("data:"))
        .map(str::to_string)
        .collect()
}

/// A reference written in a file at `from` (a spec-relative path), as a spec-relative path:
/// `None` when it is absolute or climbs above the spec's directory.
pub fn resolve_reference(from: &str, reference: &str) -> Option<String> {
    let reference = reference.replace('\\', "/");
    if reference.starts_with('/') || reference.contains(':') {
        return None;
    }
    let mut parts: Vec<&str> = from.split('/').collect();
    parts.pop();
    for part in reference.split('/') {
        match part {
            "" | "." => {}
            ".." => {
                parts.pop()?;
            }
            p => parts.push(p),
        }
    }
    Some(parts.join("/"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn references_are_read_from_each_format() {
        let obj = b"# box\nmtllib box.mtl\nv 0 0 0\nf 1 2 3 4\nf 1 2 3\n";
        assert_eq!(references("a/box.obj", obj), ["box.mtl"]);
        assert_eq!(mesh_faces("a/box.obj", obj), Some(3));
        let mtl = b"newmtl m\nKd 1 1 1\nmap_Kd -s 1 1 1 tex/box.png\nmap_Bump n.png\n";
        assert_eq!(references("a/box.mtl", mtl), ["tex/box.png", "n.png"]);
        let ply = b"ply\nformat ascii 1.0\ncomment TextureFile obj_000001.png\nelement vertex 3\nelement face 16000\nend_header\n";
        assert_eq!(references("m/obj_000001.ply", ply), ["obj_000001.png"]);
        assert_eq!(mesh_faces("m/obj_000001.ply", ply), Some(16000));
        let gltf = br#"{"buffers":[{"uri":"m.bin"},{"uri":"data:application/octet-stream;base64,AA=="}],"images":[{"uri":"c.png"}]}"#;
        assert_eq!(references("m.gltf", gltf), ["m.bin", "c.png"]);
        let mut glb = b"glTF\x02\0\0\0\0\0\0\0".to_vec();
        glb.extend((gltf.len() as u32).to_le_bytes());
        glb.extend(b"JSON");
        glb.extend(gltf);
        assert_eq!(references("m.glb", &glb), ["m.bin", "c.png"]);
        assert_eq!(resolve_reference("a/box.mtl", "tex/box.png").as_deref(), Some("a/tex/box.png"));
        assert_eq!(resolve_reference("a/box.obj", "../box.mtl").as_deref(), Some("box.mtl"));
        assert_eq!(resolve_reference("box.obj", "../box.mtl"), None);
        assert_eq!(resolve_reference("box.obj", "/etc/passwd"), None);
    }

    #[test]
    fn the_engines_hold_the_same_face_limit() {
        let meshio = include_str!("../../../workers/engines/vint_engines/objects/meshio.py");
        let pinned = format!(
            "MAX_MESH_FACES = {}",
            MAX_MESH_FACES
                .to_string()
                .as_bytes()
                .rchunks(3)
                .rev()
                .map(|c| std::str::from_utf8(c).unwrap())
                .collect::<Vec<_>>()
                .join("_")
        );
        assert!(meshio.contains(&pinned), "meshio.py must say {pinned}");
    }

    #[test]
    fn media_types_follow_the_extension() {
        assert_eq!(media_type("assets/Gripper.XML"), "application/xml");
        assert_eq!(media_type("bowl.obj"), "model/obj");
        assert_eq!(media_type("assets/lab.HDR"), "image/vnd.radiance");
        assert_eq!(media_type("x"), "application/octet-stream");
        assert_eq!(file_name("a/b/c.csv"), "c.csv");
    }
}
