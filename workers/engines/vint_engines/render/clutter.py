"""Distractor objects: other catalog objects standing on the table around the grasp, as on a real
bench, where the hand lifts one object from among others.

`render.scene.distractors = N` (default 0) stands up to N catalog objects other than the grasped
one on the table top, each in its own resting pose (`objects/rest.py`: as modelled when that is
stable, else on a side) turned about the vertical by a uniform angle. They stand outside the
grasp's footprint — the horizontal circle about the object's centre that holds the object, the
hand and the arm's pieces — by at least `GAP_M`, at most `REACH_M` beyond it, `GAP_M` apart from
one another and wholly on the table top, so they never touch the hand, the object or each other.
The layout belongs to the grasp, not the view: it is drawn from the grasp's trial seed on a stream
of its own (`DISTRACTOR_STREAM`), so every view of a grasp sees the same bench, and the same
layout comes from any worker. A distractor that finds no free place in `ATTEMPTS` draws is left
out (the camera record lists the ones that stand). Pure numpy: no Blender import here.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from vint_engines.poses import quat_multiply

Array = npt.NDArray[np.float64]

DISTRACTOR_STREAM = 0x3D  # appended to the trial's seed: the layout's own random stream
GAP_M = 0.02  # clear space between two footprints, and between a distractor and the grasp's
REACH_M = 0.25  # the farthest a distractor's edge stands beyond the grasp's footprint (+ GAP_M)
ATTEMPTS = 64  # draws per distractor before it is left out


@dataclass(frozen=True)
class Footprint:
    """How a catalog object rests (`objects.rest.RestPose`): its orientation, the height of its
    origin above the surface it stands on, and its horizontal radius about that origin."""

    quat: tuple[float, float, float, float]  # (w, x, y, z)
    height: float
    radius: float


@dataclass(frozen=True)
class Placed:
    """One distractor standing on the table: catalog name and world pose."""

    name: str
    position: tuple[float, float, float]
    quat: tuple[float, float, float, float]  # (w, x, y, z)

    def to_json(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "p": [round(v, 9) + 0.0 for v in self.position],
            "q": [round(v, 12) + 0.0 for v in self.quat],
        }


def place(
    seed: int,
    names: Sequence[str],
    footprint: Callable[[str], Footprint],
    count: int,
    centre: tuple[float, float],
    keep_out: float,
    table_top_z: float,
    table_half: tuple[float, float],
) -> list[Placed]:
    """Up to `count` of `names` standing on the table top at `table_top_z`, whose centre is
    `centre` and half-size `table_half`, outside the grasp's footprint of radius `keep_out` about
    `centre`. Candidates are tried in a seeded order; `footprint(name)` is asked only for those
    tried."""
    if count <= 0 or not names:
        return []
    rng = np.random.default_rng([seed, DISTRACTOR_STREAM])
    order = rng.permutation(len(names))
    placed: list[tuple[Placed, float]] = []
    for index in order:
        if len(placed) == count:
            break
        name = names[int(index)]
        rest = footprint(name)
        for _ in range(ATTEMPTS):
            angle, reach, yaw = rng.uniform(0.0, 1.0, size=3)
            distance = keep_out + GAP_M + rest.radius + reach * REACH_M
            x = centre[0] + distance * math.cos(2 * math.pi * angle)
            y = centre[1] + distance * math.sin(2 * math.pi * angle)
            if (
                abs(x - centre[0]) > table_half[0] - rest.radius
                or abs(y - centre[1]) > table_half[1] - rest.radius
            ):
                continue
            if any(math.dist((x, y), other.position[:2]) < rest.radius + r + GAP_M for other, r in placed):
                continue
            turn = (math.cos(math.pi * yaw), 0.0, 0.0, math.sin(math.pi * yaw))  # yaw·2π about +z
            quat = quat_multiply(turn, rest.quat)
            placed.append((Placed(name, (x, y, table_top_z + rest.height), quat), rest.radius))
            break
    return [stand for stand, _ in placed]
