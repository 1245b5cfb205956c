"""The depth camera's own viewpoint and the depth engine's smoothing, against geometry and
statistics computed here: a bar in front of a wall casts an occlusion shadow of the width the
baseline's parallax gives, on the side away from the ToF camera, and none on the other side; a
plain wall loses nothing; the smoothed noise keeps its σ per pixel and correlates between
neighbours as exp(-r² / 4σ²)."""

from __future__ import annotations

import math

import numpy as np

from vint_engines.noise.geometry import Intrinsics
from vint_engines.noise.model import NoiseModel, correlated

QUIET = {
    "lateral": False,
    "flying_pixels": False,
    "multipath": False,
    "materials": False,
    "sigma_scale": 0.0,
}
F = 500.0  # px
H, W = 120, 200
K = Intrinsics(F, F, (W - 1) / 2, (H - 1) / 2)
WALL_M, BAR_M = 0.9, 0.6  # inside the default mode's 0.5–3.86 m range
BAR_COLS = slice(90, 110)


def wall_and_bar() -> np.ndarray:
    depth = np.full((H, W), WALL_M, np.float32)
    depth[:, BAR_COLS] = BAR_M
    return depth


def registered(depth: np.ndarray, baseline_m: float) -> np.ndarray:
    model = NoiseModel.parse({**QUIET, "registration": True, "tof_baseline_m": baseline_m})
    return model.apply(depth, K, None, np.random.default_rng(0))


def test_a_plain_wall_is_seen_whole() -> None:
    wall = np.full((H, W), WALL_M, np.float32)
    assert (registered(wall, 0.032) > 0).mean() > 0.999


def test_a_bar_casts_the_shadow_the_baseline_gives_on_the_side_away_from_the_tof() -> None:
    baseline = 0.032
    out = registered(wall_and_bar(), baseline)
    # Parallax: seen from a camera `baseline` to the right (+x), the bar's left edge hides the wall
    # over f·b·(1/z_bar - 1/z_wall) pixels to its left.
    expected_px = F * baseline * (1 / BAR_M - 1 / WALL_M)
    row = out[H // 2]
    left_gap = int(np.count_nonzero(row[: BAR_COLS.start] == 0))
    right_gap = int(np.count_nonzero(row[BAR_COLS.stop :] == 0))
    assert abs(left_gap - expected_px) <= 2.0, (left_gap, expected_px)
    assert right_gap <= 1, right_gap
    assert np.all(row[BAR_COLS] == BAR_M), "the bar itself is seen"
    # No baseline, no shadow.
    assert np.count_nonzero(registered(wall_and_bar(), 0.0)[H // 2] == 0) <= 1


def test_switched_off_nothing_is_lost() -> None:
    model = NoiseModel.parse({**QUIET, "registration": False})
    out = model.apply(wall_and_bar(), K, None, np.random.default_rng(0))
    assert np.array_equal(out, wall_and_bar())


def autocorrelation(field: np.ndarray, lag: int) -> float:
    a, b = field[:, :-lag].ravel(), field[:, lag:].ravel()
    return float(np.corrcoef(a, b)[0, 1])


def test_smoothed_noise_keeps_unit_variance_and_correlates_as_stated() -> None:
    white = np.random.default_rng(4).standard_normal((400, 400)).astype(np.float32)
    for sigma in (0.8, 1.5, 3.0):
        field = correlated(white, sigma)[20:-20, 20:-20]
        assert abs(float(field.std()) - 1.0) < 0.05, (sigma, field.std())
        for lag in (1, 2, 4):
            expected = math.exp(-(lag**2) / (4 * sigma**2))
            assert abs(autocorrelation(field, lag) - expected) < 0.04, (sigma, lag)
    assert correlated(white, 0.0) is white


def test_the_residual_of_the_model_correlates_over_the_stated_native_pixels() -> None:
    """On a wall at 0.9 m, the noisy - clean residual's lag-1 correlation is what `spatial_sigma_px`
    native pixels give at this camera's output pixels per native pixel."""
    wall = np.full((300, 300), WALL_M, np.float32)
    k = Intrinsics(F, F, 149.5, 149.5)
    fields = {**QUIET, "sigma_scale": 1.0, "registration": False}
    model = NoiseModel.parse({**fields, "spatial_sigma_px": 1.0})
    residual = (model.apply(wall, k, None, np.random.default_rng(2)) - wall)[10:-10, 10:-10]
    sigma_out = 1.0 * model.mode.pixel_angle_rad * F
    assert abs(autocorrelation(residual, 1) - math.exp(-1 / (4 * sigma_out**2))) < 0.04
    white = NoiseModel.parse({**fields, "spatial_sigma_px": 0.0})
    residual = (white.apply(wall, k, None, np.random.default_rng(2)) - wall)[10:-10, 10:-10]
    assert abs(autocorrelation(residual, 1)) < 0.03
