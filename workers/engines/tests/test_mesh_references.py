"""A user's mesh reads only the files submitted with it (`objects/meshio.py`, `SidecarResolver`): an
OBJ's `mtllib`, an MTL's `map_Kd`, a PLY's `TextureFile` or a glTF's buffer `uri` that names an
absolute path or climbs out with `..` is never opened, whatever lies there. Every file that the
engine opens while loading is recorded (Python's `open` audit event), so a read outside the
submission fails the test even where a library would have swallowed what it read."""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from vint_engines.objects.meshio import load_mesh
from vint_engines.objects.textured import MeshSource
from vint_engines.protocol import BadInput

_recording: list[list[str]] = []


def _audit(event: str, args: tuple[Any, ...]) -> None:
    if _recording and event == "open" and isinstance(args[0], (str, bytes, Path)):
        _recording[-1].append(str(Path(args[0].decode() if isinstance(args[0], bytes) else args[0])))


sys.addaudithook(_audit)  # hooks cannot be removed: this one records only inside `opened_files`


@contextmanager
def opened_files() -> Iterator[list[str]]:
    """The paths of every file opened in this process while the block runs."""
    _recording.append([])
    try:
        yield _recording[-1]
    finally:
        _recording.pop()


TETRAHEDRON = """v 0 0 0
v 1 0 0
v 0 1 0
v 0 0 1
vt 0 0
vt 1 0
vt 0 1
usemtl skin
f 1/1 3/3 2/2
f 1/1 2/2 4/3
f 1/1 4/3 3/3
f 2/2 3/3 4/3
"""
RED, GREEN = (0, 0, 255), (0, 255, 0)  # BGR, as OpenCV writes


def write_png(path: Path, bgr: tuple[int, int, int]) -> Path:
    assert cv2.imwrite(str(path), np.full((4, 4, 3), bgr, np.uint8))
    return path


@pytest.fixture
def layout(tmp_path: Path) -> dict[str, Path]:
    """A submission directory (the mesh and its own green texture) and, beside it, a directory the
    submission must never reach: an MTL and a red texture that would be recognised if read."""
    submission, outside = tmp_path / "submission", tmp_path / "outside"
    submission.mkdir()
    outside.mkdir()
    red = write_png(outside / "secret.png", RED)
    (outside / "secret.mtl").write_text(f"newmtl skin\nKd 1 0 0\nmap_Kd {red}\n")
    return {
        "submission": submission,
        "outside": outside,
        "green": write_png(submission / "skin.png", GREEN),
    }


def look(files: dict[str, Path], obj_text: str, mtl_text: str | None = None) -> Any:
    """The look of `mesh.obj` (with `mesh.mtl` when given) as the render engine loads a staged
    mesh: sidecars by their names relative to the mesh, here the MTL and the green PNG."""
    mesh = files["submission"] / "mesh.obj"
    mesh.write_text(obj_text + TETRAHEDRON)
    staged = {"png": ("assets/skin.png", files["green"])}
    if mtl_text is not None:
        (files["submission"] / "mesh.mtl").write_text(mtl_text)
        staged["mtl"] = ("assets/mesh.mtl", files["submission"] / "mesh.mtl")
    return MeshSource.staged(mesh, "assets/mesh.obj", 1.0, staged).load("objects[0].mesh")


def outside_reads(opened: list[str], files: dict[str, Path]) -> list[str]:
    outside = str(files["outside"])
    return [p for p in opened if p.startswith(outside) or p.startswith("/etc/")]


def image_colour(found: Any) -> tuple[int, ...] | None:
    """The texture's colour (RGB), None without one (trimesh gives a grey one for UVs without)."""
    return None if found.image is None else tuple(int(c) for c in found.image[0, 0, :3])


RED_RGB = (255, 0, 0)


def test_a_texture_the_submission_supplies_is_read(layout: dict[str, Path]) -> None:
    """The control: the same loader does read what the submission holds (so the tests below would
    see a read)."""
    with opened_files() as opened:
        found = look(layout, "mtllib mesh.mtl\n", "newmtl skin\nmap_Kd skin.png\n")
    assert image_colour(found) == (0, 255, 0)
    assert str(layout["green"]) in opened


@pytest.mark.parametrize("reference", ["{outside}/secret.mtl", "../outside/secret.mtl", "/etc/passwd"])
def test_an_mtllib_outside_the_submission_is_never_opened(layout: dict[str, Path], reference: str) -> None:
    mtllib = reference.format(outside=layout["outside"])
    with opened_files() as opened:
        found = look(layout, f"mtllib {mtllib}\n")
    assert outside_reads(opened, layout) == []
    assert image_colour(found) != RED_RGB


@pytest.mark.parametrize(
    "reference", ["{outside}/secret.png", "../outside/secret.png", "./../outside/secret.png"]
)
def test_a_texture_map_outside_the_submission_is_never_opened(
    layout: dict[str, Path], reference: str
) -> None:
    texture = reference.format(outside=layout["outside"])
    with opened_files() as opened:
        found = look(layout, "mtllib mesh.mtl\n", f"newmtl skin\nmap_Kd {texture}\n")
    assert outside_reads(opened, layout) == []
    assert image_colour(found) != RED_RGB


def test_a_ply_texture_or_gltf_buffer_outside_the_submission_is_never_opened(layout: dict[str, Path]) -> None:
    secret = layout["outside"] / "secret.png"
    ply = layout["submission"] / "mesh.ply"
    ply.write_text(
        f"ply\nformat ascii 1.0\ncomment TextureFile {secret}\nelement vertex 4\n"
        "property float x\nproperty float y\nproperty float z\nelement face 4\n"
        "property list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n"
        "3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n"
    )
    gltf = layout["submission"] / "mesh.gltf"
    gltf.write_text(
        json.dumps({"asset": {"version": "2.0"}, "buffers": [{"uri": str(secret), "byteLength": 64}]})
    )
    with opened_files() as opened:
        found = MeshSource.staged(ply, "assets/mesh.ply", 1.0, {}).load("objects[0].mesh")
        with pytest.raises(BadInput, match=r"objects\[0\]\.mesh: cannot read mesh 'mesh.gltf'"):
            MeshSource.staged(gltf, "assets/mesh.gltf", 1.0, {}).load("objects[0].mesh")
    assert outside_reads(opened, layout) == []
    assert image_colour(found) != RED_RGB


def test_the_grasp_engine_reads_no_reference_at_all(layout: dict[str, Path]) -> None:
    """The grasp engine's mesh load (`load_mesh`) gets no sidecars: geometry only."""
    mesh = layout["submission"] / "mesh.obj"
    mesh.write_text(f"mtllib {layout['outside']}/secret.mtl\n" + TETRAHEDRON)
    with opened_files() as opened:
        vertices, faces = load_mesh(mesh, 1.0, "objects[0].mesh")
    assert (len(vertices), len(faces)) == (4, 4)
    assert outside_reads(opened, layout) == []
