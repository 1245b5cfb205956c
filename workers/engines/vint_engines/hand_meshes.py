"""How `grasps.json` carries a user hand's meshes (`grasp/scene.py` writes them, the renderer reads
them): each mesh once, its vertices as little-endian float32 (metres, x y z per vertex) and its
triangles as little-endian uint32 (three vertex indices each), both base64-encoded. A real hand's
meshes hold 10⁴–10⁵ triangles, which as JSON numbers tripled the file every render task fetches
and every grasp record repeats; float32 keeps well under a micrometre within a metre.
"""

from __future__ import annotations

import base64
from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

VERTICES = "vertices_f32le"
FACES = "faces_u32le"


def encode(vertices: npt.ArrayLike, faces: npt.ArrayLike) -> dict[str, Any]:
    """A mesh as `grasps.json` holds it (see the module doc)."""
    v = np.ascontiguousarray(vertices, dtype="<f4").reshape(-1, 3)
    f = np.ascontiguousarray(faces, dtype="<u4").reshape(-1, 3)
    return {
        "vertex_count": len(v),
        "face_count": len(f),
        VERTICES: base64.b64encode(v.tobytes()).decode("ascii"),
        FACES: base64.b64encode(f.tobytes()).decode("ascii"),
    }


def decode(record: Mapping[str, Any]) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Vertices (n × 3, metres) and triangles (m × 3) of an `encode`d mesh; ValueError when the
    record is malformed (counts that disagree with the data, an index past the vertices)."""
    vertices = np.frombuffer(base64.b64decode(record[VERTICES], validate=True), dtype="<f4")
    faces = np.frombuffer(base64.b64decode(record[FACES], validate=True), dtype="<u4")
    n, m = int(record["vertex_count"]), int(record["face_count"])
    if vertices.size != 3 * n or faces.size != 3 * m:
        raise ValueError(
            f"mesh holds {vertices.size} coordinates and {faces.size} indices, not {n}×3 and {m}×3"
        )
    if m and int(faces.max()) >= n:
        raise ValueError(f"a triangle names vertex {int(faces.max())} of {n}")
    return vertices.reshape(n, 3).astype(np.float64), faces.reshape(m, 3).astype(np.int64)
