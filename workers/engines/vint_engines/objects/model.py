"""An object's model: its watertight mesh in the object frame, convex pieces for collision, mass
properties and resting pose — everything engines need, built once per object and cached.

Object frame (shared by physics, rendering and the exported PLY): the origin is the centre of the
mesh's axis-aligned bounding box, the axes are the shape's own (for cylinders and revolved shapes
+z is the axis). The bounding-box centre does not depend on an assumed density, and for the
symmetric shapes it is the usual centre.

A BOP dataset's model (an entry with `obj_id`) keeps its file's own frame through the exports: its
record names `file_offset_m`, the bounding-box centre in the mesh file's coordinates (metres), so a
point x of the object frame is x + file_offset_m in the file's, and a pose (R, t) of the object
frame is (R, t - R·file_offset_m) of the file's (`docs/assets.md`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import manifold3d
import numpy as np

from vint_engines.objects import meshio
from vint_engines.objects.catalog import CATALOG_DIR
from vint_engines.objects.decompose import ConvexPiece, convex_pieces
from vint_engines.objects.rest import RestPose, rest_pose
from vint_engines.objects.spec import ObjectSpec
from vint_engines.objects.tessellate import Array, TriangleMesh, shape_mesh

MODEL_FILE = "object.ply"
MODEL_MEDIA_TYPE = "application/x-ply"
DECIMALS = 9  # lengths in grasps.json's model record: nanometres


@dataclass(frozen=True, eq=False)
class ObjectModel:
    spec: ObjectSpec
    mesh: TriangleMesh  # metres, object frame
    pieces: tuple[ConvexPiece, ...]  # object frame
    volume: float  # m³
    centroid: Array  # centre of mass (uniform density), object frame
    inertia: Array  # 3×3 about the centroid, object axes, kg·m² for spec.mass
    rest: RestPose
    file_offset: Array  # bounding-box centre in the shape's own (file) coordinates, m

    @property
    def extent(self) -> Array:
        """Bounding-box edge lengths along the object axes (m)."""
        return self.mesh.vertices.max(axis=0) - self.mesh.vertices.min(axis=0)

    def ply(self) -> bytes:
        """The model mesh as the dataset ships it: binary PLY in millimetres."""
        return meshio.ply_bytes(self.mesh.vertices, self.mesh.faces)

    def record(self) -> dict[str, Any]:
        """What grasps.json says about the model file next to it; a BOP dataset's model (`obj_id`)
        adds where its file's frame is (`file_offset_m`), for the exports."""
        keep_frame = (
            {"file_offset_m": [round(float(v), DECIMALS) + 0.0 for v in self.file_offset]}
            if self.spec.obj_id is not None
            else {}
        )
        return {
            "file": MODEL_FILE,
            "units": "mm",
            "frame": "bounding-box centre",
            "extent_m": [round(float(v), DECIMALS) for v in self.extent],
            "volume_m3": round(self.volume, DECIMALS + 3),
            "centroid_m": [round(float(v), DECIMALS) + 0.0 for v in self.centroid],
            "diameter_m": round(diameter(self.mesh.vertices), DECIMALS),
            **keep_frame,
        }


def build_model(
    spec: ObjectSpec,
    root: Path = CATALOG_DIR,
    where: str = "params.object",
    assets: Mapping[str, Path] | None = None,
) -> ObjectModel:
    """Build the object's model; `root` resolves mesh-file paths and `assets` (SHA-256 to staged
    file) a user's mesh, `where` names it in errors."""
    raw = shape_mesh(spec.shape, root, f"{where}.shape", assets)
    low, high = raw.vertices.min(axis=0), raw.vertices.max(axis=0)
    to_object = np.eye(4)
    to_object[:3, 3] = -(low + high) / 2
    mesh = raw.moved(to_object)
    pieces = tuple(piece.moved(to_object) for piece in convex_pieces(spec.shape, raw))
    volume, centroid, unit_inertia = mass_properties(mesh)
    return ObjectModel(
        spec=spec,
        mesh=mesh,
        pieces=pieces,
        volume=volume,
        centroid=centroid,
        inertia=unit_inertia * spec.mass,
        rest=rest_pose(mesh.vertices, centroid),
        file_offset=(low + high) / 2,
    )


def mass_properties(mesh: TriangleMesh) -> tuple[float, Array, Array]:
    """Volume, centroid and the inertia per kilogram about the centroid of a closed mesh of uniform
    density (signed tetrahedra from the origin; exact for the polyhedron)."""
    a, b, c = (mesh.vertices[mesh.faces[:, k]] for k in range(3))
    det = np.einsum("ij,ij->i", a, np.cross(b, c))  # 6 × signed tetra volume
    volume = float(det.sum() / 6.0)
    centroid = (det[:, None] * (a + b + c)).sum(axis=0) / (24.0 * volume)
    # Second moments ∫ x_i x_j dV over each tetra (0, a, b, c): det/120 · (Σ v v^T + s s^T), s = a+b+c.
    s = a + b + c
    second = np.einsum("k,kij->ij", det / 120.0, _outer(a) + _outer(b) + _outer(c) + _outer(s))
    second_c = second / volume - np.outer(centroid, centroid)  # per unit mass, about the centroid
    inertia = np.trace(second_c) * np.eye(3) - second_c
    return volume, centroid, inertia


def _outer(v: Array) -> Array:
    return np.einsum("ki,kj->kij", v, v)


def diameter(vertices: Array) -> float:
    """The largest distance between two vertices (BOP's model diameter; attained on the hull)."""
    hull = manifold3d.Manifold.hull_points(np.ascontiguousarray(vertices)).to_mesh64()
    points = np.asarray(hull.vert_properties)[:, :3]
    best = 0.0
    for start in range(0, len(points), 256):
        d2 = ((points[start : start + 256, None, :] - points[None, :, :]) ** 2).sum(axis=2)
        best = max(best, float(d2.max()))
    return float(np.sqrt(best))


class ObjectModels:
    """Models built so far, per object: an engine keeps one for its lifetime (a mesh file's convex
    decomposition takes seconds). Bounded; the oldest model is dropped first."""

    def __init__(self, root: Path = CATALOG_DIR, capacity: int = 64) -> None:
        self.root = root
        self.capacity = capacity
        self._models: dict[ObjectSpec, ObjectModel] = {}

    def get(
        self, spec: ObjectSpec, where: str = "params.object", assets: Mapping[str, Path] | None = None
    ) -> ObjectModel:
        """The object's model, built on first use; a mesh asset is keyed by its hash, so the same
        content is built once whatever file it was staged as."""
        model = self._models.get(spec)
        if model is None:
            model = build_model(spec, self.root, where, assets)
            if len(self._models) >= self.capacity:
                del self._models[next(iter(self._models))]
            self._models[spec] = model
        return model
