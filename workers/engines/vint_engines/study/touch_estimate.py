"""One view's two estimates: ICP from a perturbed pose on (a) the visible depth alone and (b) the
same depth plus the active taxels.

The choices, all stated in the study's report:
- start: the true pose turned by 15–30° (uniform) about a uniformly random axis through the model
  origin, and shifted 20–40 mm (uniform) in a uniformly random direction; drawn from the job seed
  and the sample id, so both variants start from the same pose;
- depth: the noisy depth (`depth_noisy.npy`, what a sensor gives), visible-mask pixels only,
  subsampled to at most VISION_POINTS;
- touch: every active taxel, each weighing TAXEL_WEIGHT depth points (inverse variance: see the
  constant), never dropped by the outlier gate — a taxel is on the surface by construction;
- guards: under MIN_POINTS usable points the start pose is returned (`too_few_points`); no
  active taxel makes (b) a copy of (a) (`no_taxels`); a singular system is flagged `degenerate`
  and never raises.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from vint_engines.study.icp import IcpResult, Surface, icp, rotation_from_vector
from vint_engines.study.touch_inputs import View, sample_rng

Array = npt.NDArray[np.float64]

VISION_POINTS = 300
# Per-point residuals at the true pose, measured on the study's quick data (point-to-plane distance
# to the model): noisy depth median 0.67 mm (σ ≈ 1.0 mm), taxels median 0.21 mm (σ ≈ 0.31 mm, the
# skin's 0.5 mm contact margin). Inverse-variance weighting gives a taxel (1.0 / 0.31)² ≈ 10 depth
# points: ~10 taxels then carry about a quarter of a 300-point cloud's weight — enough to matter,
# not enough for one misplaced taxel to outvote the camera.
TAXEL_WEIGHT = 10.0
MIN_POINTS = 3
ROTATION_DEG = (15.0, 30.0)
TRANSLATION_MM = (20.0, 40.0)

VISION = "vision"
VISION_TOUCH = "vision_touch"
VARIANTS = (VISION, VISION_TOUCH)


@dataclass(frozen=True)
class Estimate:
    variant: str
    R: Array
    t: Array  # mm
    vision_points: int
    taxels: int
    guard: str  # "", "too_few_points", "no_taxels"
    iterations: int
    converged: bool
    degenerate: bool
    cpu_ms: float
    wall_ms: float


def start_pose(view: View, seed: int) -> tuple[Array, Array]:
    """The perturbed pose both variants start from (model → camera, mm)."""
    rng = sample_rng(seed, view.sample_id, "touch-study-start")
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    turn = rotation_from_vector(axis * math.radians(rng.uniform(*ROTATION_DEG)))
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    return turn @ view.R_gt, view.t_gt_mm + direction * rng.uniform(*TRANSLATION_MM)


def subsample(points: Array, count: int, rng: np.random.Generator) -> Array:
    if len(points) <= count:
        return points
    return points[np.sort(rng.choice(len(points), size=count, replace=False))]


@dataclass(frozen=True)
class ViewEstimates:
    start_R: Array
    start_t: Array  # mm
    by_variant: dict[str, Estimate]


def estimate_view(view: View, surface: Surface, seed: int) -> ViewEstimates:
    """Both variants' estimates of one view, from the same start."""
    R0, t0 = start_pose(view, seed)
    vision = subsample(
        view.vision_mm, VISION_POINTS, sample_rng(seed, view.sample_id, "touch-study-subsample")
    )
    a = _fit(VISION, vision, np.zeros((0, 3)), surface, R0, t0)
    if len(view.touch_mm) == 0:
        b = dataclasses.replace(a, variant=VISION_TOUCH, guard=a.guard or "no_taxels")
    else:
        b = _fit(VISION_TOUCH, vision, view.touch_mm, surface, R0, t0)
    return ViewEstimates(start_R=R0, start_t=t0, by_variant={VISION: a, VISION_TOUCH: b})


def _fit(variant: str, vision: Array, touch: Array, surface: Surface, R0: Array, t0: Array) -> Estimate:
    points = np.vstack([vision, touch])
    weights = np.concatenate([np.ones(len(vision)), np.full(len(touch), TAXEL_WEIGHT)])
    gated = np.concatenate([np.ones(len(vision), dtype=bool), np.zeros(len(touch), dtype=bool)])
    common = {"variant": variant, "vision_points": len(vision), "taxels": len(touch)}
    if len(points) < MIN_POINTS:
        return Estimate(
            **common,
            R=R0,
            t=t0,
            guard="too_few_points",
            iterations=0,
            converged=False,
            degenerate=True,
            cpu_ms=0.0,
            wall_ms=0.0,
        )
    wall, cpu = time.perf_counter(), time.thread_time()
    result: IcpResult = icp(points, weights, gated, surface, R0, t0)
    cpu, wall = time.thread_time() - cpu, time.perf_counter() - wall
    return Estimate(
        **common,
        R=result.R,
        t=result.t,
        guard="",
        iterations=result.iterations,
        converged=result.converged,
        degenerate=result.degenerate,
        cpu_ms=cpu * 1000.0,
        wall_ms=wall * 1000.0,
    )
