"""Sampled cameras: the roll about the optical axis turns the image, nothing else."""

from __future__ import annotations

import math

import numpy as np

from vint_engines.render.camera import look_at, rolled, sample_on_hemisphere


def image_angle(R: np.ndarray, t: np.ndarray, point: np.ndarray, centre: np.ndarray) -> float:
    """Direction (radians, counter-clockwise on screen) of `point` seen from the image of `centre`,
    projected with a pinhole of focal length 1 — independent of the camera module."""

    def project(p: np.ndarray) -> np.ndarray:
        c = R @ p + t
        return c[:2] / c[2]

    du, dv = project(point) - project(centre)
    return math.atan2(-dv, du)  # image y points down


def test_a_roll_keeps_the_position_and_optical_axis_and_turns_the_image() -> None:
    target = np.array([0.1, -0.2, 0.3])
    camera = look_at(np.array([0.6, 0.1, 0.5]), target)
    above = target + np.array([0.0, 0.0, 0.05])
    for angle in (0.3, -2.0, math.pi):
        turned = rolled(camera, angle)
        np.testing.assert_allclose(turned.R_w2c @ turned.R_w2c.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(turned.R_w2c) > 0
        np.testing.assert_allclose(turned.position, camera.position, atol=1e-12)
        np.testing.assert_allclose(turned.R_w2c[2], camera.R_w2c[2], atol=1e-12)
        before = image_angle(camera.R_w2c, camera.t_w2c, above, target)
        after = image_angle(turned.R_w2c, turned.t_w2c, above, target)
        # Counter-clockwise by the roll, modulo a full turn.
        assert abs(math.remainder(after - before - angle, 2 * math.pi)) < 1e-9


def test_without_a_roll_cameras_are_where_they_were_and_with_one_world_up_spreads_over_the_circle() -> None:
    target = np.zeros(3)
    up = target + np.array([0.0, 0.0, 0.05])
    plain, turned = [], []
    for seed in range(200):
        a = sample_on_hemisphere(np.random.default_rng(seed), target, (0.35, 0.5), (15.0, 75.0))
        b = sample_on_hemisphere(
            np.random.default_rng(seed), target, (0.35, 0.5), (15.0, 75.0), (-180.0, 180.0)
        )
        np.testing.assert_allclose(a.position, b.position, atol=1e-12)
        plain.append(image_angle(a.R_w2c, a.t_w2c, up, target))
        turned.append(image_angle(b.R_w2c, b.t_w2c, up, target))
    # World up stays image up without a roll; with the full roll it points every way.
    assert max(abs(x - math.pi / 2) for x in plain) < 0.2
    bins = np.histogram(np.array(turned), bins=12, range=(-math.pi, math.pi))[0]
    assert (bins > 0).all(), bins
