"""Geometry checks for the object tests, written independently of `vint_engines.objects`."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a ⊗ b of (w, x, y, z) quaternions: the tests' own, not the engines'."""
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


def is_convex(vertices: np.ndarray, faces: np.ndarray, tolerance: float = 1e-9) -> bool:
    """A closed outward-wound mesh is convex when no vertex lies in front of any face's plane."""
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    normals = np.cross(b - a, c - a)
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    heights = normals @ vertices.T - np.einsum("ij,ij->i", normals, a)[:, None]
    return bool((heights <= tolerance).all())


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def distance_to_mesh(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unsigned distance from each point to the nearest triangle: the distance to the triangle's
    plane when the point projects inside it, else the distance to its nearest edge."""
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    best = np.full(len(points), np.inf)
    for start in range(0, len(points), 256):
        p = points[start : start + 256, None, :]  # (n, 1, 3) against (m, 3) triangles
        normal = np.cross(b - a, c - a)
        normal /= np.linalg.norm(normal, axis=1)[:, None]
        height = np.einsum("nmk,mk->nm", p - a, normal)
        foot = p - height[..., None] * normal
        inside = np.ones(height.shape, dtype=bool)
        for u, v in ((a, b), (b, c), (c, a)):
            inside &= np.einsum("nmk,mk->nm", np.cross(v - u, foot - u), normal) >= 0
        edges = np.min([_segment_distance(p, u, v) for u, v in ((a, b), (b, c), (c, a))], axis=0)
        distance = np.where(inside, np.abs(height), edges)
        best[start : start + 256] = distance.min(axis=1)
    return best


def signed_distance_to_mesh(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """`distance_to_mesh`, negative inside a closed outward-wound mesh: a point is inside when the
    mesh's winding number about it (its triangles' solid angles over 4π; Van Oosterom & Strackee's
    formula) is above one half."""
    distance = distance_to_mesh(points, vertices, faces)
    winding = np.zeros(len(points))
    for start in range(0, len(points), 256):
        a, b, c = (vertices[faces[:, k]][None] - points[start : start + 256, None, :] for k in range(3))
        la, lb, lc = (np.linalg.norm(v, axis=2) for v in (a, b, c))
        triple = np.einsum("nmk,nmk->nm", a, np.cross(b, c))
        dots = la * lb * lc + np.einsum("nmk,nmk->nm", a, b) * lc
        dots += np.einsum("nmk,nmk->nm", b, c) * la + np.einsum("nmk,nmk->nm", c, a) * lb
        winding[start : start + 256] = 2.0 * np.arctan2(triple, dots).sum(axis=1) / (4.0 * np.pi)
    return np.where(winding > 0.5, -distance, distance)


def _segment_distance(p: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    edge = v - u
    t = np.clip(np.einsum("nmk,mk->nm", p - u, edge) / np.einsum("mk,mk->m", edge, edge), 0.0, 1.0)
    return np.linalg.norm(p - (u + t[..., None] * edge), axis=2)


def rasterise_depth(points_c: np.ndarray, faces: np.ndarray, K: np.ndarray, width: int, height: int) -> Array:
    """Z-buffer of a triangle mesh given in camera coordinates (OpenCV): the depth along the optical
    axis of the nearest triangle through each pixel centre (integer pixel coordinates), inf where
    none. Triangles reaching behind the camera are skipped (the tests keep meshes in front)."""
    depth = np.full((height, width), np.inf)
    z = points_c[:, 2]
    uv = (K @ (points_c / z[:, None]).T).T[:, :2]
    for face in faces:
        if (z[face] <= 1e-6).any():
            continue
        (u0, v0), (u1, v1), (u2, v2) = uv[face]
        us = _pixel_span(u0, u1, u2, width)
        vs = _pixel_span(v0, v1, v2, height)
        if not len(us) or not len(vs):
            continue
        uu, vv = np.meshgrid(us, vs)
        area = (u1 - u0) * (v2 - v0) - (u2 - u0) * (v1 - v0)
        if abs(area) < 1e-12:
            continue
        b1 = ((uu - u0) * (v2 - v0) - (u2 - u0) * (vv - v0)) / area
        b2 = ((u1 - u0) * (vv - v0) - (uu - u0) * (v1 - v0)) / area
        b0 = 1.0 - b1 - b2
        inside = (b0 >= -1e-9) & (b1 >= -1e-9) & (b2 >= -1e-9)
        # 1/z is linear in screen space: perspective-correct depth.
        zz = 1.0 / (b0 / z[face[0]] + b1 / z[face[1]] + b2 / z[face[2]])
        block = depth[vv, uu]
        depth[vv, uu] = np.where(inside & (zz < block), zz, block)
    return depth


def _pixel_span(a: float, b: float, c: float, size: int) -> Array:
    """Integer pixel coordinates within [0, size) between the smallest and largest of a, b, c."""
    return np.arange(max(0, int(np.ceil(min(a, b, c)))), min(size - 1, int(np.floor(max(a, b, c)))) + 1)


def signed_distance_to_primitive(points: np.ndarray, kind: str, size: list[float]) -> Array:
    """Signed distance (negative inside) from points (n × 3, in the primitive's frame) to the
    surface of a MuJoCo primitive: box (half extents), sphere [r], capsule and cylinder
    [r, half length] along +z."""
    if kind == "box":
        q = np.abs(points) - np.asarray(size)
        return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)
    if kind == "sphere":
        return np.linalg.norm(points, axis=1) - size[0]
    radius, half = size
    if kind == "capsule":
        axis = np.clip(points[:, 2], -half, half)
        return np.linalg.norm(points - np.outer(axis, [0.0, 0.0, 1.0]), axis=1) - radius
    if kind == "cylinder":
        dx = np.hypot(points[:, 0], points[:, 1]) - radius
        dz = np.abs(points[:, 2]) - half
        return np.minimum(np.maximum(dx, dz), 0.0) + np.hypot(np.maximum(dx, 0.0), np.maximum(dz, 0.0))
    raise ValueError(kind)
