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


def test_framing_puts_the_object_off_centre_inside_the_frame_and_barely_rolls() -> None:
    """The object's centre lands over the allowed part of the image (not always near the centre),
    its bounding sphere's image stays inside the frame, the camera stays where it was, and world
    up stays near image up. Projections here use a pinhole written out in the test."""
    from vint_engines.render.camera import FRAME_MARGIN, Intrinsics, framed

    intrinsics = Intrinsics(640, 480, 60.0)
    f = (640 / 2) / math.tan(math.radians(30.0))
    cx, cy = 319.5, 239.5
    target, radius = np.array([0.0, 0.0, 0.05]), 0.06
    offsets, rolls = [], []
    for seed in range(300):
        rng = np.random.default_rng(seed)
        camera = sample_on_hemisphere(rng, target, (0.5, 0.65), (15.0, 75.0), (0.0, 0.0))
        turned = framed(rng, camera, target, radius, intrinsics, 0.6)
        np.testing.assert_allclose(turned.position, camera.position, atol=1e-12)
        np.testing.assert_allclose(turned.R_w2c @ turned.R_w2c.T, np.eye(3), atol=1e-12)
        c = turned.R_w2c @ target + turned.t_w2c
        u, v = f * c[0] / c[2] + cx, f * c[1] / c[2] + cy
        # The sphere's image: every point of its silhouette inside the frame, less the margin.
        rim = f * math.tan(math.asin(radius / np.linalg.norm(c)))
        margin = FRAME_MARGIN * 240
        assert rim + margin - 1.0 <= u + 0.5 <= 640 - rim - margin + 1.0, (seed, u)
        assert rim + margin - 1.0 <= v + 0.5 <= 480 - rim - margin + 1.0, (seed, v)
        offsets.append(((u - cx) / 320, (v - cy) / 240))
        rolls.append(image_angle(turned.R_w2c, turned.t_w2c, target + np.array([0.0, 0.0, 0.05]), target))
    offsets_ = np.array(offsets)
    assert np.abs(offsets_).max() > 0.45, "the object reaches well off the centre"
    assert np.mean(np.hypot(*offsets_.T) < 0.05) < 0.05, "and is rarely centred"
    # World up (a point above the target) reads as image up within the framing's small turn.
    assert np.percentile(np.abs(np.array(rolls) - math.pi / 2), 95) < math.radians(25)


def test_framing_with_no_offcentre_changes_nothing_but_draws_the_same() -> None:
    from vint_engines.render.camera import Intrinsics, framed

    rng_a, rng_b = np.random.default_rng(3), np.random.default_rng(3)
    camera = sample_on_hemisphere(rng_a, np.zeros(3), (0.5, 0.6), (15.0, 75.0))
    sample_on_hemisphere(rng_b, np.zeros(3), (0.5, 0.6), (15.0, 75.0))
    same = framed(rng_a, camera, np.zeros(3), 0.05, Intrinsics(128, 128, 50.0), 0.0)
    assert same is camera
    framed(rng_b, camera, np.zeros(3), 0.05, Intrinsics(128, 128, 50.0), 0.5)
    assert rng_a.uniform() == rng_b.uniform(), "both consumed two draws"
