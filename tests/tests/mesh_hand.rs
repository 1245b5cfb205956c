//! A user's hand built from mesh files, as real hand models are (MuJoCo Menagerie's, robosuite's),
//! through `vintctl` as a user runs it: the spec lists the meshes its MJCF refers to (through
//! `meshdir`), they travel with the job, its grasp tasks stage them, and the hand grasps, feels and
//! is rendered in the colours of its visual meshes. The fixture is generated here.

use std::path::Path;

use vint_tests::*;

/// Triangles of an axis-aligned box from `low` to `high`, outward-wound.
fn box_triangles(low: [f64; 3], high: [f64; 3]) -> Vec<[[f64; 3]; 3]> {
    let corner = |i: usize| {
        [
            if i & 4 != 0 { high[0] } else { low[0] },
            if i & 2 != 0 { high[1] } else { low[1] },
            if i & 1 != 0 { high[2] } else { low[2] },
        ]
    };
    let quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]];
    quads
        .iter()
        .flat_map(|q| [[corner(q[0]), corner(q[1]), corner(q[2])], [corner(q[0]), corner(q[2]), corner(q[3])]])
        .collect()
}

fn write_obj(path: &Path, triangles: &[[[f64; 3]; 3]]) {
    let mut text = String::new();
    for t in triangles {
        for v in t {
            text += &format!("v {} {} {}\n", v[0], v[1], v[2]);
        }
    }
    for i in 0..triangles.len() {
        text += &format!("f {} {} {}\n", 3 * i + 1, 3 * i + 2, 3 * i + 3);
    }
    std::fs::write(path, text).unwrap();
}

fn write_stl(path: &Path, triangles: &[[[f64; 3]; 3]]) {
    let mut bytes = vec![b' '; 80];
    bytes.extend((triangles.len() as u32).to_le_bytes());
    for t in triangles {
        bytes.extend([0f32; 3].iter().flat_map(|v| v.to_le_bytes()));
        bytes.extend(t.iter().flatten().flat_map(|&v| (v as f32).to_le_bytes()));
        bytes.extend([0u8, 0]);
    }
    std::fs::write(path, bytes).unwrap();
}

const MJCF: &str = r#"<mujoco model="meshy">
  <compiler angle="radian" meshdir="meshes"/>
  <default>
    <joint type="hinge" axis="0 1 0" limited="true" armature="0.002" damping="0.08"/>
    <position kp="6" forcelimited="true"/>
    <default class="visual"><geom type="mesh" contype="0" conaffinity="0" group="2" density="0"/></default>
  </default>
  <asset>
    <material name="red" rgba="0.8 0.1 0.1 1"/>
    <mesh name="palm" file="palm.stl"/>
    <mesh name="link" file="link.obj"/>
    <mesh name="shell" file="visual/shell.obj"/>
  </asset>
  <custom>
    <numeric name="vint_open" data="-0.25 0.1 -0.25 0.1"/>
    <numeric name="vint_closed" data="1.5 1.7 1.5 1.7"/>
  </custom>
  <worldbody>
    <body name="palm">
      <geom type="mesh" mesh="palm" mass="0.25"/>
      FINGERS
    </body>
  </worldbody>
  <actuator>
    <position joint="left_j0" ctrlrange="-0.5 1.6" forcerange="-1.2 1.2"/>
    <position joint="left_j1" ctrlrange="0 1.9" forcerange="-0.8 0.8"/>
    <position joint="right_j0" ctrlrange="-0.5 1.6" forcerange="-1.2 1.2"/>
    <position joint="right_j1" ctrlrange="0 1.9" forcerange="-0.8 0.8"/>
  </actuator>
</mujoco>
"#;

/// The spec's directory: a two-finger hand of box meshes (colliding) in red shells (visual), its
/// taxels on the boxes' palmar faces.
fn write_mesh_hand(dir: &Path, files: &str) -> std::path::PathBuf {
    let meshes = dir.join("hand/meshes");
    std::fs::create_dir_all(meshes.join("visual")).unwrap();
    write_stl(&meshes.join("palm.stl"), &box_triangles([-0.05, -0.03, -0.012], [0.05, 0.03, 0.012]));
    write_obj(&meshes.join("link.obj"), &box_triangles([-0.009, -0.009, 0.0], [0.009, 0.009, 0.05]));
    write_obj(&meshes.join("visual/shell.obj"), &box_triangles([-0.011, -0.011, 0.0], [0.011, 0.011, 0.05]));
    let finger = |side: &str, x: f64, turn: &str| {
        format!(
            r#"<body name="{side}_prox" pos="{x} 0 0.012"{turn}>
        <joint name="{side}_j0" range="-0.5 1.6"/>
        <geom type="mesh" mesh="link" mass="0.045"/><geom class="visual" mesh="shell" material="red"/>
        <body name="{side}_tip" pos="0 0 0.05">
          <joint name="{side}_j1" range="0 1.9"/>
          <geom type="mesh" mesh="link" mass="0.033"/><geom class="visual" mesh="shell" material="red"/>
        </body>
      </body>"#
        )
    };
    let fingers = finger("left", -0.04, "") + &finger("right", 0.04, r#" quat="0 0 0 1""#);
    std::fs::write(dir.join("hand/meshy.xml"), MJCF.replace("FINGERS", &fingers)).unwrap();
    let mut taxels = String::from("taxel,link,x,y,z,nx,ny,nz,region\n");
    let mut n = 0;
    for i in 0..25 {
        for j in 0..15 {
            let (x, y) = (-0.048 + 0.004 * f64::from(i), -0.028 + 0.004 * f64::from(j));
            taxels += &format!("{n},palm,{x:.6},{y:.6},0.012,0,0,1,palm\n");
            n += 1;
        }
    }
    for link in ["left_prox", "left_tip", "right_prox", "right_tip"] {
        let region = if link.ends_with("tip") { "tip" } else { "pulp" };
        for i in 0..9 {
            for j in 0..25 {
                let (y, z) = (-0.008 + 0.002 * f64::from(i), 0.001 + 0.002 * f64::from(j));
                taxels += &format!("{n},{link},0.009,{y:.6},{z:.6},1,0,0,{region}\n");
                n += 1;
            }
        }
    }
    std::fs::write(dir.join("hand/meshy_taxels.csv"), taxels).unwrap();
    let spec = format!(
        "hands = [\"meshy\"]\nobjects = [\"tomato_soup_can\"]\n\
         [hand.meshy]\nmjcf = \"hand/meshy.xml\"\ntaxels = \"hand/meshy_taxels.csv\"\nfiles = {files}\n\
         [dataset]\nname = \"meshy\"\nseed = 5\n\
         [grasp]\ntrials_per_pair = 6\nchunk_size = 6\nhold_s = 0.3\n\
         [render]\nresolution = [48, 48]\nsamples = 4\nviews_per_environment = 1\nenvironments = [\"studio\"]\n\
         [outputs]\nmodalities = [\"rgb\", \"depth\", \"segmentation\", \"pose\"]\n"
    );
    let path = dir.join("spec.toml");
    std::fs::write(&path, spec).unwrap();
    path
}

/// A single-channel 8-bit PNG's pixels.
fn png_u8(path: &Path) -> Vec<u8> {
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    buf.truncate(info.buffer_size());
    buf
}

const FILES: &str = r#"["hand/meshes/palm.stl", "hand/meshes/link.obj", "hand/meshes/visual/shell.obj"]"#;

#[test]
fn a_hand_of_mesh_files_grasps_feels_and_is_rendered_end_to_end() {
    let tmp = tempfile::tempdir().unwrap();
    let spec = write_mesh_hand(tmp.path(), FILES);
    let (out, state) = (tmp.path().join("out"), tmp.path().join("state"));
    let o =
        vintctl(&["run", spec.to_str().unwrap(), "--out", out.to_str().unwrap(), "--state", state.to_str().unwrap()]);
    assert!(o.status.success(), "vintctl run failed:\n{}\n{}", stdout(&o), stderr(&o));
    let lines = verify_dataset(&out);
    assert!(!lines.is_empty(), "no accepted grasp");
    for line in &lines {
        let sample = line["sample_id"].as_str().unwrap();
        let record = grasp_record(&out, sample);
        assert!(record["touch"]["active_count"].as_u64().unwrap() >= 3, "{sample}: no touch");
        // The record describes the hand as rendered: each link's meshes, the visual ones red.
        let hand = &record["hand"];
        assert_eq!(hand["meshes"].as_object().unwrap().len(), 3, "{sample}: palm, link and shell, each once");
        let tip = hand["links"].as_array().unwrap().iter().find(|l| l["name"] == "left_tip").unwrap();
        let visual: Vec<&serde_json::Value> =
            tip["geoms"].as_array().unwrap().iter().filter(|g| g["visual"] == true).collect();
        assert_eq!(visual.len(), 1, "{sample}: {tip}");
        assert_eq!(visual[0]["type"], "mesh");
        assert_eq!(visual[0]["rgba"][0].as_f64().map(|r| (r * 10.0).round()), Some(8.0), "{sample}: {tip}");
        let seg = png_u8(&out.join(sample).join("segmentation.png"));
        assert!(seg.iter().any(|&v| v >= 2), "{sample}: no hand pixel");
    }
}

#[test]
fn a_hands_mesh_files_must_be_listed_and_stay_in_the_spec_directory() {
    let tmp = tempfile::tempdir().unwrap();
    let spec = write_mesh_hand(tmp.path(), r#"["hand/meshes/palm.stl"]"#);
    let v = vintctl(&["validate", spec.to_str().unwrap()]);
    assert_eq!(v.status.code(), Some(2), "{}", stderr(&v));
    assert!(
        stderr(&v).contains(
            "hand.meshy.files: must list every mesh file hand/meshy.xml refers to (relative to the spec file); \
             missing [\"hand/meshes/link.obj\", \"hand/meshes/visual/shell.obj\"]"
        ),
        "{}",
        stderr(&v)
    );
    let xml = tmp.path().join("hand/meshy.xml");
    let text = std::fs::read_to_string(&xml).unwrap();
    std::fs::write(&xml, text.replace("meshdir=\"meshes\"", "meshdir=\"../../meshes\"")).unwrap();
    let v = vintctl(&["validate", spec.to_str().unwrap()]);
    assert_eq!(v.status.code(), Some(2), "{}", stderr(&v));
    assert!(stderr(&v).contains("which leaves the spec's directory"), "{}", stderr(&v));
}
