"""The hand's meshes are the same bytes in every process: vertices, and the order of the faces and
their loops. The ray tracer breaks a tie between two triangles by their order, so a mesh built in
another order renders a few pixels differently (`docs/rendering.md`, "Byte-stable RGB");
`bmesh.ops.create_uvsphere` gave another loop order in every fresh process. The sensor skin's
discs are held to the same (a link carrying hundreds of them)."""

from __future__ import annotations

import subprocess
import sys

from conftest import ENGINES_DIR

# Every primitive the renderer draws, a rounded palm box and a fingertip with taxel discs, hashed in
# a fresh process.
SCRIPT = """
import hashlib
import bpy
import numpy as np
from mathutils import Matrix
from vint_engines.render import meshes
turn = Matrix.Rotation(0.7, 3, (1.0, 2.0, 3.0)).to_quaternion()
place = Matrix.LocRotScale((0.01, -0.02, 0.03), turn, None)
for kind, size, radius in (
    ("capsule", (0.0098, 0.02115), 0.0),
    ("sphere", (0.012,), 0.0),
    ("cylinder", (0.01, 0.02), 0.0),
    ("box", (0.0475, 0.0565, 0.0204), 0.004),
    ("skin", (0.012,), 0.0),
):
    angles = np.linspace(0.0, 3.0, 60)
    normals = np.stack([np.sin(angles), np.cos(angles), np.cos(3 * angles)], axis=1)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    discs = (0.0122 * normals, normals, 0.0018, 0.0002, 2) if kind == "skin" else None
    shape = "sphere" if kind == "skin" else kind
    mesh = meshes.new_mesh(kind, [(shape, size, place)], [0], radius, (), discs)
    co = np.empty(3 * len(mesh.vertices), np.float32)
    mesh.vertices.foreach_get("co", co)
    loops = np.empty(len(mesh.loops), np.int32)
    mesh.loops.foreach_get("vertex_index", loops)
    starts = np.empty(len(mesh.polygons), np.int32)
    mesh.polygons.foreach_get("loop_start", starts)
    digest = hashlib.sha256(co.tobytes() + loops.tobytes() + starts.tobytes()).hexdigest()
    print(kind, len(mesh.polygons), digest)
"""


def mesh_digests() -> str:
    done = subprocess.run(
        [sys.executable, "-c", SCRIPT],
        cwd=ENGINES_DIR,
        capture_output=True,
        text=True,
        check=True,
        timeout=120,
    )
    lines = [
        line
        for line in done.stdout.splitlines()
        if line.split(" ")[0] in {"capsule", "sphere", "cylinder", "box", "skin"}
    ]
    assert len(lines) == 5, done.stdout + done.stderr
    return "\n".join(lines)


def test_primitive_meshes_are_the_same_bytes_in_fresh_processes() -> None:
    first = mesh_digests()
    assert all(mesh_digests() == first for _ in range(2)), first
