"""How an object rests on the ground before a grasp, chosen deterministically from its mesh.

An object stands as modelled (+z up) when that is stable: its centre of mass lies over its support
polygon with a tipping angle of at least `MIN_TIPPING_DEG`. Otherwise it is laid on a side (a
quarter turn about x or y, or upside down): the stable candidate with the lowest centre of mass,
or, when none is stable (e.g. a cylinder on its side rests on a line), the lowest one. Candidates
are tried in a fixed order, so ties always resolve the same way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vint_engines.objects.tessellate import Array

MIN_TIPPING_DEG = 10.0
SUPPORT_BAND_M = 5e-4  # vertices this close to the lowest one carry the object

# (w, x, y, z) unit quaternions: as modelled, quarter turns about +x, -x, +y, -y, half turn about x.
_H = math.sqrt(0.5)
CANDIDATES: tuple[tuple[float, float, float, float], ...] = (
    (1.0, 0.0, 0.0, 0.0),
    (_H, _H, 0.0, 0.0),
    (_H, -_H, 0.0, 0.0),
    (_H, 0.0, _H, 0.0),
    (_H, 0.0, -_H, 0.0),
    (0.0, 1.0, 0.0, 0.0),
)


@dataclass(frozen=True)
class RestPose:
    """The object's orientation on the ground and what a grasp planner needs about it."""

    quat: tuple[float, float, float, float]  # (w, x, y, z) of the object frame in the world
    height: float  # z of the object's origin
    top: float  # height of the object's highest point
    radius: float  # largest horizontal distance of the object from its origin's vertical
    tipping_deg: float  # how far it can tilt before it falls over (0 on a line or point)


def rest_pose(vertices: Array, centroid: Array) -> RestPose:
    poses = [_resting(vertices, centroid, quat) for quat in CANDIDATES]
    if poses[0].tipping_deg >= MIN_TIPPING_DEG:
        return poses[0]
    stable = [pose for pose in poses if pose.tipping_deg >= MIN_TIPPING_DEG]
    return min(stable or poses, key=lambda pose: _com_height(pose, vertices, centroid))


def _com_height(pose: RestPose, vertices: Array, centroid: Array) -> float:
    return float(_rotate(centroid[None, :], pose.quat)[0, 2] + pose.height)


def _resting(vertices: Array, centroid: Array, quat: tuple[float, float, float, float]) -> RestPose:
    points = _rotate(vertices, quat)
    com = _rotate(centroid[None, :], quat)[0]
    bottom = float(points[:, 2].min())
    support = points[points[:, 2] <= bottom + SUPPORT_BAND_M, :2]
    margin = _inside_margin(convex_hull_2d(support), com[:2])
    tipping = math.degrees(math.atan2(max(margin, 0.0), com[2] - bottom))
    return RestPose(
        quat=quat,
        height=-bottom,
        top=float(points[:, 2].max()) - bottom,
        radius=float(np.hypot(points[:, 0], points[:, 1]).max()),
        tipping_deg=tipping,
    )


def _rotate(points: Array, quat: tuple[float, float, float, float]) -> Array:
    w, x, y, z = quat
    matrix = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    return points @ matrix.T


def convex_hull_2d(points: Array) -> Array:
    """Counter-clockwise hull (Andrew's monotone chain); fewer than 3 rows when degenerate."""
    unique = np.unique(np.round(points, 12), axis=0)
    if len(unique) < 3:
        return unique

    def half(sequence: Array) -> list[Array]:
        chain: list[Array] = []
        for p in sequence:
            while len(chain) >= 2 and _cross(chain[-2], chain[-1], p) <= 0:
                chain.pop()
            chain.append(p)
        return chain

    lower, upper = half(unique), half(unique[::-1])
    return np.array(lower[:-1] + upper[:-1])


def _cross(o: Array, a: Array, b: Array) -> float:
    return float((a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]))


def _inside_margin(hull: Array, point: Array) -> float:
    """Distance from `point` to the nearest hull edge, negative outside; 0 for a degenerate hull."""
    if len(hull) < 3:
        return 0.0
    margins = []
    for a, b in zip(hull, np.roll(hull, -1, axis=0), strict=True):
        edge = b - a
        margins.append(_cross(a, b, point) / float(np.hypot(*edge)))
    return min(margins)
