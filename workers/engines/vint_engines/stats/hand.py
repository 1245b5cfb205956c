"""Statistics in the hand's own frame: where the object sits in the palm (the in-hand pose
distribution, one per accepted grasp) and from which side of the palm each camera looks.

The palm frame is the hand's root body's (docs/hands.md): +z the palm normal, towards the object;
+y "up" across the palm; +x across the fingers. A statistic whose poses a layout does not carry is
None ("unavailable"), never filled in.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from vint_engines.stats.dataset import Array, Grasp, View
from vint_engines.stats.summaries import DECIMALS, histogram, summary

MM_PER_M = 1000.0
# palm_facing = sin(elevation above the palm plane): bins of equal height in it are bands of equal
# area on the sphere of directions (as the orientation map's), so an even spread looks even.
PALM_FACING_BINS = 10
AXES = ("x", "y", "z")


def object_position_mm(grasp: Grasp) -> Array:
    """The object frame's origin (the model's bounding-box centre) in the palm frame, mm."""
    assert grasp.object_in_palm is not None
    return MM_PER_M * grasp.object_in_palm.t


def object_z_cos(grasp: Grasp) -> float:
    """Cosine between the object's +z axis and the palm normal: the object's z axis in the palm
    frame is R's third column, its palm-normal component R[2, 2]. 1: the object's z along the
    normal, 0: lying in the palm plane, -1: pointing into the palm."""
    assert grasp.object_in_palm is not None
    return float(grasp.object_in_palm.R[2, 2])


def camera_in_palm(view: View) -> Array:
    """The camera centre in the palm frame (metres): -Rᵀ t of the palm's pose in the camera."""
    assert view.palm_to_camera is not None
    return view.palm_to_camera.inverse().t


def palm_facing(view: View) -> float:
    """Cosine between the palm normal and the direction from the palm frame's origin to the camera
    (the render's `viewpoint.palm_facing`): > 0 sees the palm's front, < 0 its back; it is also
    sin of the camera's elevation above the palm plane."""
    centre = camera_in_palm(view)
    return float(centre[2] / np.linalg.norm(centre))


def side(facing: float) -> str:
    """As the renderer names it (render/viewpoint.py): the plane itself counts as the front."""
    return "front" if facing >= 0.0 else "back"


def in_hand_stats(
    grasps: Sequence[Grasp], hands: Sequence[str], objects: Sequence[str]
) -> dict[str, Any] | None:
    """Per accepted grasp, the object's pose in the palm frame: position (mm) per axis and its
    distance from the palm frame's origin, and the object z axis' cosine with the palm normal;
    in all, per hand, per object and per (object, hand) pair. None when no grasp has it."""
    posed = [g for g in grasps if g.object_in_palm is not None]
    if not posed:
        return None

    def group(selected: Sequence[Grasp]) -> dict[str, Any]:
        positions = [object_position_mm(g) for g in selected]
        return {
            "grasps": len(selected),
            **{f"{axis}_mm": summary([float(p[i]) for p in positions]) for i, axis in enumerate(AXES)},
            "distance_mm": summary([float(np.linalg.norm(p)) for p in positions]),
            "object_z_cos": summary([object_z_cos(g) for g in selected]),
        }

    pairs = sorted({(g.object, g.hand) for g in posed})
    return {
        "frame": "palm: +z the palm normal towards the object, +y up across the palm (docs/hands.md)",
        "grasps_without_pose": len(grasps) - len(posed),
        "all": group(posed),
        "by_hand": {h: group([g for g in posed if g.hand == h]) for h in hands},
        "by_object": {o: group([g for g in posed if g.object == o]) for o in objects},
        "by_pair": [
            {"object": o, "hand": h, **group([g for g in posed if (g.object, g.hand) == (o, h)])}
            for o, h in pairs
        ],
    }


def camera_stats(views: Sequence[View], hands: Sequence[str]) -> dict[str, Any] | None:
    """Per view, where the camera looks from relative to the palm: palm_facing binned in tenths of
    [-1, 1], the front/back split and the elevation above the palm plane (degrees); in all and per
    hand. None when no view has the palm's pose."""
    posed = [v for v in views if v.palm_to_camera is not None]
    if not posed:
        return None
    edges = [round(-1.0 + 2.0 * k / PALM_FACING_BINS, DECIMALS) for k in range(PALM_FACING_BINS + 1)]

    def group(selected: Sequence[View]) -> dict[str, Any]:
        facing = [palm_facing(v) for v in selected]
        sides = [side(f) for f in facing]
        return {
            "samples": len(selected),
            "front": sides.count("front"),
            "back": sides.count("back"),
            "counts": histogram(facing, edges),
            "palm_facing": summary(facing),
            "elevation_deg": summary([math.degrees(math.asin(max(-1.0, min(1.0, f)))) for f in facing]),
        }

    return {
        "direction": "palm frame origin to camera centre, palm frame; palm_facing = its z component",
        "edges": edges,
        "samples_without_pose": len(views) - len(posed),
        "all": group(posed),
        "by_hand": {h: group([v for v in posed if v.hand == h]) for h in hands},
    }
