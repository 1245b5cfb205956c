"""The object's surface as a grasp sees it: area-weighted points with their outward normals, and
how wide the object is across a hand's closing direction.

Pure numpy over the object's model mesh (object frame, outward-wound triangles); built once per
scene. Owns no randomness: `sample` draws from the generator it is given, in a fixed order (one
uniform for the triangle, two for the point in it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from vint_engines.objects.tessellate import TriangleMesh

Array = npt.NDArray[np.float64]

# A ray testing whether a surface point faces outwards starts this far off the surface, clear of
# the triangle it starts on.
RAY_OFFSET_M = 1e-6


@dataclass(frozen=True, eq=False)
class ObjectSurface:
    """Triangles of the model mesh with their cumulative area (for area-weighted sampling), unit
    outward normals and unique edges (for cross-sections)."""

    vertices: Array
    corners: Array  # m×3×3: each triangle's vertices
    normals: Array  # m×3 unit outward normals
    cumulative_area: Array  # m: running sum of the triangle areas
    edges: npt.NDArray[np.int64]  # e×2 vertex indices, each edge once

    @staticmethod
    def of(mesh: TriangleMesh) -> ObjectSurface:
        corners = mesh.vertices[mesh.faces]
        cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        double_area = np.linalg.norm(cross, axis=1)
        keep = double_area > 1e-12  # degenerate slivers have no normal and no area to draw from
        pairs = np.concatenate([mesh.faces[:, [0, 1]], mesh.faces[:, [1, 2]], mesh.faces[:, [2, 0]]])
        return ObjectSurface(
            vertices=np.asarray(mesh.vertices, dtype=np.float64),
            corners=corners[keep],
            normals=cross[keep] / double_area[keep, None],
            cumulative_area=np.cumsum(0.5 * double_area[keep]),
            edges=np.unique(np.sort(pairs, axis=1), axis=0),
        )

    @property
    def area(self) -> float:
        return float(self.cumulative_area[-1])

    def sample(self, rng: np.random.Generator) -> tuple[Array, Array]:
        """A point drawn uniformly over the surface (by area) and the outward normal there."""
        face = int(np.searchsorted(self.cumulative_area, rng.uniform(0.0, self.area), side="right"))
        face = min(face, len(self.cumulative_area) - 1)
        r1, r2 = rng.uniform(size=2)
        root = np.sqrt(r1)
        a, b, c = self.corners[face]
        point = (1.0 - root) * a + root * (1.0 - r2) * b + root * r2 * c
        return point, self.normals[face].copy()

    def faces_outward(self, point: Array, normal: Array) -> bool:
        """Whether the ray from `point` along `normal` leaves the object without meeting its
        surface again: a palm can face the point from outside (not, e.g., the inside wall of a
        mug or the inner side of a handle). Möller-Trumbore against every triangle."""
        origin = point + RAY_OFFSET_M * normal
        a = self.corners[:, 0]
        e1, e2 = self.corners[:, 1] - a, self.corners[:, 2] - a
        p = np.cross(normal, e2)
        det = np.einsum("ij,ij->i", e1, p)
        usable = np.abs(det) > 1e-15
        inv = np.where(usable, 1.0 / np.where(usable, det, 1.0), 0.0)
        s = origin - a
        u = np.einsum("ij,ij->i", s, p) * inv
        q = np.cross(s, e1)
        v = (q @ normal) * inv
        t = np.einsum("ij,ij->i", e2, q) * inv
        hit = usable & (u >= 0.0) & (v >= 0.0) & (u + v <= 1.0) & (t > 0.0)
        return not bool(hit.any())

    def width_across(self, point: Array, across: Array, along: Array, half_band: float) -> float:
        """The object's extent along `across` within the slab of points whose coordinate along
        `along` is within `half_band` of `point`'s: what the fingers must span when they close
        along `across` over a palm of half-width `half_band` (all unit vectors, object frame).
        Exact for the mesh: the slab's cross-section is bounded by the vertices inside it and the
        edges' crossings of its two planes."""
        heights = (self.vertices - point) @ along
        inside = self.vertices[np.abs(heights) <= half_band]
        ends = self.edges
        h0, h1 = heights[ends[:, 0]], heights[ends[:, 1]]
        crossings = [inside]
        for plane in (-half_band, half_band):
            crossing = (h0 - plane) * (h1 - plane) < 0
            t = (plane - h0[crossing]) / (h1[crossing] - h0[crossing])
            p0, p1 = self.vertices[ends[crossing, 0]], self.vertices[ends[crossing, 1]]
            crossings.append(p0 + t[:, None] * (p1 - p0))
        section = np.concatenate(crossings)
        return float(np.ptp(section @ across)) if len(section) else 0.0


def palm_axes(normal: Array, angle: float) -> Array:
    """Rotation (palm → object frame) of a palm facing the surface whose outward normal is
    `normal`: palm +z = -normal, palm +x turned by `angle` about it from a reference tangent.
    The reference is the object axis least aligned with the normal (the first of equals), so the
    frame is well defined for every normal, including the axes themselves."""
    z = -normal / np.linalg.norm(normal)
    reference = np.eye(3)[int(np.argmin(np.abs(z)))]
    x0 = reference - (reference @ z) * z
    x0 /= np.linalg.norm(x0)
    y0 = np.cross(z, x0)
    x = np.cos(angle) * x0 + np.sin(angle) * y0
    return np.column_stack([x, np.cross(z, x), z])


def random_rotation(rng: np.random.Generator) -> Array:
    """A unit quaternion (w, x, y, z), w ≥ 0, uniform over rotations: a normalised 4-D Gaussian."""
    while True:
        q = rng.normal(size=4)
        norm = float(np.linalg.norm(q))
        if norm > 1e-6:
            q /= norm
            return -q if q[0] < 0 else q
