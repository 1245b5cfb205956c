"""Mesh files: import OBJ/STL/PLY/glTF (trimesh), and the model PLY the dataset ships (millimetres).

A mesh file's surface is judged on positions: scanned and textured meshes split their vertices
at UV seams (one position, several texture coordinates), so the vertices are welded by position
(within `WELD_TOLERANCE` of the mesh's bounding-box diagonal) before the watertight and winding
checks, and physics and the model PLY use the welded mesh. trimesh follows the file references a
mesh names (OBJ `mtllib`, MTL `map_Kd`, glTF `uri`); here it may read only the files given to it
(`sidecars`), never anything else on the disk.

The exported PLY is binary little-endian with float32 `x y z` and `uchar`-counted `int` triangle
indices, and nothing that varies between runs (no timestamps, no library banner): the same mesh
always gives the same bytes.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import trimesh

from vint_engines.protocol import BadInput

PLY_FACE = np.dtype([("count", "u1"), ("index", "<i4", (3,))])
MAX_MESH_FACES = 500_000  # vint_core::asset::MAX_MESH_FACES
WELD_TOLERANCE = 1e-6  # of the bounding-box diagonal: far below any feature, above float noise


class SidecarResolver(trimesh.resolvers.Resolver):
    """Serves a mesh file's references from `files` (name as the mesh writes it → path) alone: a
    name outside them is absent, whatever lies on the disk."""

    def __init__(self, files: Mapping[str, Path]) -> None:
        self.files = dict(files)

    def get(self, name: str) -> bytes:
        path = self.files.get(name.replace("\\", "/").removeprefix("./"))
        if path is None:
            raise FileNotFoundError(name)
        return path.read_bytes()

    def keys(self) -> list[str]:
        return sorted(self.files)

    def write(self, name: str, data: Any) -> None:
        raise PermissionError(name)

    def namespaced(self, namespace: str) -> SidecarResolver:
        prefix = namespace.rstrip("/") + "/"
        return SidecarResolver(
            {k.removeprefix(prefix): v for k, v in self.files.items() if k.startswith(prefix)}
        )


def read_scene(path: Path, where: str, sidecars: Mapping[str, Path] | None = None) -> trimesh.Trimesh:
    """The file's triangles as one trimesh, unprocessed (split vertices and their UVs or colours
    kept), references resolved from `sidecars` only. BadInput when missing, unreadable or empty."""
    if not path.is_file():
        raise BadInput(f"{where}: mesh file {str(path)!r} does not exist")
    try:
        loaded = trimesh.load(path, process=False, resolver=SidecarResolver(sidecars or {}), force="mesh")
    except Exception as exc:  # trimesh raises many kinds of errors on malformed files
        raise BadInput(f"{where}: cannot read mesh {path.name!r}: {exc}") from exc
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) < 4:
        raise BadInput(f"{where}: {path.name!r} holds no triangle mesh")
    if len(loaded.faces) > MAX_MESH_FACES:
        raise BadInput(
            f"{where}: {path.name!r} has {len(loaded.faces)} triangles, "
            f"more than the limit of {MAX_MESH_FACES}"
        )
    return loaded


def weld(vertices: npt.NDArray[np.float64]) -> npt.NDArray[np.int64]:
    """For each vertex, the index of the first vertex at its position (within `WELD_TOLERANCE` of
    the bounding-box diagonal)."""
    diagonal = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0))) if len(vertices) else 0.0
    step = max(diagonal * WELD_TOLERANCE, np.finfo(np.float64).tiny)
    cells = np.round((vertices - vertices.min(axis=0)) / step).astype(np.int64)
    _, first, inverse = np.unique(cells, axis=0, return_index=True, return_inverse=True)
    return first[inverse.reshape(-1)]


def load_mesh(path: Path, scale: float, where: str) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Vertices (metres: file units × `scale`) and outward triangles of a closed mesh file, welded
    by position. BadInput when the file is missing, unreadable, or not a closed surface; `where`
    names the parameter that pointed at it."""
    loaded = read_scene(path, where)
    raw = np.asarray(loaded.vertices, dtype=np.float64)
    faces = weld(raw)[np.asarray(loaded.faces, dtype=np.int64)]
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    used, compact = np.unique(faces, return_inverse=True)
    mesh = trimesh.Trimesh(raw[used], compact.reshape(-1, 3), process=False)
    if not mesh.is_watertight:
        raise BadInput(
            f"{where}: {path.name!r} is not a closed surface: after welding vertices that share a position, "
            f"{_open_edges(mesh)} edges still bound only one triangle (holes or cracks)"
        )
    if not mesh.is_winding_consistent:
        raise BadInput(
            f"{where}: {path.name!r} is not consistently wound (neighbouring triangles face opposite ways)"
        )
    vertices = np.asarray(mesh.vertices, dtype=np.float64) * scale
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if _signed_volume(vertices, faces) < 0:
        faces = faces[:, ::-1].copy()  # inside out: flip every triangle
    return vertices, faces


def _open_edges(mesh: trimesh.Trimesh) -> int:
    edges = np.sort(mesh.edges, axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return int(np.count_nonzero(counts == 1))


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
