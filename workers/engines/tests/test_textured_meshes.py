"""A user's textured meshes: closedness judged on positions (a mesh split at UV seams is closed, an
open one is refused). Every fixture is generated here."""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from vint_engines.objects import ObjectSpec, build_model
from vint_engines.protocol import BadInput

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
