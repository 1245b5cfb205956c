"""Watertight triangle meshes of shapes, in metres, in the shape's own frame.

A cylinder or box is centred on its origin, a revolved profile keeps its own (r, z) coordinates, a
compound is the boolean union (Manifold) of its placed parts, a mesh file is read by `meshio`.
Circles have `SEGMENTS` vertices, one of them on +x. Every mesh leaves here in canonical order
(vertices sorted, faces sorted), so the same shape always gives the same arrays, bit for bit.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import manifold3d
import numpy as np
import numpy.typing as npt

from vint_engines.objects import meshio
from vint_engines.objects.spec import (
    Box,
    Compound,
    Cylinder,
    MeshFile,
    Part,
    Revolved,
    Shape,
    closed_outline,
    euler_matrix,
)
from vint_engines.protocol import BadInput

SEGMENTS = 64

Array = npt.NDArray[np.float64]
Faces = npt.NDArray[np.int64]


@dataclass(frozen=True, eq=False)
class TriangleMesh:
    """Vertices (n×3, metres) and outward-wound triangles (m×3 vertex indices)."""

    vertices: Array
    faces: Faces

    def moved(self, transform: Array) -> TriangleMesh:
        """The mesh under a 4×4 rigid transform."""
        return TriangleMesh(self.vertices @ transform[:3, :3].T + transform[:3, 3], self.faces)

    def volume(self) -> float:
        a, b, c = (self.vertices[self.faces[:, k]] for k in range(3))
        return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def shape_mesh(
    shape: Shape, root: Path, where: str, assets: Mapping[str, Path] | None = None
) -> TriangleMesh:
    """The shape's surface in its own frame; `root` resolves mesh-file paths and `assets` (SHA-256
    to staged file) mesh assets, `where` names the shape in errors."""
    if isinstance(shape, Compound):
        return union([part_mesh(part) for part in shape.parts], f"{where}.parts")
    if isinstance(shape, MeshFile):
        if shape.asset:
            staged = (assets or {}).get(shape.asset)
            if staged is None:
                raise BadInput(f"{where}.asset: the file {shape.asset} was not staged for this task")
            vertices, faces = meshio.load_mesh(staged, shape.scale, f"{where}.asset")
        else:
            vertices, faces = meshio.load_mesh(root / shape.path, shape.scale, f"{where}.path")
        return canonical(vertices, faces)
    return primitive_mesh(shape)


def primitive_mesh(shape: Cylinder | Box | Revolved) -> TriangleMesh:
    if isinstance(shape, Cylinder):
        half = shape.height / 2
        return revolve(((shape.radius, -half), (shape.radius, half)))
    if isinstance(shape, Box):
        return box(shape.size)
    return revolve(shape.profile)


def part_transform(part: Part) -> Array:
    transform = np.eye(4)
    transform[:3, :3] = euler_matrix(part.euler_deg)
    transform[:3, 3] = part.pos
    return transform


def part_mesh(part: Part) -> TriangleMesh:
    return primitive_mesh(part.shape).moved(part_transform(part))


def circle(radius: float, z: float, segments: int = SEGMENTS) -> Array:
    """`segments` points of a horizontal circle, the first on +x, counter-clockwise seen from +z."""
    angles = 2 * math.pi * np.arange(segments) / segments
    return np.stack([radius * np.cos(angles), radius * np.sin(angles), np.full(segments, z)], axis=1)


def revolve(profile: Sequence[tuple[float, float]], segments: int = SEGMENTS) -> TriangleMesh:
    """The solid of revolution of a validated profile about +z (closed along the axis)."""
    outline = closed_outline(profile)
    vertices: list[Array] = []
    rings: list[npt.NDArray[np.int64]] = []  # per outline point: its vertex indices (1 on the axis)
    count = 0
    for r, z in outline:
        points = np.array([[0.0, 0.0, z]]) if r == 0.0 else circle(r, z, segments)
        vertices.append(points)
        rings.append(np.arange(count, count + len(points)))
        count += len(points)
    faces: list[Faces] = []
    j = np.arange(segments)
    for lower, upper in itertools.pairwise(rings):
        a, b = (lower[j % len(lower)], lower[(j + 1) % len(lower)])
        d, c = (upper[j % len(upper)], upper[(j + 1) % len(upper)])
        if len(lower) > 1:
            faces.append(np.stack([a, b, c], axis=1))
        if len(upper) > 1:
            faces.append(np.stack([a, c, d], axis=1))
    mesh = canonical(np.concatenate(vertices), np.concatenate(faces))
    return mesh if mesh.volume() > 0 else TriangleMesh(mesh.vertices, mesh.faces[:, ::-1].copy())


def box(size: Sequence[float]) -> TriangleMesh:
    half = np.asarray(size, dtype=np.float64) / 2
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
    # Corner index = 4·(x>0) + 2·(y>0) + (z>0); two outward triangles per face.
    faces = np.array(
        [
            [0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5],  # -x, +x
            [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],  # -y, +y
            [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3],  # -z, +z
        ]
    )  # fmt: skip
    return canonical(corners * half, faces)


def union(meshes: Sequence[TriangleMesh], where: str) -> TriangleMesh:
    """The boolean union of closed meshes; BadInput unless it is one connected solid."""
    solids = [to_manifold(mesh) for mesh in meshes]
    result = manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add)
    if len(result.decompose()) != 1:
        raise BadInput(f"{where}: the parts do not form one connected solid (they must overlap)")
    out = result.to_mesh64()
    return canonical(np.asarray(out.vert_properties)[:, :3], np.asarray(out.tri_verts, dtype=np.int64))


def to_manifold(mesh: TriangleMesh) -> manifold3d.Manifold:
    solid = manifold3d.Manifold(
        manifold3d.Mesh64(
            vert_properties=np.ascontiguousarray(mesh.vertices, dtype=np.float64),
            tri_verts=np.ascontiguousarray(mesh.faces, dtype=np.uint64),
        )
    )
    if solid.status() != manifold3d.Error.NoError:
        raise BadInput(f"the shape is not a closed oriented manifold mesh: {solid.status()}")
    return solid


def canonical(vertices: npt.ArrayLike, faces: npt.ArrayLike) -> TriangleMesh:
    """Merge identical vertices, drop degenerate and unused ones, and sort: vertices
    lexicographically, each face rotated to start at its lowest index (winding kept), faces
    lexicographically. Equal geometry in any order gives identical arrays."""
    points = np.asarray(vertices, dtype=np.float64) + 0.0  # -0.0 → 0.0
    unique, inverse = np.unique(points, axis=0, return_inverse=True)
    tris = inverse.reshape(-1)[np.asarray(faces, dtype=np.int64)]
    tris = tris[(tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 0] != tris[:, 2])]
    used = np.unique(tris)
    remap = np.full(len(unique), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    tris = remap[tris]
    start = np.argmin(tris, axis=1)
    rows = np.arange(len(tris))
    tris = np.stack([tris[rows, (start + k) % 3] for k in range(3)], axis=1)
    tris = tris[np.lexsort((tris[:, 2], tris[:, 1], tris[:, 0]))]
    return TriangleMesh(unique[used], tris)
