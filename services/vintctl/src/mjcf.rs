//! The files a user's hand MJCF refers to, found as MuJoCo finds them: each `<mesh file=…>` joined
//! to the compiler's `meshdir` (or `assetdir`), its name alone under `strippath`, relative to the
//! MJCF's directory. The grasp engine resolves them by the same rule and refuses the same
//! references (`vint_engines/grasp/hands/mjcf_files.py`: `mesh_file_path`, `check_references`);
//! vintctl uses it to check that a spec's `[hand.NAME] files` lists every one, and that the MJCF
//! names no file a hand may not, before anything is submitted. Reads text only, no files.

use quick_xml::events::{BytesStart, Event};

/// What an MJCF document refers to: the spec paths of its mesh files, and what it refers to that a
/// hand may not (a DOCTYPE, an `<include>`, a `<model>` to `<attach>`, any file but a mesh's or a
/// texture's) or that leaves the spec's directory (a texture, a compiler directory), each said as
/// a sentence.
#[derive(Debug, Default, PartialEq, Eq)]
pub struct MjcfFiles {
    pub meshes: Vec<String>,
    pub refused: Vec<String>,
}

/// The files the MJCF at spec path `mjcf_path` with text `xml` refers to (see `MjcfFiles`). A
/// document that is not XML is left to the engine's own check (it reports MuJoCo's message).
pub fn mjcf_files(mjcf_path: &str, xml: &str) -> MjcfFiles {
    let mut reader = quick_xml::Reader::from_str(xml);
    let (mut meshdir, mut assetdir, mut texturedir, mut strippath) = (None::<String>, None, None, false);
    let mut files: Vec<(String, String)> = Vec::new(); // (mesh name or file, file)
    let mut textures: Vec<(String, String)> = Vec::new(); // (attribute, file)
    let mut out = MjcfFiles::default();
    let mut in_asset = 0usize;
    loop {
        let (element, is_start) = match reader.read_event() {
            Ok(Event::Start(e)) => (e, true),
            Ok(Event::Empty(e)) => (e, false),
            Ok(Event::End(e)) => {
                if e.name().as_ref() == b"asset" {
                    in_asset = in_asset.saturating_sub(1);
                }
                continue;
            }
            Ok(Event::DocType(_)) => {
                out.refused.push(
                    "declares a DOCTYPE: a hand's MJCF may declare no DOCTYPE or entities (they could expand \
                     without bound)"
                        .to_string(),
                );
                continue;
            }
            Ok(Event::Eof) | Err(_) => break,
            Ok(_) => continue,
        };
        let attr = |key: &str| attribute(&element, key);
        let tag = String::from_utf8_lossy(element.name().as_ref()).into_owned();
        match tag.as_str() {
            "asset" if is_start => in_asset += 1,
            "compiler" => {
                for (key, dir) in
                    [("meshdir", &mut meshdir), ("assetdir", &mut assetdir), ("texturedir", &mut texturedir)]
                {
                    if let Some(value) = attr(key) {
                        if mesh_file_path(mjcf_path, &value, "x", false).is_none() {
                            out.refused.push(format!("<compiler {key}={value:?}> leaves the spec's directory"));
                        }
                        *dir = Some(value);
                    }
                }
                strippath = attr("strippath").map(|v| v == "true").unwrap_or(strippath);
            }
            "include" => out.refused.push(format!(
                "includes {:?}: a hand is one MJCF file (paste the included file in)",
                attr("file").unwrap_or_default()
            )),
            "attach" => out.refused.push(format!(
                "attaches the model {:?}: a hand is one MJCF file (models to <attach> are not supported)",
                attr("model").unwrap_or_default()
            )),
            _ => {}
        }
        for (key, value) in file_attributes(&element) {
            match tag.as_str() {
                "mesh" => {
                    if in_asset > 0 && key == "file" {
                        files.push((attr("name").unwrap_or_else(|| value.clone()), value));
                    }
                }
                "texture" => textures.push((key, value)),
                "include" => {} // refused above
                _ => out.refused.push(format!(
                    "<{tag} {key}={value:?}> names a file: a hand's files are its MJCF and its meshes' files"
                )),
            }
        }
    }
    let texture_dir = texturedir.or_else(|| assetdir.clone()).unwrap_or_default();
    for (key, file) in textures {
        if mesh_file_path(mjcf_path, &texture_dir, &file, strippath).is_none() {
            out.refused
                .push(format!("<texture {key}={file:?}> (texturedir {texture_dir:?}) leaves the spec's directory"));
        }
    }
    let dir = meshdir.or(assetdir).unwrap_or_default();
    for (name, file) in files {
        match mesh_file_path(mjcf_path, &dir, &file, strippath) {
            Some(path) if !out.meshes.contains(&path) => out.meshes.push(path),
            Some(_) => {}
            None => out
                .refused
                .push(format!("mesh {name:?} names {file:?} (meshdir {dir:?}), which leaves the spec's directory")),
        }
    }
    out
}

/// The element's attributes whose names start with `file` (`file`, a cube texture's `fileright`…).
fn file_attributes(element: &BytesStart<'_>) -> Vec<(String, String)> {
    element
        .attributes()
        .flatten()
        .filter(|a| a.key.as_ref().starts_with(b"file"))
        .filter_map(|a| {
            let value = a.normalized_value(quick_xml::XmlVersion::default()).ok()?.into_owned();
            Some((String::from_utf8_lossy(a.key.as_ref()).into_owned(), value))
        })
        .collect()
}

fn attribute(element: &BytesStart<'_>, key: &str) -> Option<String> {
    let found = element.try_get_attribute(key).ok().flatten()?;
    found.normalized_value(quick_xml::XmlVersion::default()).ok().map(|v| v.into_owned())
}

/// The spec path of a mesh file named `file` in the MJCF at `mjcf_path` under `meshdir`, or
/// `None` when it is absolute or climbs above the spec's directory.
pub fn mesh_file_path(mjcf_path: &str, meshdir: &str, file: &str, strippath: bool) -> Option<String> {
    let file = file.replace('\\', "/");
    let file = if strippath { file.rsplit('/').next().unwrap_or(&file).to_string() } else { file };
    let meshdir = meshdir.replace('\\', "/");
    if [&file, &meshdir].iter().any(|p| p.starts_with('/') || p.contains(':')) {
        return None;
    }
    let reference = if meshdir.is_empty() { file } else { format!("{meshdir}/{file}") };
    vint_core::asset::resolve_reference(mjcf_path, &reference)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mesh_files_follow_meshdir_assetdir_and_strippath() {
        let xml = r#"<mujoco><!-- <mesh file="commented.stl"/> -->
            <compiler angle="radian" meshdir="meshes"/>
            <default><mesh scale="0.001 0.001 0.001"/></default>
            <asset>
              <texture name="t" type="2d" file="textures/grain.png"/>
              <mesh name="palm" file="palm.stl"/><mesh file="visual/link.obj"/>
              <mesh name="again" file="./palm.stl"/><mesh name="inline" vertex="0 0 0 1 0 0 0 1 0 0 0 1"/>
            </asset></mujoco>"#;
        let found = mjcf_files("assets/hand.xml", xml);
        assert_eq!(found.meshes, ["assets/meshes/palm.stl", "assets/meshes/visual/link.obj"]);
        assert!(found.refused.is_empty());
        let assetdir = r#"<mujoco><compiler assetdir="../shared" strippath="true"/>
            <asset><mesh file="deep/a.STL"/></asset></mujoco>"#;
        assert_eq!(mjcf_files("assets/hand.xml", assetdir).meshes, ["shared/a.STL"]);
    }

    #[test]
    fn paths_that_leave_the_spec_directory_and_includes_are_refused() {
        let xml = r#"<mujoco><compiler meshdir="../../x"/><include file="arm.xml"/>
            <asset><mesh name="m" file="a.stl"/><hfield name="h" file="h.png"/></asset></mujoco>"#;
        let found = mjcf_files("assets/hand.xml", xml);
        assert!(found.meshes.is_empty());
        assert_eq!(found.refused.len(), 4, "{:?}", found.refused);
        assert!(found.refused[0].contains("<compiler meshdir=\"../../x\"> leaves the spec's directory"));
        assert!(found.refused[2].contains("<hfield file=\"h.png\"> names a file"), "{:?}", found.refused);
        assert!(found.refused[1].starts_with("includes \"arm.xml\""), "{:?}", found.refused);
        assert!(found.refused[3].contains("mesh \"m\" names \"a.stl\""), "{:?}", found.refused);
        assert_eq!(mesh_file_path("hand.xml", "", "/etc/a.stl", false), None);
        assert_eq!(mesh_file_path("hand.xml", "C:/m", "a.stl", false), None);
        assert_eq!(mesh_file_path("a/hand.xml", "", "a\\b.stl", false).as_deref(), Some("a/a/b.stl"));
    }

    /// What the grasp engine refuses (`mjcf_files.py`, `check_references`), the client refuses
    /// before it submits: each line of this document is one refusal.
    #[test]
    fn every_reference_the_engine_refuses_is_refused_here_too() {
        let xml = r#"<!DOCTYPE mujoco [<!ENTITY a "aaaa">]>
            <mujoco><compiler texturedir="../../t"/>
            <include file="/abs/arm.xml"/>
            <attach model="arm" body="b"/>
            <asset><model name="arm" file="arm.xml"/>
              <skin file="s.skn"/><flexcomp name="f" file="f.obj"/>
              <texture name="c" type="cube" fileright="r.png"/>
              <mesh name="ok" file="ok.stl"/>
            </asset></mujoco>"#;
        let found = mjcf_files("assets/hand.xml", xml);
        assert_eq!(found.meshes, ["assets/ok.stl"]);
        let refused = found.refused.join("\n");
        for says in [
            "DOCTYPE",
            "<compiler texturedir=\"../../t\">",
            "includes \"/abs/arm.xml\"",
            "attaches the model \"arm\"",
            "<model file=\"arm.xml\">",
            "<skin file=\"s.skn\">",
            "<flexcomp file=\"f.obj\">",
            "<texture fileright=\"r.png\">",
        ] {
            assert!(refused.contains(says), "{says:?} not refused in:\n{refused}");
        }
        assert_eq!(found.refused.len(), 8, "{refused}");
        let inside = r#"<mujoco><compiler texturedir="tex"/><asset><texture file="grain.png"/></asset></mujoco>"#;
        assert!(mjcf_files("assets/hand.xml", inside).refused.is_empty());
    }

    #[test]
    fn a_hands_files_must_be_exactly_the_meshes_its_mjcf_names() {
        use vint_core::DatasetSpec;
        use vint_proto::v1 as pb;
        let spec = |files: &str| {
            DatasetSpec::parse(&format!(
                "hands = [\"grip\"]\nobjects = [\"tomato_soup_can\"]\n[dataset]\nname = \"t\"\nseed = 1\n\
                 [hand.grip]\nmjcf = \"a/grip.xml\"\ntaxels = \"a/grip.csv\"\nfiles = [{files}]\n"
            ))
            .unwrap()
        };
        let xml = r#"<mujoco><compiler meshdir="meshes"/><asset><mesh file="palm.stl"/></asset></mujoco>"#;
        let files = [pb::AssetFile { path: "a/grip.xml".into(), content: xml.as_bytes().to_vec() }];
        let check = |listed: &str| crate::spec_file::check_hand_files(&spec(listed), &files);
        assert!(check("\"a/meshes/palm.stl\"").is_ok());
        let missing = check("").unwrap_err().0;
        assert_eq!(missing[0].path, "hand.grip.files");
        assert!(missing[0].rule.contains("missing [\"a/meshes/palm.stl\"]"), "{}", missing[0].rule);
        let extra = check("\"a/meshes/palm.stl\", \"a/other.stl\"").unwrap_err().0;
        assert!(extra[0].rule.contains("names none of [\"a/other.stl\"]"), "{}", extra[0].rule);
    }
}
