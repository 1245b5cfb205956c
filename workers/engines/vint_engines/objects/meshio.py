"""Mesh files: import OBJ/STL/PLY (trimesh), and the model PLY the dataset ships (millimetres).

The exported PLY is binary little-endian with float32 `x y z` and `uchar`-counted `int` triangle
indices, and nothing that varies between runs (no timestamps, no library banner): the same mesh
always gives the same bytes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt
import trimesh

from vint_engines.protocol import BadInput

PLY_FACE = np.dtype([("count", "u1"), ("index", "<i4", (3,))])


def load_mesh(path: Path, scale: float, where: str) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Vertices (metres: file units × `scale`) and outward triangles of a watertight mesh file.
    BadInput when the file is missing, unreadable, or not a closed surface; `where` names the
    parameter that pointed at it."""
    if not path.is_file():
        raise BadInput(f"{where}: mesh file {str(path)!r} does not exist")
    try:
        mesh = trimesh.load_mesh(path, process=True)
    except Exception as exc:  # trimesh raises many kinds of errors on malformed files
        raise BadInput(f"{where}: cannot read mesh {path.name!r}: {exc}") from exc
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) < 4:
        raise BadInput(f"{where}: {path.name!r} holds no triangle mesh")
    if not (mesh.is_watertight and mesh.is_winding_consistent):
        raise BadInput(f"{where}: {path.name!r} is not a closed, consistently wound surface")
    vertices = np.asarray(mesh.vertices, dtype=np.float64) * scale
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if _signed_volume(vertices, faces) < 0:
        faces = faces[:, ::-1].copy()  # inside out: flip every triangle
    return vertices, faces


def _signed_volume(vertices: npt.NDArray[np.float64], faces: npt.NDArray[np.int64]) -> float:
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def ply_bytes(vertices_m: npt.NDArray[np.float64], faces: npt.NDArray[np.int64]) -> bytes:
    """A binary PLY of the mesh in millimetres."""
    header = (
        "ply\n"
        "format binary_little_endian 1.0\n"
        "comment vint object model, units: mm\n"
        f"element vertex {len(vertices_m)}\n"
        "property float x\nproperty float y\nproperty float z\n"
        f"element face {len(faces)}\n"
        "property list uchar int vertex_indices\n"
        "end_header\n"
    )
    records = np.empty(len(faces), dtype=PLY_FACE)
    records["count"] = 3
    records["index"] = faces
    return header.encode("ascii") + (vertices_m * 1000.0).astype("<f4").tobytes() + records.tobytes()


def read_ply_m(path: Path) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Vertices (converted to metres) and triangles of a model PLY written in millimetres."""
    try:
        mesh = trimesh.load_mesh(path, file_type="ply", process=False)
    except Exception as exc:
        raise BadInput(f"cannot read model mesh {path.name!r}: {exc}") from exc
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise BadInput(f"model mesh {path.name!r} holds no triangles")
    return np.asarray(mesh.vertices, dtype=np.float64) / 1000.0, np.asarray(mesh.faces, dtype=np.int64)
