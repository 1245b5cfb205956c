"""A user's MJCF hand built from mesh files, as real hand models are (MuJoCo Menagerie's, robosuite's):
visual meshes drawn but never felt, colliding meshes felt through MuJoCo's convex hulls, the mesh
files found through `meshdir` and staged with the MJCF, a texture dropped, a supplied taxel layout.
It grasps a catalog object with touch, and its rendered segmentation matches an independent
projection of its visual meshes, read from the files the test wrote, at the recorded link poses."""

from __future__ import annotations

import hashlib
import json
import math
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from conftest import EngineProcess, new_dir, started_engine
from geometry import quat_multiply, rasterise_depth

from vint_engines import hand_meshes
from vint_engines.grasp.engine import GraspEngine
from vint_engines.grasp.hands import load_mjcf_hand
from vint_engines.grasp.hands.mjcf import mesh_file_path
from vint_engines.grasp.skin import generate_layout
from vint_engines.objects import load_catalog
from vint_engines.objects.meshio import read_ply_m
from vint_engines.poses import matrix_to_quat, quat_to_matrix
from vint_engines.protocol import BadInput, InputRef, TaskRequest

Mesh = tuple[np.ndarray, np.ndarray]  # vertices (m), outward-wound triangles

# The two-finger layout of examples/assets/gripper.xml, its links made of meshes: colliding boxes
# (STL and OBJ, not centred on their frame, as exported parts rarely are) and visual hexagonal
# prisms turned 30° about the link axis, in a colour per finger.
PALM_HALF = (0.05, 0.03, 0.012)
FINGER_HALF = 0.009
LENGTHS = {"prox": 0.05, "tip": 0.05}
VISUAL_RADIUS = 0.013
VISUAL_TURN = math.radians(30.0)
COLOURS = {"left": (0.8, 0.1, 0.1, 1.0), "right": (0.1, 0.2, 0.8, 1.0)}

HAND_XML = """<mujoco model="mesh_hand">
  <compiler angle="radian" meshdir="meshes"/>
  <default>
    <joint type="hinge" axis="0 1 0" limited="true" armature="0.002" damping="0.08"/>
    <position kp="6" forcelimited="true"/>
    <default class="visual"><geom type="mesh" contype="0" conaffinity="0" group="2" density="0"/></default>
    <default class="collision"><geom type="mesh" group="3"/></default>
  </default>
  <asset>
    <texture name="grain" type="2d" file="textures/grain.png"/>
    <material name="housing" rgba="0.6 0.6 0.55 1" texture="grain"/>
    <material name="left" rgba="LEFT_RGBA"/>
    <material name="right" rgba="RIGHT_RGBA"/>
    <mesh name="palm_collision" file="palm.stl"/>
    <mesh name="palm_visual" file="visual/palm.obj"/>
    <mesh name="prox_collision" file="prox.stl"/>
    <mesh name="tip_collision" file="tip.obj"/>
    <mesh name="link_visual" file="visual/link.obj"/>
  </asset>
  <custom>
    <numeric name="vint_open" data="-0.25 0.1 -0.25 0.1"/>
    <numeric name="vint_closed" data="1.5 1.7 1.5 1.7"/>
  </custom>
  <worldbody>
    <body name="palm">
      <geom class="collision" mesh="palm_collision" mass="0.25"/>
      <geom class="visual" mesh="palm_visual" material="housing"/>
      LEFT_FINGER
      RIGHT_FINGER
    </body>
  </worldbody>
  <actuator>
    <position joint="left_j0" ctrlrange="-0.5 1.6" forcerange="-1.2 1.2"/>
    <position joint="left_j1" ctrlrange="0 1.9" forcerange="-0.8 0.8"/>
    <position joint="right_j0" ctrlrange="-0.5 1.6" forcerange="-1.2 1.2"/>
    <position joint="right_j1" ctrlrange="0 1.9" forcerange="-0.8 0.8"/>
  </actuator>
</mujoco>
"""

FINGER_XML = """<body name="{side}_prox" pos="{x} 0 0.012"{turn}>
        <joint name="{side}_j0" range="-0.5 1.6"/>
        <geom class="collision" mesh="prox_collision" mass="0.045"/>
        <geom class="visual" mesh="link_visual" material="{side}" euler="0 0 {visual_turn}"/>
        <body name="{side}_tip" pos="0 0 0.05">
          <joint name="{side}_j1" range="0 1.9"/>
          <geom class="collision" mesh="tip_collision" mass="0.033"/>
          <geom class="visual" mesh="link_visual" material="{side}" euler="0 0 {visual_turn}"/>
        </body>
      </body>"""

# Each visual geom as the file places it: link → (mesh file, pose in the link frame).
VISUAL = {
    "palm": ("visual/palm.obj", 0.0),
    **{f"{side}_{part}": ("visual/link.obj", VISUAL_TURN) for side in COLOURS for part in LENGTHS},
}
RENDER = {
    "width": 96,
    "height": 96,
    "samples": 4,
    "fov_deg": 60.0,
    "environment": "studio",
    "radius_m": [0.22, 0.26],
    "elevation_deg": [20.0, 70.0],
    "sensor": {"enabled": False},
    "scene": {"flange": False, "table": False, "table_gap_m": 0.05},
}


def box(low: tuple[float, float, float], high: tuple[float, float, float]) -> Mesh:
    corners = np.array(
        [[x, y, z] for x in (low[0], high[0]) for y in (low[1], high[1]) for z in (low[2], high[2])]
    )
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return corners, np.array([t for q in quads for t in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))])


def prism(radius: float, z0: float, z1: float, sides: int = 6) -> Mesh:
    """A regular prism about +z from z0 to z1, outward-wound."""
    angles = 2 * np.pi * np.arange(sides) / sides
    ring = np.stack([radius * np.cos(angles), radius * np.sin(angles)], axis=1)
    vertices = np.vstack(
        [np.column_stack([ring, np.full(sides, z)]) for z in (z0, z1)] + [[[0, 0, z0]], [[0, 0, z1]]]
    )
    faces = []
    for i in range(sides):
        j = (i + 1) % sides
        faces += [(i, j, sides + j), (i, sides + j, sides + i)]
        faces += [(2 * sides, j, i), (2 * sides + 1, sides + i, sides + j)]
    return vertices, np.array(faces)


def write_stl(path: Path, mesh: Mesh) -> None:
    vertices, faces = mesh
    out = bytearray(b"vint test mesh".ljust(80, b" ") + struct.pack("<I", len(faces)))
    for face in faces:
        a, b, c = vertices[face]
        n = np.cross(b - a, c - a)
        out += struct.pack("<12fH", *(n / np.linalg.norm(n)), *a, *b, *c, 0)
    path.write_bytes(bytes(out))


def write_obj(path: Path, mesh: Mesh) -> None:
    vertices, faces = mesh
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices] + [
        f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces
    ]
    path.write_text("\n".join(lines) + "\n")


def visual_mesh(name: str) -> Mesh:
    if name == "palm":  # a housing deeper than the colliding palm plate
        return box((-PALM_HALF[0], -PALM_HALF[1], -0.03), PALM_HALF)
    return prism(VISUAL_RADIUS, 0.0, 0.05)


def taxel_rows() -> list[str]:
    """Taxels on the colliding boxes' palmar faces: the palm's +z face, the links' +x face."""
    rows = []
    for x in np.arange(-0.048, 0.0481, 0.004):
        for y in np.arange(-0.028, 0.0281, 0.004):
            rows.append(("palm", (x, y, PALM_HALF[2]), (0, 0, 1), "palm"))
    for side in COLOURS:
        for part in LENGTHS:
            region = "tip" if part == "tip" else "pulp"
            for y in np.arange(-0.008, 0.0081, 0.002):
                for z in np.arange(0.001, 0.0491, 0.002):
                    rows.append((f"{side}_{part}", (FINGER_HALF, y, z), (1, 0, 0), region))
    lines = ["taxel,link,x,y,z,nx,ny,nz,region"]
    for i, (link, p, n, region) in enumerate(rows):
        lines.append(f"{i},{link},{p[0]:.6f},{p[1]:.6f},{p[2]:.6f},{n[0]},{n[1]},{n[2]},{region}")
    return lines


def write_hand(root: Path) -> dict[str, Path]:
    """The hand's files under `root` as a spec's directory holds them; their spec paths."""
    meshes = root / "assets" / "meshes"
    (meshes / "visual").mkdir(parents=True)
    write_stl(meshes / "palm.stl", box(tuple(-h for h in PALM_HALF), PALM_HALF))  # type: ignore[arg-type]
    write_obj(meshes / "visual" / "palm.obj", visual_mesh("palm"))
    write_stl(meshes / "prox.stl", box((-FINGER_HALF, -FINGER_HALF, 0.0), (FINGER_HALF, FINGER_HALF, 0.05)))
    write_obj(meshes / "tip.obj", box((-FINGER_HALF, -FINGER_HALF, 0.0), (FINGER_HALF, FINGER_HALF, 0.05)))
    write_obj(meshes / "visual" / "link.obj", visual_mesh("link"))
    fingers = {
        side: FINGER_XML.format(side=side, x=x, turn=turn, visual_turn=VISUAL_TURN)
        for side, x, turn in (("left", -0.04, ""), ("right", 0.04, ' quat="0 0 0 1"'))
    }
    rgba = {side: " ".join(str(v) for v in colour) for side, colour in COLOURS.items()}
    xml = HAND_XML
    for side in COLOURS:
        xml = xml.replace(f"{side.upper()}_FINGER", fingers[side]).replace(f"{side.upper()}_RGBA", rgba[side])
    (root / "assets" / "hand.xml").write_text(xml)
    (root / "assets" / "hand_taxels.csv").write_text("\n".join(taxel_rows()) + "\n")
    files = [root / "assets" / "hand.xml", root / "assets" / "hand_taxels.csv", *sorted(meshes.rglob("*.*"))]
    return {path.relative_to(root).as_posix(): path for path in files}


def staged(files: dict[str, Path]) -> tuple[list[dict[str, Any]], tuple[InputRef, ...], dict[str, str]]:
    sha = {p: hashlib.sha256(path.read_bytes()).hexdigest() for p, path in files.items()}
    assets = [{"path": p, "sha256": sha[p], "size": files[p].stat().st_size} for p in files]
    return assets, tuple(InputRef(sha[p], "asset", path) for p, path in files.items()), sha


def test_mesh_paths_follow_meshdir_and_never_leave_the_spec_directory() -> None:
    assert mesh_file_path("assets/hand.xml", "meshes", "visual/link.obj") == "assets/meshes/visual/link.obj"
    assert mesh_file_path("assets/hand.xml", "../shared", "palm.stl") == "shared/palm.stl"
    assert mesh_file_path("assets/hand.xml", "", "a\\b.STL") == "assets/a/b.STL"
    assert mesh_file_path("assets/hand.xml", "meshes", "deep/x.stl", strippath=True) == "assets/meshes/x.stl"
    assert mesh_file_path("assets/hand.xml", "../..", "x.stl") is None
    assert mesh_file_path("assets/hand.xml", "", "/etc/x.stl") is None
    assert mesh_file_path("hand.xml", "C:/meshes", "x.stl") is None


def test_a_mesh_hand_loads_with_its_staged_files_and_says_what_is_missing(tmp_path: Path) -> None:
    files = write_hand(tmp_path)
    xml = files["assets/hand.xml"].read_text()
    hand = load_mjcf_hand("mesh_hand", xml, "params.hand.mjcf", "assets/hand.xml", files)
    assert hand.link_names() == ["palm", "left_prox", "left_tip", "right_prox", "right_tip"]
    assert len(hand.visual_geoms()) == 5
    assert hand.palm_half == pytest.approx(PALM_HALF)
    assert hand.mesh_files == tuple(sorted(p for p in files if "/meshes/" in p))
    without = {p: f for p, f in files.items() if not p.endswith("tip.obj")}
    with pytest.raises(
        BadInput, match=r"mesh 'tip_collision' names 'assets/meshes/tip.obj', which the task did not"
    ):
        load_mjcf_hand("mesh_hand", xml, "params.hand.mjcf", "assets/hand.xml", without)
    escaping = xml.replace('meshdir="meshes"', 'meshdir="../../elsewhere"')
    with pytest.raises(BadInput, match="leaves the spec's directory"):
        load_mjcf_hand("mesh_hand", escaping, "params.hand.mjcf", "assets/hand.xml", files)


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("mesh_hand")


@pytest.fixture(scope="module")
def grasp(workdir: Path) -> dict[str, Any]:
    """Accepted grasps of the tomato soup can by the mesh hand, from the real grasp engine."""
    files = write_hand(workdir / "spec")
    assets, inputs, sha = staged(files)
    params = {
        "assets": assets,
        "hand": {
            "name": "mesh_hand",
            "mjcf": sha["assets/hand.xml"],
            "taxels": sha["assets/hand_taxels.csv"],
        },
        "object": load_catalog()["tomato_soup_can"].to_json(),
        "trials": [{"grasp_index": i, "seed": 700 + i} for i in range(6)],
        "physics": {"hold_s": 0.3},
    }
    out = new_dir(workdir, "grasp")
    GraspEngine().run(TaskRequest("grasp", params, inputs, out))
    doc = json.loads((out / "grasps.json").read_text())
    accepted = [t for t in doc["trials"] if t["accepted"]]
    assert accepted, [t["reason"] for t in doc["trials"]]
    trial = max(accepted, key=lambda t: t["touch"]["active_count"])
    return {"dir": out, "doc": doc, "trial": trial, "files": files}


def test_the_mesh_hand_grasps_with_touch_and_records_its_meshes(grasp: dict[str, Any]) -> None:
    doc, trial = grasp["doc"], grasp["trial"]
    assert trial["touch"]["active_count"] > 0, "the colliding meshes' contacts reach the taxels"
    links = {link["name"]: link["geoms"] for link in doc["hand"]["links"]}
    assert list(links) == ["palm", "left_prox", "left_tip", "right_prox", "right_tip"]
    for name, geoms in links.items():
        kinds = sorted((g["type"], bool(g.get("visual"))) for g in geoms)
        assert kinds == [("mesh", False), ("mesh", True)], name
        visual = next(g for g in geoms if g.get("visual"))
        if name != "palm":
            assert visual["rgba"] == pytest.approx(COLOURS[name.split("_")[0]])
        vertices, faces = hand_meshes.decode(doc["hand"]["meshes"][visual["mesh"]])
        assert len(faces) == len(visual_mesh(name)[1])
        # MuJoCo moves a mesh into its inertial frame: the file's vertices up to a rigid motion,
        # within float32 (their distances from their mean do not change).
        spread = lambda v: np.sort(np.linalg.norm(v - v.mean(axis=0), axis=1))  # noqa: E731
        assert np.abs(spread(vertices) - spread(visual_mesh(name)[0])).max() < 1e-6


def placed_visual(link: str, pose: dict[str, Any]) -> np.ndarray:
    """The link's visual mesh vertices in the world: the file's vertices, the geom's pose as the
    file writes it, the link's recorded pose."""
    vertices, _ = visual_mesh(link)
    turn = VISUAL[link][1]
    c, s = math.cos(turn), math.sin(turn)
    in_link = vertices @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T
    return in_link @ quat_to_matrix(np.array(pose["q"])).T + np.array(pose["p"])


@pytest.fixture(scope="module")
def engine(workdir: Path) -> Iterator[EngineProcess]:
    with started_engine("render", workdir) as process:
        yield process


def test_the_rendered_segmentation_matches_a_projection_of_the_visual_meshes(
    engine: EngineProcess, grasp: dict[str, Any], workdir: Path
) -> None:
    out = new_dir(workdir, "views")
    trial = grasp["trial"]
    params = {
        "grasp_index": trial["grasp_index"],
        "render": RENDER,
        "views": [{"view_index": v, "seed": 31 + v} for v in range(3)],
        "outputs": ["rgb", "depth", "mask", "segmentation"],
    }
    reply = engine.task(out.name, params, out, [grasp["dir"] / "grasps.json", grasp["dir"] / "object.ply"])
    assert reply["ok"] is True, reply
    links = [link["name"] for link in grasp["doc"]["hand"]["links"]]
    vertices, faces = read_ply_m(grasp["dir"] / "object.ply")
    object_pose = trial["object_pose"]
    object_world = vertices @ quat_to_matrix(np.array(object_pose["q"])).T + np.array(object_pose["p"])
    checked = 0
    for v in range(3):
        camera = json.loads((out / f"v{v:02d}_camera.json").read_text())
        names = {str(2 + k): f"hand/{name}" for k, name in enumerate(links)}
        assert camera["segmentation"] == {"0": "background", "1": "object", **names}
        seg = cv2.imread(str(out / f"v{v:02d}_segmentation.png"), cv2.IMREAD_UNCHANGED)
        K, R_w2c, t_w2c = (np.array(camera[k]) for k in ("K", "R_w2c", "t_w2c"))
        depths = [rasterise_depth(object_world @ R_w2c.T + t_w2c, faces, K, 96, 96)]
        for name in links:
            world = placed_visual(name, trial["link_poses"][name])
            depths.append(rasterise_depth(world @ R_w2c.T + t_w2c, visual_mesh(name)[1], K, 96, 96))
        stack = np.stack(depths)
        expected = np.where(np.isfinite(stack.min(axis=0)), 1 + np.argmin(stack, axis=0), 0).astype(np.uint8)
        # Pixels whose 3×3 neighbourhood holds one label in the projection: edges are left out.
        uniform = cv2.dilate(expected, np.ones((3, 3), np.uint8)) == cv2.erode(
            expected, np.ones((3, 3), np.uint8)
        )
        hand = uniform & (expected >= 2)
        assert hand.sum() > 30, f"view {v}: the hand is hardly in sight"
        agree = np.mean(seg[uniform] == expected[uniform])
        assert agree > 0.98, f"view {v}: {agree:.3f} of interior pixels agree"
        checked += int(hand.sum())
        rgb = cv2.imread(str(out / f"v{v:02d}_rgb.png"), cv2.IMREAD_COLOR)[..., ::-1].astype(float)
        for side, colour in COLOURS.items():
            shown = hand & np.isin(expected, [2 + links.index(f"{side}_{p}") for p in LENGTHS])
            if shown.sum() >= 10:
                mean = rgb[shown].mean(axis=0)
                assert np.argmax(mean) == int(np.argmax(colour[:3])), (side, mean)
    assert checked > 300


def test_the_layout_generator_lays_taxels_on_the_leading_faces_of_the_colliding_meshes(
    tmp_path: Path,
) -> None:
    """Judged on the boxes this file wrote, not on the hulls the generator read: the palm's +z face,
    each finger link's +x face (its joint turns about +y, so closing swings +z towards +x) and the
    fingertip's end face; 1.5 mm inside each face, evenly spread."""
    files = write_hand(tmp_path)
    hand = load_mjcf_hand(
        "mesh_hand", files["assets/hand.xml"].read_text(), "hand.xml", "assets/hand.xml", files
    )
    layout = generate_layout(hand, 240)
    assert len(layout.links) == 240
    micron, margin = 1.01e-6, 0.0015 - 1e-6
    faces_hit: set[tuple[str, str]] = set()
    for link, p, n, region in zip(
        layout.links, layout.positions, layout.normals, layout.regions, strict=True
    ):
        if link == "palm":
            assert region == "palm"
            assert abs(p[2] - PALM_HALF[2]) < micron and np.allclose(n, (0, 0, 1)), (link, p, n)
            assert abs(p[0]) <= PALM_HALF[0] - margin and abs(p[1]) <= PALM_HALF[1] - margin, p
            faces_hit.add((link, "+z"))
            continue
        part = link.split("_")[1]
        assert region == ("tip" if part == "tip" else "pulp"), (link, region)
        assert abs(p[1]) <= FINGER_HALF - margin, p
        if abs(p[0] - FINGER_HALF) < micron:  # the leading face
            assert np.allclose(n, (1, 0, 0)) and margin <= p[2] <= LENGTHS[part], (link, p, n)
            faces_hit.add((link, "+x"))
        else:  # only a fingertip's end face besides
            assert part == "tip" and abs(p[2] - LENGTHS[part]) < micron, (link, p, n)
            assert np.allclose(n, (0, 0, 1)) and abs(p[0]) <= FINGER_HALF - margin, (link, p, n)
            faces_hit.add((link, "+z"))
    expected = {("palm", "+z")} | {(f"{s}_{p}", "+x") for s in COLOURS for p in LENGTHS}
    assert faces_hit == expected | {(f"{s}_tip", "+z") for s in COLOURS}
    palm = layout.positions[[i for i, link in enumerate(layout.links) if link == "palm"]]
    gaps = np.linalg.norm(palm[:, None] - palm[None], axis=2) + np.eye(len(palm))
    assert gaps.min() > 0.003, "farthest-point sampling spreads the palm's taxels"
    assert generate_layout(hand, 240).to_csv() == layout.to_csv()


def robosuite_grippers() -> Path | None:
    """robosuite's gripper models when installed (`pip install --no-deps robosuite`, or
    VINT_ROBOSUITE_DIR naming its package directory); never required."""
    import importlib.util
    import os

    named = os.environ.get("VINT_ROBOSUITE_DIR")
    if named:
        return Path(named) / "models" / "assets" / "grippers"
    found = importlib.util.find_spec("robosuite")
    if found is None or found.origin is None:
        return None
    return Path(found.origin).parent / "models" / "assets" / "grippers"


def adapt_robosuite_hand(xml: str) -> str:
    """robosuite's Inspire hand adapted as docs/hands.md says: `r_palm` becomes the worldbody's only
    body, `palm`, turned into vint's palm frame; the wrapper, the end-effector sites and the force
    sensor on them go."""
    import xml.etree.ElementTree as ET

    root = ET.fromstring(xml)
    world = root.find("worldbody")
    assert world is not None
    wrapper = world.find("body")
    assert wrapper is not None
    palm = wrapper.find("body[@name='r_palm']")
    assert palm is not None
    world.remove(wrapper)
    palm.set("name", "palm")
    world.append(palm)
    # Turned into vint's palm frame: the fingers grow along the palm's -y and curl towards its -x,
    # so the palm's new axes are x = -z, y = -y (the fingers' way), z = -x (the palm normal).
    turn = np.array([[0.0, 0.0, -1.0], [0.0, -1.0, 0.0], [-1.0, 0.0, 0.0]])  # columns: new axes
    turn_quat = matrix_to_quat(turn.T)
    for child in palm:
        if child.tag not in ("geom", "body", "site"):
            continue
        assert child.get("euler") is None and child.get("axisangle") is None, child.attrib
        pos = np.array([float(v) for v in child.get("pos", "0 0 0").split()])
        quat = np.array([float(v) for v in child.get("quat", "1 0 0 0").split()])
        child.set("pos", " ".join(f"{v:.9g}" for v in turn.T @ pos))
        child.set("quat", " ".join(f"{v:.9g}" for v in quat_multiply(turn_quat, quat)))
    for sensor in root.findall("sensor"):
        root.remove(sensor)
    for exclude in root.iter("exclude"):
        for key in ("body1", "body2"):
            if exclude.get(key) == "r_palm":
                exclude.set(key, "palm")
    return ET.tostring(root, encoding="unicode")


def test_robosuites_inspire_hand_adapted_as_documented_loads_and_grasps(
    tmp_path: Path, engine: EngineProcess
) -> None:
    grippers = robosuite_grippers()
    if grippers is None or not (grippers / "inspire_right_hand.xml").is_file():
        pytest.skip("robosuite is not installed (optional: pip install --no-deps robosuite)")
    xml = adapt_robosuite_hand((grippers / "inspire_right_hand.xml").read_text())
    spec_dir = tmp_path / "spec"
    (spec_dir / "hands").mkdir(parents=True)
    (spec_dir / "hands" / "inspire.xml").write_text(xml)
    files = {"hands/inspire.xml": spec_dir / "hands" / "inspire.xml"}
    for mesh in sorted((grippers / "meshes" / "inspire_hands").glob("rh_*.STL")):
        files[f"hands/meshes/inspire_hands/{mesh.name}"] = mesh
    hand = load_mjcf_hand("inspire", xml, "params.hand.mjcf", "hands/inspire.xml", files)
    assert len(hand.mesh_files) == 13 and len(hand.visual_geoms()) == 13
    layout = generate_layout(hand, 400)  # on the colliding meshes' hulls, as scripts/gen_taxels.py lays it
    assert {"palm", "pulp", "tip"} == set(layout.regions)
    assert {layout.links[i] for i, region in enumerate(layout.regions) if region == "tip"} == set(
        hand.fingertips()
    )
    (spec_dir / "hands" / "inspire_taxels.csv").write_text(layout.to_csv())
    files["hands/inspire_taxels.csv"] = spec_dir / "hands" / "inspire_taxels.csv"
    assets, inputs, sha = staged(files)
    params = {
        "assets": assets,
        "hand": {
            "name": "inspire",
            "mjcf": sha["hands/inspire.xml"],
            "taxels": sha["hands/inspire_taxels.csv"],
        },
        "object": load_catalog()["tomato_soup_can"].to_json(),
        "trials": [{"grasp_index": i, "seed": 900 + i} for i in range(4)],
        "physics": {"hold_s": 0.3},
    }
    out = new_dir(tmp_path, "grasp")
    GraspEngine().run(TaskRequest("grasp", params, inputs, out))
    doc = json.loads((out / "grasps.json").read_text())
    for trial in doc["trials"]:
        assert trial["accepted"] or trial["reason"], trial
    # 26 meshes from 13 files, a visual and a collision one each: each content once (the four
    # fingers' proximal links are one file's copies too).
    assert len(doc["hand"]["meshes"]) <= 13, len(doc["hand"]["meshes"])
    accepted = [t for t in doc["trials"] if t["accepted"]]
    if not accepted:  # the palm frame above is a rough one: grasps of this hand are not tuned
        return
    views = new_dir(tmp_path, "views")
    render = {
        "grasp_index": accepted[0]["grasp_index"],
        "render": {**RENDER, "width": 64, "height": 64},
        "views": [{"view_index": 0, "seed": 1}],
        "outputs": ["depth", "segmentation"],
    }
    reply = engine.task(views.name, render, views, [out / "grasps.json", out / "object.ply"])
    assert reply["ok"] is True, reply
    seg = cv2.imread(str(views / "v00_segmentation.png"), cv2.IMREAD_UNCHANGED)
    assert (seg >= 2).any(), "the hand is drawn"
