//! A spec file as vintctl reads it: the TOML text, its validation (`vint_core::spec`) and the
//! user files it names, read relative to the spec's directory. Every problem is reported at once.

use std::path::Path;

use anyhow::Context;
use vint_core::asset::{self, MAX_ASSET_BYTES, MAX_ASSETS_TOTAL_BYTES, MAX_MESH_FACES};
use vint_core::{DatasetSpec, SpecError, SpecErrors};
use vint_proto::v1 as pb;

use crate::{Failure, InvalidSpec, bad_input, mjcf};

/// A spec as a submission carries it: its text, its parsed form and the user files it names.
pub struct LoadedSpec {
    pub text: String,
    pub spec: DatasetSpec,
    pub assets: Vec<pb::AssetFile>,
}

/// Reads and validates a spec and reads the files it names; every problem is reported and the
/// exit code is 2.
pub fn load_spec(path: &Path) -> Result<LoadedSpec, Failure> {
    let text = read_spec(path)?;
    let invalid = |errors| InvalidSpec::failure(path, errors);
    let spec = DatasetSpec::parse(&text).map_err(invalid)?;
    let assets = read_assets(path, &spec).map_err(invalid)?;
    check_meshes(&spec, &assets).map_err(invalid)?;
    check_hand_files(&spec, &assets).map_err(invalid)?;
    Ok(LoadedSpec { text, spec, assets })
}

/// The files the spec's own hands, objects and HDRIs name, read relative to the spec file's directory;
/// a missing, unreadable or oversized file is a spec error naming the field and the path.
pub fn read_assets(spec_path: &Path, spec: &DatasetSpec) -> Result<Vec<pb::AssetFile>, SpecErrors> {
    let base = spec_path.parent().unwrap_or(Path::new("."));
    let mut errors = Vec::new();
    let mut files: Vec<pb::AssetFile> = Vec::new();
    let mut total = 0u64;
    for used in spec.asset_uses() {
        if files.iter().any(|f| f.path == used.path) {
            continue;
        }
        let error = |rule: String, value: String| SpecError { path: used.field.clone(), value, rule };
        let file = base.join(&used.path);
        let size = match std::fs::metadata(&file) {
            Ok(m) if m.is_file() => m.len(),
            Ok(_) => {
                errors.push(error(
                    format!("must name a file ({} is not one)", file.display()),
                    format!("{:?}", used.path),
                ));
                continue;
            }
            Err(e) => {
                errors.push(error(
                    format!("must name a readable file ({}: {e})", file.display()),
                    format!("{:?}", used.path),
                ));
                continue;
            }
        };
        if size > MAX_ASSET_BYTES {
            errors.push(error(
                format!("must be a file of at most {MAX_ASSET_BYTES} bytes"),
                format!("{:?} ({size} bytes)", used.path),
            ));
            continue;
        }
        match std::fs::read(&file) {
            Ok(content) => {
                total += content.len() as u64;
                files.push(pb::AssetFile { path: used.path, content });
            }
            Err(e) => errors.push(error(
                format!("must name a readable file ({}: {e})", file.display()),
                format!("{:?}", used.path),
            )),
        }
    }
    if total > MAX_ASSETS_TOTAL_BYTES {
        errors.push(SpecError {
            path: String::new(),
            value: format!("{total} bytes"),
            rule: format!("the spec's files add up to {total} bytes, more than the limit of {MAX_ASSETS_TOTAL_BYTES}"),
        });
    }
    if errors.is_empty() { Ok(files) } else { Err(SpecErrors(errors)) }
}

/// Each user object's mesh within the face limit, and every file its mesh (and the MTLs it lists)
/// refers to listed in its `files`, so the render tasks get all of them and nothing else is read.
pub fn check_meshes(spec: &DatasetSpec, files: &[pb::AssetFile]) -> Result<(), SpecErrors> {
    let content = |path: &str| files.iter().find(|f| f.path == path).map(|f| f.content.as_slice());
    let mut errors = Vec::new();
    for name in &spec.objects {
        let Some(o) = spec.object_defs.get(name) else { continue };
        let Some(mesh) = content(&o.mesh) else { continue };
        if let Some(faces) = asset::mesh_faces(&o.mesh, mesh).filter(|&n| n > MAX_MESH_FACES) {
            errors.push(SpecError {
                path: format!("object.{name}.mesh"),
                value: format!("{:?} ({faces} triangles)", o.mesh),
                rule: format!("must have at most {MAX_MESH_FACES} triangles"),
            });
        }
        let mut referring = vec![o.mesh.as_str()];
        referring.extend(o.files.iter().map(String::as_str).filter(|f| f.to_ascii_lowercase().ends_with(".mtl")));
        for from in referring {
            let Some(bytes) = content(from) else { continue };
            for reference in asset::references(from, bytes) {
                let listed = asset::resolve_reference(from, &reference).filter(|p| o.files.contains(p));
                if listed.is_none() {
                    errors.push(SpecError {
                        path: format!("object.{name}.files"),
                        value: format!("{:?}", o.files),
                        rule: format!(
                            "must list every file the mesh refers to: {from} names {reference:?} (a path relative to \
                             {from}, within the spec's directory)"
                        ),
                    });
                }
            }
        }
    }
    if errors.is_empty() { Ok(()) } else { Err(SpecErrors(errors)) }
}

/// Each user hand's `files` are exactly the mesh files its MJCF refers to, found as MuJoCo finds
/// them (`mjcf::mjcf_files`), so its grasp tasks get all of them and nothing else; an MJCF that
/// includes other files, or names a file outside the spec's directory, is refused here too.
pub fn check_hand_files(spec: &DatasetSpec, files: &[pb::AssetFile]) -> Result<(), SpecErrors> {
    let mut errors = Vec::new();
    for name in &spec.hands {
        let Some(h) = spec.hand_defs.get(name) else { continue };
        let Some(xml) = files.iter().find(|f| f.path == h.mjcf) else { continue };
        let found = mjcf::mjcf_files(&h.mjcf, &String::from_utf8_lossy(&xml.content));
        let error =
            |field: &str, value: String, rule: String| SpecError { path: format!("hand.{name}.{field}"), value, rule };
        for refused in found.refused {
            errors.push(error("mjcf", format!("{:?}", h.mjcf), format!("must follow docs/hands.md: it {refused}")));
        }
        let missing: Vec<&String> = found.meshes.iter().filter(|p| !h.files.contains(p)).collect();
        if !missing.is_empty() {
            errors.push(error(
                "files",
                format!("{:?}", h.files),
                format!(
                    "must list every mesh file {} refers to (relative to the spec file); missing {missing:?}",
                    h.mjcf
                ),
            ));
        }
        let unused: Vec<&String> = h.files.iter().filter(|p| !found.meshes.contains(p)).collect();
        if !unused.is_empty() {
            errors.push(error(
                "files",
                format!("{:?}", h.files),
                format!("must list only mesh files {} refers to; it names none of {unused:?}", h.mjcf),
            ));
        }
    }
    if errors.is_empty() { Ok(()) } else { Err(SpecErrors(errors)) }
}

pub fn read_spec(path: &Path) -> Result<String, Failure> {
    std::fs::read_to_string(path).with_context(|| format!("reading spec {}", path.display())).map_err(bad_input)
}
