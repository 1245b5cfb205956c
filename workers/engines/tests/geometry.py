"""Geometry checks for the object tests, written independently of `vint_engines.objects`."""

from __future__ import annotations

import numpy as np


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


def _segment_distance(p: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    edge = v - u
    t = np.clip(np.einsum("nmk,mk->nm", p - u, edge) / np.einsum("mk,mk->m", edge, edge), 0.0, 1.0)
    return np.linalg.norm(p - (u + t[..., None] * edge), axis=2)
