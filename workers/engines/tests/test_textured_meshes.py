"""A user's textured meshes: closedness judged on positions (a mesh split at UV seams is closed, an
open one is refused), the formats that carry colour (OBJ + MTL + image, PLY with BOP's
`TextureFile`, vertex colours) read from the files that travel with the mesh alone, and a
rendered box whose faces show their texture's colours where an independent projection of each
face lands. Every fixture is generated here."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from conftest import EngineProcess, new_dir

from vint_engines import depth_file
from vint_engines.grasp.engine import GraspEngine
from vint_engines.objects import ObjectSpec, build_model
from vint_engines.objects.textured import load_look
from vint_engines.protocol import BadInput, InputRef, TaskRequest

SIZE_MM = (80.0, 50.0, 30.0)
# Each face (by its outward axis) and its texture's colour (RGB): six hues 60° apart.
FACES: dict[str, tuple[int, int, int]] = {
    "+x": (255, 0, 0),
    "-x": (0, 255, 0),
    "+y": (0, 0, 255),
    "-y": (255, 255, 0),
    "+z": (0, 255, 255),
    "-z": (255, 0, 255),
}
TILE = 64  # texture pixels per face tile


def face_corners(name: str) -> np.ndarray:
    """The face's four corners (mm), counter-clockwise seen from outside."""
    half = np.array(SIZE_MM) / 2
    axis = "xyz".index(name[1])
    sign = 1.0 if name[0] == "+" else -1.0
    u, v = [(axis + 1) % 3, (axis + 2) % 3]
    corners = []
    for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
        p = np.zeros(3)
        p[axis] = sign * half[axis]
        p[u], p[v] = a * half[u], b * half[v]
        corners.append(p)
    corners = np.array(corners)
    return corners if sign > 0 else corners[::-1].copy()


def write_box(folder: Path, *, open_face: str | None = None, name: str = "box") -> dict[str, Path]:
    """A closed box with four vertices of its own per face (split at every edge, as a textured
    scan is at its UV seams), per-face UVs into one tile each of a texture atlas, its MTL and its
    PNG. Returns the three files."""
    folder.mkdir(parents=True, exist_ok=True)
    lines = [f"mtllib {name}.mtl", "usemtl skin"]
    n = 0
    for k, face in enumerate(FACES):
        if face == open_face:
            continue
        lines += ["v {:.6f} {:.6f} {:.6f}".format(*p) for p in face_corners(face)]
        u0, u1 = (k * TILE + 8) / (6 * TILE), ((k + 1) * TILE - 8) / (6 * TILE)
        lines += [f"vt {u:.6f} {v:.6f}" for u, v in ((u0, 0.2), (u1, 0.2), (u1, 0.8), (u0, 0.8))]
        a = n + 1
        lines += [f"f {a}/{a} {a + 1}/{a + 1} {a + 2}/{a + 2}", f"f {a}/{a} {a + 2}/{a + 2} {a + 3}/{a + 3}"]
        n += 4
    files = {"obj": folder / f"{name}.obj", "mtl": folder / f"{name}.mtl", "png": folder / f"{name}.png"}
    files["obj"].write_text("\n".join(lines) + "\n")
    files["mtl"].write_text(f"newmtl skin\nKd 1 1 1\nmap_Kd {name}.png\n")
    atlas = np.zeros((TILE, 6 * TILE, 3), np.uint8)
    for k, colour in enumerate(FACES.values()):
        atlas[:, k * TILE : (k + 1) * TILE] = colour
    cv2.imwrite(str(files["png"]), atlas[:, :, ::-1])
    return files


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def box_entry(sha: str) -> dict[str, Any]:
    return {
        "name": "box",
        "ycb_id": "",
        "mass_kg": 0.12,
        "material": "cardboard",
        "texture": {"kind": "plain"},
        "symmetries_continuous": [],
        "symmetries_discrete": [],
        "description": "user mesh assets/box.obj",
        "shape": {"type": "mesh", "asset": sha, "scale": 0.001},
    }


def test_a_box_split_at_its_uv_seams_is_closed_and_its_model_is_welded(tmp_path: Path) -> None:
    files = write_box(tmp_path)
    sha = sha256(files["obj"])
    model = build_model(ObjectSpec.parse(box_entry(sha)), assets={sha: files["obj"]})
    assert len(model.mesh.vertices) == 8 and len(model.mesh.faces) == 12
    assert model.extent == pytest.approx(np.array(SIZE_MM) / 1000)
    assert model.volume == pytest.approx(np.prod(SIZE_MM) / 1e9)


def test_an_open_mesh_is_still_refused_naming_its_holes(tmp_path: Path) -> None:
    files = write_box(tmp_path, open_face="+z")
    sha = sha256(files["obj"])
    with pytest.raises(
        BadInput, match=r"params\.object\.shape\.asset: 'box\.obj' is not a closed surface.* 4 edges"
    ):
        build_model(ObjectSpec.parse(box_entry(sha)), assets={sha: files["obj"]})


def test_texture_and_colour_come_only_from_the_files_given(tmp_path: Path) -> None:
    files = write_box(tmp_path / "staged")
    sidecars = {"box.mtl": files["mtl"], "box.png": files["png"]}
    look = load_look(files["obj"], 0.001, "x", sidecars)
    assert look.image is not None and look.image.shape == (TILE, 6 * TILE, 4)
    assert look.corner_uv is not None and look.corner_uv.shape == (12, 3, 2)
    assert len(look.vertices) == 8, "welded: one vertex per corner of the box"
    assert np.allclose(look.vertices.min(axis=0), -np.array(SIZE_MM) / 2000)
    # The MTL lies next to the mesh on the disk, but was not given: it is not read.
    bare = load_look(files["obj"], 0.001, "x", {})
    assert bare.image is None or bare.image.shape[:2] != (TILE, 6 * TILE)

    # A BOP model: PLY in mm, `comment TextureFile`, per-vertex texture_u/texture_v.
    corners = np.array([face_corners("+z")[i] for i in range(4)] + [face_corners("-z")[i] for i in range(4)])
    quads = [(0, 1, 2, 3), (4, 5, 6, 7), (0, 3, 5, 4), (1, 0, 4, 7), (2, 1, 7, 6), (3, 2, 6, 5)]
    tris = [(a, b, c) for a, b, c, d in quads] + [(a, c, d) for a, b, c, d in quads]
    header = (
        "ply\nformat ascii 1.0\ncomment TextureFile obj_000001.png\nelement vertex 8\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property float texture_u\nproperty float texture_v\n"
        "element face 12\nproperty list uchar int vertex_indices\nend_header\n"
    )
    body = [f"{x} {y} {z} {k / 8:.3f} 0.5" for k, (x, y, z) in enumerate(corners)] + [
        f"3 {a} {b} {c}" for a, b, c in tris
    ]
    ply = tmp_path / "obj_000001.ply"
    ply.write_text(header + "\n".join(body) + "\n")
    look = load_look(ply, 0.001, "x", {"obj_000001.png": files["png"]})
    assert look.image is not None and look.image.shape[:2] == (TILE, 6 * TILE)
    assert look.corner_uv is not None

    # Vertex colours (a PLY with red/green/blue).
    coloured = tmp_path / "coloured.ply"
    header = header.replace("comment TextureFile obj_000001.png\n", "").replace(
        "property float texture_u\nproperty float texture_v\n",
        "property uchar red\nproperty uchar green\nproperty uchar blue\n",
    )
    body = [f"{x} {y} {z} 255 0 0" for x, y, z in corners] + [f"3 {a} {b} {c}" for a, b, c in tris]
    coloured.write_text(header + "\n".join(body) + "\n")
    look = load_look(coloured, 0.001, "x", {})
    assert look.image is None and look.corner_colours is not None
    assert np.allclose(look.corner_colours[..., :3], [1.0, 0.0, 0.0])


# -- rendering ----------------------------------------------------------------------------------

RENDER = {
    "width": 128,
    "height": 128,
    "samples": 16,
    "fov_deg": 60.0,
    "environment": "studio",
    "radius_m": [0.22, 0.26],
    "elevation_deg": [20.0, 70.0],
    "sensor": {"enabled": False},
}
SEEDS = (3, 4, 5, 6)


@pytest.fixture(scope="module")
def staged(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The box's files, each staged as the worker stages an asset (its own folder, under its
    SHA-256), with the spec paths a spec in `specs/` would give them."""
    root = tmp_path_factory.mktemp("textured")
    files = write_box(root / "user")
    staged: dict[str, Any] = {"root": root, "assets": [], "inputs": []}
    for kind, path in files.items():
        sha = sha256(path)
        target = root / "assets" / sha / path.name
        target.parent.mkdir(parents=True)
        target.write_bytes(path.read_bytes())
        staged["assets"].append({"path": f"assets/{path.name}", "sha256": sha, "size": path.stat().st_size})
        staged["inputs"].append((sha, target))
        staged[kind] = sha
    return staged


@pytest.fixture(scope="module")
def grasp(staged: dict[str, Any]) -> dict[str, Any]:
    """An accepted grasp of the box by trx3 from the real grasp engine, which reads the mesh only."""
    out = new_dir(staged["root"], "grasp")
    mesh = next(a for a in staged["assets"] if a["sha256"] == staged["obj"])
    params = {
        "object": box_entry(staged["obj"]),
        "hand": {"name": "trx3"},
        "trials": [{"grasp_index": i, "seed": 70 + i} for i in range(6)],
        "assets": [mesh],
    }
    inputs = tuple(InputRef(sha, "asset", path) for sha, path in staged["inputs"] if sha == staged["obj"])
    GraspEngine().run(TaskRequest("grasp", params, inputs, out))
    doc = json.loads((out / "grasps.json").read_text())
    accepted = [t for t in doc["trials"] if t["accepted"]]
    assert accepted, [t["reason"] for t in doc["trials"]]
    trial = max(accepted, key=lambda t: t["approach"]["palm_normal_world"][2])  # the hand below
    return {"dir": out, "doc": doc, "trial": trial}


@pytest.fixture(scope="module")
def engine(staged: dict[str, Any]) -> Iterator[EngineProcess]:
    process = EngineProcess("render", staged["root"])
    assert process.receive() is not None, process.stderr_tail()
    yield process
    assert process.shutdown(60) == 0
    process.kill()


def quat_matrix(q: list[float]) -> np.ndarray:
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def face_samples(name: str, camera: dict[str, Any], pose: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (row, col) and camera depths (m) of a grid inside the face (inset from its edges),
    when the face looks at the camera; none otherwise. From the mesh's own numbers: mm to metres,
    the object frame at the bounding box's centre (the box is centred already)."""
    corners = face_corners(name) / 1000.0
    s, t = np.meshgrid(np.linspace(0.25, 0.75, 9), np.linspace(0.25, 0.75, 9))
    s, t = s.reshape(-1, 1), t.reshape(-1, 1)
    points = corners[0] + s * (corners[1] - corners[0]) + t * (corners[3] - corners[0])
    R, p = quat_matrix(pose["q"]), np.asarray(pose["p"])
    R_w2c, t_w2c = np.asarray(camera["R_w2c"]), np.asarray(camera["t_w2c"])
    in_camera = (R_w2c @ (R @ points.T + p[:, None]) + t_w2c[:, None]).T
    normal = R_w2c @ R @ np.cross(corners[1] - corners[0], corners[3] - corners[0])
    if normal @ in_camera.mean(axis=0) >= 0:
        return np.empty((0, 2), int), np.empty(0)
    uvw = (np.asarray(camera["K"]) @ in_camera.T).T
    cols, rows = uvw[:, 0] / uvw[:, 2], uvw[:, 1] / uvw[:, 2]
    return np.stack([np.floor(rows), np.floor(cols)], axis=1).astype(int), in_camera[:, 2]


def test_each_face_shows_its_texture_colour_where_it_projects(
    engine: EngineProcess, grasp: dict[str, Any], staged: dict[str, Any]
) -> None:
    out = new_dir(staged["root"], "views")
    params = {
        "grasp_index": grasp["trial"]["grasp_index"],
        "render": RENDER,
        "views": [{"view_index": v, "seed": seed} for v, seed in enumerate(SEEDS)],
        "outputs": ["rgb", "depth", "mask"],
        "assets": staged["assets"],
    }
    inputs = [grasp["dir"] / "grasps.json", grasp["dir"] / "object.ply", *staged["inputs"]]
    reply = engine.task(out.name, params, out, inputs)
    assert reply["ok"] is True, reply
    pose = grasp["trial"]["object_pose"]
    seen: dict[str, int] = {}
    for v in range(len(SEEDS)):
        prefix = out / f"v{v:02d}"
        camera = json.loads(Path(f"{prefix}_camera.json").read_text())
        rgb = cv2.imread(f"{prefix}_rgb.png", cv2.IMREAD_COLOR)
        mask = cv2.imread(f"{prefix}_mask.png", cv2.IMREAD_UNCHANGED) > 0
        depth = depth_file.read(Path(f"{prefix}_depth.png"))
        hsv = cv2.cvtColor(rgb, cv2.COLOR_BGR2HSV).astype(np.int64)
        for name, colour in FACES.items():
            pixels, z = face_samples(name, camera, pose)
            inside = (pixels >= 0).all(axis=1) & (pixels[:, 0] < 128) & (pixels[:, 1] < 128)
            pixels, z = pixels[inside], z[inside]
            shown = mask[pixels[:, 0], pixels[:, 1]] & (np.abs(depth[pixels[:, 0], pixels[:, 1]] - z) < 0.003)
            pixels = pixels[shown]
            if len(pixels) < 8:
                continue  # the face is edge-on, hidden by the hand or out of the frame
            expected = int(cv2.cvtColor(np.uint8([[colour[::-1]]]), cv2.COLOR_BGR2HSV)[0, 0, 0])
            hue, saturation = hsv[pixels[:, 0], pixels[:, 1], 0], hsv[pixels[:, 0], pixels[:, 1], 1]
            off = np.abs((hue - expected + 90) % 180 - 90)  # OpenCV hue: 0..180 for 0..360°
            assert np.median(off) <= 10, (name, v, np.median(off), expected, np.median(hue))
            assert np.median(saturation) >= 80, (name, v, np.median(saturation))
            seen[name] = seen.get(name, 0) + len(pixels)
    assert len(seen) >= 3, seen


def test_a_bop_models_obj_id_travels_through_the_entry() -> None:
    entry = {**box_entry("a" * 64), "obj_id": 5}
    spec = ObjectSpec.parse(entry)
    assert spec.obj_id == 5 and spec.to_json() == entry
    assert "obj_id" not in ObjectSpec.parse(box_entry("a" * 64)).to_json()
    with pytest.raises(BadInput, match=r"params\.object\.obj_id: 101 is outside \[1, 100\]"):
        ObjectSpec.parse({**entry, "obj_id": 101})


def test_a_bop_models_record_says_where_its_files_origin_is(tmp_path: Path) -> None:
    # A box spanning x 0..80, y 10..60, z 0..30 mm: its origin is far from its bounding-box centre.
    lo, hi = np.array([0.0, 10.0, 0.0]), np.array([80.0, 60.0, 30.0])
    corners = np.array([[hi[k] if i >> k & 1 else lo[k] for k in range(3)] for i in range(8)])
    quads = [(1, 3, 4, 2), (5, 6, 8, 7), (1, 2, 6, 5), (3, 7, 8, 4), (1, 5, 7, 3), (2, 4, 8, 6)]
    lines = [f"v {x} {y} {z}" for x, y, z in corners]
    lines += [f"f {a} {b} {c}\nf {a} {c} {d}" for a, b, c, d in quads]
    path = tmp_path / "offset_box.obj"
    path.write_text("\n".join(lines) + "\n")
    sha = sha256(path)
    model = build_model(ObjectSpec.parse({**box_entry(sha), "obj_id": 9}), assets={sha: path})
    offset = np.array(model.record()["file_offset_m"])
    assert offset == pytest.approx([0.04, 0.035, 0.015], abs=1e-12)
    # The object frame is still the bounding-box centre; adding the offset gives the file's points.
    assert model.mesh.vertices.min(axis=0) == pytest.approx(-(hi - lo) / 2000)

    def in_file(vertices: np.ndarray) -> np.ndarray:
        return np.unique(np.round((vertices + offset) * 1000, 6), axis=0)

    assert in_file(model.mesh.vertices) == pytest.approx(np.unique(corners, axis=0))
    # The render engine places the file's surface in the same frame.
    look = load_look(path, 0.001, "params.object", {})
    assert in_file(look.vertices) == pytest.approx(np.unique(corners, axis=0))
    # Objects that keep no BOP id keep their records as they were.
    plain = build_model(ObjectSpec.parse(box_entry(sha)), assets={sha: path})
    assert "file_offset_m" not in plain.record()
