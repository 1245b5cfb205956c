"""The depth-noise model: seeded, finite, and invalid stays invalid."""

from __future__ import annotations

import numpy as np

from vint_engines.noise.model import NoiseModel


def scene_depth() -> np.ndarray:
    """A 0.8 m plane with a 0.5 m box in front (a depth edge) and background (0) on one side."""
    depth = np.full((48, 64), 0.8, np.float32)
    depth[10:30, 10:30] = 0.5
    depth[:, 56:] = 0.0
    return depth


def test_same_seed_gives_identical_noise() -> None:
    model = NoiseModel.parse({})
    a = model.apply(scene_depth(), np.random.default_rng(7))
    b = model.apply(scene_depth(), np.random.default_rng(7))
    assert a.dtype == np.float32 and a.shape == (48, 64)
    assert np.array_equal(a, b)


def test_different_seed_gives_different_noise() -> None:
    model = NoiseModel.parse({})
    a = model.apply(scene_depth(), np.random.default_rng(7))
    b = model.apply(scene_depth(), np.random.default_rng(8))
    assert not np.array_equal(a, b)


def test_invalid_input_stays_zero_and_output_is_finite() -> None:
    depth = scene_depth()
    depth[0, 0], depth[1, 1], depth[2, 2], depth[3, 3] = np.nan, np.inf, -1.0, 0.0
    noisy = NoiseModel.parse({"dropout": 0.0}).apply(depth, np.random.default_rng(1))
    assert np.isfinite(noisy).all()
    assert (noisy >= 0).all()
    assert noisy[0, 0] == noisy[1, 1] == noisy[2, 2] == noisy[3, 3] == 0
    assert (noisy[:, 56:] == 0).all()


def test_noise_level_follows_sigma_of_depth() -> None:
    flat = np.full((200, 200), 2.5, np.float32)
    model = NoiseModel.parse({"dropout": 0.0})
    noisy = model.apply(flat, np.random.default_rng(3))
    expected = model.sigma_base_m + model.sigma_per_m * (2.5 - 0.5)
    assert abs(float(np.std(noisy - flat)) - expected) < 0.1 * expected
    assert abs(float(np.mean(noisy - flat))) < 0.1 * expected


def test_depth_edges_and_silhouettes_become_holes() -> None:
    noisy = NoiseModel.parse({"dropout": 0.0}).apply(scene_depth(), np.random.default_rng(5))
    assert noisy[20, 9] == 0 and noisy[20, 10] == 0  # both sides of the 0.3 m step
    assert noisy[20, 55] == 0  # rim next to the background
    assert noisy[20, 20] > 0 and noisy[40, 40] > 0  # interiors survive


def test_out_of_range_and_dropout_are_invalid() -> None:
    depth = np.full((100, 100), 0.1, np.float32)
    assert (NoiseModel.parse({}).apply(depth, np.random.default_rng(0)) == 0).all()  # closer than min_range_m
    dropped = NoiseModel.parse({"dropout": 0.5}).apply(
        np.full((100, 100), 1.0, np.float32), np.random.default_rng(0)
    )
    assert 0.4 < float(np.mean(dropped == 0)) < 0.6
