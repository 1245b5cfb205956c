"""Viewpoint control: a sampled view's camera is redrawn — seeded and bounded — until the share of
the object the hand hides lies within the spec's `occlusion` range and, with `palm_side = "front"`,
the camera stands in front of the palm's plane.

Attempt 0 draws from the view's seed exactly as a view always has; attempt k ≥ 1 from the seed with
`REDRAW_STREAM` and k appended, so attempt k is a pure function of (seed, k) and a view renders the
same camera whatever task, worker or order renders it. The palm side is checked on the drawn pose
alone (no render); occlusion needs the geometry passes (one ray per pixel, no path tracing), so a
rejected attempt never costs an RGB render. After `MAX_CAMERA_ATTEMPTS` without a camera that meets
the rules, the view keeps the attempt nearest to them — first the palm side, then the distance of
its occlusion from the range — and its record says it is out of range: a view is never dropped
(its grasp keeps its views), and a dataset's checks can find every such view.

Pure numpy over what the caller measures: no Blender import here.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from vint_engines.render.camera import CameraPose, Mat

# Cameras a sampled view draws at most before it keeps the best one. At the tiny run's views about
# one attempt in four misses the paper's 10-90 % (docs/rendering.md), so 32 misses all in a row with
# odds of ~1e-19 unless the grasp itself makes the range unreachable.
MAX_CAMERA_ATTEMPTS = 32
REDRAW_STREAM = 0x0C  # appended to the view's seed with the attempt number (k >= 1)

PalmRule = Literal["any", "front"]


@dataclass(frozen=True)
class ViewpointRule:
    """What a sampled camera must meet: the occlusion range [min, max] and the palm side."""

    occlusion: tuple[float, float]
    palm_side: PalmRule = "any"

    def occlusion_miss(self, occlusion: float) -> float:
        """How far `occlusion` lies outside the range; 0 inside it (the ends included)."""
        low, high = self.occlusion
        return max(0.0, low - occlusion, occlusion - high)


@dataclass(frozen=True)
class Palm:
    """The palm's origin and its normal (the palm frame's +z, towards the object) in the world."""

    point: Mat
    normal: Mat

    def facing(self, camera: CameraPose) -> float:
        """The cosine between the palm normal and the direction from the palm to the camera: > 0
        in front of the palm's plane, < 0 behind it (the back of the hand)."""
        offset = camera.position - self.point
        distance = float(np.linalg.norm(offset))
        return 0.0 if distance == 0.0 else float(np.dot(offset, self.normal) / distance)


@dataclass(frozen=True)
class Viewpoint[G]:
    """The camera a view renders from, what its geometry passes saw, and how it was chosen."""

    camera: CameraPose
    geometry: G
    occlusion: float  # exact: 1 - visible / full
    attempts: int  # cameras drawn
    renders: int  # geometry passes run to choose it (the chosen camera's included)
    sampled: bool  # False: the task gave the camera
    occlusion_in_range: bool
    palm_facing: float | None  # None: the hand has no palm pose

    def record(self, rule: ViewpointRule) -> dict[str, Any]:
        """camera.json's `viewpoint`."""
        side = None if self.palm_facing is None else ("front" if self.palm_facing >= 0.0 else "back")
        return {
            "source": "sampled" if self.sampled else "given",
            "attempts": self.attempts,
            "renders": self.renders,
            "occlusion_range": list(rule.occlusion),
            "occlusion_in_range": self.occlusion_in_range,
            "palm_rule": rule.palm_side,
            "palm_side": side,
            "palm_facing": None if self.palm_facing is None else round(self.palm_facing, 6),
        }


def attempt_rng(seed: int, attempt: int) -> np.random.Generator:
    """The random stream of a view's camera attempt: the view's own seed for attempt 0 (the camera
    a view drew before redraws existed), the seed with `REDRAW_STREAM` and `attempt` after."""
    return np.random.default_rng(seed if attempt == 0 else [seed, REDRAW_STREAM, attempt])


def occlusion_share(visible_px: int, full_px: int) -> float:
    """1 - visible/full: the share of the object the hand hides; 1 when none of it is in view."""
    return 1.0 if full_px == 0 else 1.0 - visible_px / full_px


def given[G](
    camera: CameraPose,
    measure: Callable[[CameraPose], tuple[G, float]],
    rule: ViewpointRule,
    palm: Palm | None,
) -> Viewpoint[G]:
    """A camera the task gave: rendered as is, its occlusion reported against the range."""
    geometry, occlusion = measure(camera)
    facing = None if palm is None else palm.facing(camera)
    return Viewpoint(camera, geometry, occlusion, 1, 1, False, rule.occlusion_miss(occlusion) == 0.0, facing)


def search[G](
    draw: Callable[[int], CameraPose],
    measure: Callable[[CameraPose], tuple[G, float]],
    rule: ViewpointRule,
    palm: Palm | None,
    max_attempts: int = MAX_CAMERA_ATTEMPTS,
) -> Viewpoint[G]:
    """The first of attempts 0, 1, … (`draw(k)`) that meets `rule`, measured by `measure` (the
    geometry passes and their occlusion); after `max_attempts` the nearest miss (see the module)."""
    if rule.palm_side == "front" and palm is None:
        raise ValueError("palm_side 'front' needs the palm's pose")
    best: tuple[tuple[float, float], int, CameraPose, tuple[G, float] | None] | None = None
    renders = 0
    for attempt in range(max_attempts):
        camera = draw(attempt)
        facing = None if palm is None else palm.facing(camera)
        palm_miss = max(0.0, -facing) if rule.palm_side == "front" and facing is not None else 0.0
        measured: tuple[G, float] | None = None
        occlusion_miss = math.inf
        if palm_miss == 0.0:
            measured = measure(camera)
            renders += 1
            occlusion_miss = rule.occlusion_miss(measured[1])
            if occlusion_miss == 0.0:
                return Viewpoint(camera, measured[0], measured[1], attempt + 1, renders, True, True, facing)
        key = (palm_miss, occlusion_miss)
        if best is None or key < best[0]:
            best = (key, attempt, camera, measured)
    if best is None:
        raise ValueError("max_attempts must be at least 1")
    (_, occlusion_miss), _, camera, measured = best
    if measured is None:  # every attempt stood behind the palm: render the nearest one
        measured = measure(camera)
        renders += 1
        occlusion_miss = rule.occlusion_miss(measured[1])
    facing = None if palm is None else palm.facing(camera)
    geometry, occlusion = measured
    return Viewpoint(camera, geometry, occlusion, max_attempts, renders, True, occlusion_miss == 0.0, facing)
