"""The touch-vs-vision study's estimator and scorer on constructed cases with known answers.

Errors are computed here from their definitions (not with `pose_scores`), and poses are built from
axis-angle by hand, so the tests do not trust the code under test to check itself.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from vint_engines.study import pose_scores
from vint_engines.study.icp import icp, sample_surface
from vint_engines.study.touch_estimate import (
    TAXEL_WEIGHT,
    VISION,
    VISION_TOUCH,
    estimate_view,
    start_pose,
)
from vint_engines.study.touch_inputs import View, back_project, taxels_in_camera
from vint_engines.study.touch_report import bucket, finding

# A box 80 × 50 × 30 mm (no two sides alike, so its pose is unique), centred on the origin,
# triangles wound outward.
HALF = np.array([40.0, 25.0, 15.0])
CORNERS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float) * HALF
QUADS = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
FACES = np.array([t for a, b, c, d in QUADS for t in ((a, b, c), (a, c, d))], dtype=np.int64)


def axis_angle(axis: list[float], degrees: float) -> np.ndarray:
    k = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    a = math.radians(degrees)
    return np.eye(3) * math.cos(a) + math.sin(a) * kx + (1 - math.cos(a)) * np.outer(k, k)


def add_error(points: np.ndarray, R: np.ndarray, t: np.ndarray, R_gt: np.ndarray, t_gt: np.ndarray) -> float:
    """ADD by its definition, one point at a time."""
    return float(np.mean([np.linalg.norm((R @ x + t) - (R_gt @ x + t_gt)) for x in points]))


def box_surface(count: int = 3000, seed: int = 0):
    return sample_surface(CORNERS, FACES, count, np.random.default_rng(seed))


def box_view(vision: np.ndarray, touch: np.ndarray, R_gt: np.ndarray, t_gt: np.ndarray) -> View:
    return View(
        sample_id="box.hand.g000000.v00", grasp_id="box.hand.g000000", object="box", hand="hand", view=0,
        occlusion=0.5, visible_px=len(vision), R_gt=R_gt, t_gt_mm=t_gt, vision_mm=vision, touch_mm=touch,
    )  # fmt: skip


R_TRUE = axis_angle([0.3, -0.5, 0.8], 40.0)
T_TRUE = np.array([12.0, -7.0, 400.0])


def test_surface_samples_lie_on_the_box_with_outward_normals() -> None:
    s = box_surface()
    # Every sample is on a face: one coordinate at ±half, the others within.
    on_face = np.isclose(np.abs(s.points), HALF, atol=1e-9)
    assert (on_face.sum(axis=1) >= 1).all() and (np.abs(s.points) <= HALF + 1e-9).all()
    # A sample's normal points out of its face (same sign as the coordinate at ±half).
    face_axis = np.argmax(on_face, axis=1)
    rows = np.arange(len(s.points))
    assert np.allclose(np.abs(s.normals[rows, face_axis]), 1.0)
    assert (np.sign(s.normals[rows, face_axis]) == np.sign(s.points[rows, face_axis])).all()


def test_icp_recovers_a_known_pose_from_exact_model_points() -> None:
    model = box_surface(seed=0)
    cloud = model.points[::5]  # exact model points: each one's match at the true pose is itself
    observed = cloud @ R_TRUE.T + T_TRUE
    R0 = axis_angle([1.0, 1.0, 0.0], 20.0) @ R_TRUE
    t0 = T_TRUE + np.array([25.0, -15.0, 10.0])
    assert add_error(CORNERS, R0, t0, R_TRUE, T_TRUE) > 20.0
    fit = icp(observed, np.ones(len(observed)), np.ones(len(observed), dtype=bool), model, R0, t0)
    assert fit.converged and not fit.degenerate
    assert add_error(CORNERS, fit.R, fit.t, R_TRUE, T_TRUE) < 0.1
    assert np.allclose(fit.R @ fit.R.T, np.eye(3), atol=1e-9)


def test_touch_pulls_the_fit_onto_faces_the_camera_does_not_see() -> None:
    """Depth of the top face alone leaves the box free to slide and spin in that face's plane; a few
    taxels on two side faces pin it."""
    model = box_surface(seed=0)
    rng = np.random.default_rng(2)
    top = np.column_stack([rng.uniform(-38, 38, 300), rng.uniform(-23, 23, 300), np.full(300, HALF[2])])
    sides = np.array(
        [[HALF[0], -10.0, 0.0], [HALF[0], 12.0, 5.0], [-5.0, HALF[1], -3.0], [20.0, HALF[1], 4.0]]
    )
    view = box_view(top @ R_TRUE.T + T_TRUE, sides @ R_TRUE.T + T_TRUE, R_TRUE, T_TRUE)
    found = estimate_view(view, model, seed=7)
    start = add_error(CORNERS, found.start_R, found.start_t, R_TRUE, T_TRUE)
    vision = found.by_variant[VISION]
    both = found.by_variant[VISION_TOUCH]
    assert vision.taxels == 0 and both.taxels == len(sides) and both.vision_points == vision.vision_points
    err_vision = add_error(CORNERS, vision.R, vision.t, R_TRUE, T_TRUE)
    err_both = add_error(CORNERS, both.R, both.t, R_TRUE, T_TRUE)
    assert err_both < 0.5, (start, err_vision, err_both)
    assert err_vision > 5.0, (start, err_vision, err_both)


def test_the_start_is_15_to_30_degrees_and_20_to_40_mm_off_and_seeded_by_the_sample() -> None:
    view = box_view(np.zeros((0, 3)), np.zeros((0, 3)), R_TRUE, T_TRUE)
    for seed in range(20):
        R0, t0 = start_pose(view, seed)
        angle = math.degrees(math.acos(np.clip((np.trace(R0 @ R_TRUE.T) - 1) / 2, -1, 1)))
        assert 15.0 - 1e-9 <= angle <= 30.0 + 1e-9
        assert 20.0 - 1e-9 <= np.linalg.norm(t0 - T_TRUE) <= 40.0 + 1e-9
    again = start_pose(view, 3)
    assert np.array_equal(again[0], start_pose(view, 3)[0]) and not np.array_equal(
        again[0], start_pose(view, 4)[0]
    )


def test_no_points_at_all_returns_the_start_pose_for_both_variants() -> None:
    view = box_view(np.zeros((0, 3)), np.zeros((0, 3)), R_TRUE, T_TRUE)
    found = estimate_view(view, box_surface(), seed=1)
    for variant in (VISION, VISION_TOUCH):
        est = found.by_variant[variant]
        assert est.guard == "too_few_points"
        assert np.array_equal(est.R, found.start_R) and np.array_equal(est.t, found.start_t)


def test_no_active_taxels_makes_vision_touch_a_copy_of_vision() -> None:
    cloud = box_surface(count=200, seed=3).points @ R_TRUE.T + T_TRUE
    found = estimate_view(box_view(cloud, np.zeros((0, 3)), R_TRUE, T_TRUE), box_surface(), seed=1)
    a, b = found.by_variant[VISION], found.by_variant[VISION_TOUCH]
    assert a.guard == "" and b.guard == "no_taxels"
    assert np.array_equal(a.R, b.R) and np.array_equal(a.t, b.t)


def test_touch_alone_is_used_when_the_hand_hides_every_pixel() -> None:
    taxels = box_surface(count=12, seed=4).points @ R_TRUE.T + T_TRUE
    found = estimate_view(box_view(np.zeros((0, 3)), taxels, R_TRUE, T_TRUE), box_surface(), seed=1)
    assert found.by_variant[VISION].guard == "too_few_points"
    assert found.by_variant[VISION_TOUCH].guard == "" and found.by_variant[VISION_TOUCH].iterations > 0


@pytest.mark.parametrize(
    "points",
    [
        np.tile([[10.0, 0.0, 400.0]], (20, 1)),  # one point, many times: rank 1
        np.column_stack([np.linspace(-30, 30, 20), np.zeros(20), np.full(20, 400.0)]),  # a line
    ],
)
def test_degenerate_clouds_are_flagged_not_fatal(points: np.ndarray) -> None:
    fit = icp(points, np.ones(len(points)), np.ones(len(points), dtype=bool), box_surface(), R_TRUE, T_TRUE)
    assert fit.degenerate
    assert np.isfinite(fit.R).all() and np.isfinite(fit.t).all()
    assert np.allclose(fit.R @ fit.R.T, np.eye(3), atol=1e-9)


def test_fewer_than_three_points_return_the_start_unchanged() -> None:
    points = np.array([[0.0, 0.0, 400.0], [1.0, 0.0, 400.0]])
    fit = icp(points, np.ones(2), np.ones(2, dtype=bool), box_surface(), R_TRUE, T_TRUE)
    assert fit.degenerate and not fit.converged and fit.iterations == 0
    assert np.array_equal(fit.R, R_TRUE) and np.array_equal(fit.t, T_TRUE)


def test_back_projection_puts_a_fronto_parallel_plane_at_its_depth() -> None:
    K = np.array([[100.0, 0.0, 15.5], [0.0, 100.0, 11.5], [0.0, 0.0, 1.0]])
    depth = np.full((24, 32), 0.5, dtype=np.float32)
    depth[0, 0] = 0.0  # no return: dropped
    mask = np.zeros((24, 32), dtype=bool)
    mask[:, :16] = True
    points = back_project(depth, mask, K)
    assert len(points) == 24 * 16 - 1
    assert np.allclose(points[:, 2], 500.0)
    # Row-major order, (0, 0) dropped: the first point is pixel (u, v) = (1, 0), (1 - 15.5) / 100 · z
    # to the left of the axis and (0 - 11.5) / 100 · z above it.
    assert np.allclose(points[0], [-14.5 / 100 * 500.0, -11.5 / 100 * 500.0, 500.0])


def test_back_projection_of_a_distorted_view_follows_each_pixels_ray_through_its_lens() -> None:
    """Points back-projected with the record's `dist` project back onto their pixels through K and
    dist (OpenCV's projection); read as a pinhole they would miss them by pixels."""
    K = np.array([[60.0, 0.0, 31.5], [0.0, 60.0, 23.5], [0.0, 0.0, 1.0]])
    dist = [-0.25, 0.05, 0.004, -0.003, 0.01]
    depth = np.full((48, 64), 0.5, dtype=np.float32)
    mask = np.ones((48, 64), dtype=bool)
    points = back_project(depth, mask, K, dist)
    assert np.allclose(points[:, 2], 500.0)
    v, u = np.nonzero(mask)
    uv = cv2.projectPoints(points, np.zeros(3), np.zeros(3), K, np.array(dist))[0].reshape(-1, 2)
    assert np.abs(uv - np.column_stack([u, v])).max() < 1e-6
    pinhole = back_project(depth, mask, K, [0.0] * 5)
    assert np.array_equal(pinhole, back_project(depth, mask, K))
    corner = cv2.projectPoints(pinhole[:1], np.zeros(3), np.zeros(3), K, np.array(dist))[0].reshape(2)
    assert np.hypot(*(corner - [0.0, 0.0])) > 2.0


def test_taxels_go_from_the_palm_frame_through_the_world_to_the_camera() -> None:
    # Palm turned 90° about world z (q = [cos 45°, 0, 0, sin 45°]) at (0.1, 0, 0); camera = world
    # shifted 0.5 m along z.
    c = math.cos(math.pi / 4)
    grasp = {
        "trial": {"link_poses": {"palm": {"p": [0.1, 0.0, 0.0], "q": [c, 0.0, 0.0, c]}}},
        "touch": {"active": [{"p_palm": [0.01, 0.0, 0.0]}, {"p_palm": [0.0, 0.02, 0.003]}]},
    }
    points = taxels_in_camera(grasp, np.eye(3), np.array([0.0, 0.0, 0.5]))
    # Palm x → world y, palm y → world -x.
    assert np.allclose(points, [[100.0, 10.0, 500.0], [80.0, 0.0, 503.0]])
    assert taxels_in_camera(
        {"trial": grasp["trial"], "touch": {"active": []}}, np.eye(3), np.zeros(3)
    ).shape == (0, 3)


def test_pooled_auc_is_the_step_sum_docs_metrics_md_defines() -> None:
    # Errors 0, 50, 200 mm (n = 3; d_1 = 0, d_2 = 50 within 100 mm): the curve's steps, each at its
    # right end, summed by hand: (0 - 0)·1/3 + (50 - 0)·2/3 + (100 - 50)·2/3 = 66.67 mm of 100.
    assert pose_scores.auc([200.0, 0.0, 50.0]) == pytest.approx(100.0 * (50.0 * 2 / 3 + 50.0 * 2 / 3) / 100.0)
    assert pose_scores.auc([150.0, 300.0]) == 0.0
    assert pose_scores.auc([0.0]) == pytest.approx(100.0)
    assert pose_scores.auc([100.0]) == pytest.approx(100.0)  # an error of exactly T counts as within
    assert math.isnan(pose_scores.auc([]))


def test_buckets_and_the_finding_read_the_occlusion_as_documented() -> None:
    assert [bucket(x) for x in (0.0, 0.099, 0.1, 0.55, 0.9, 1.0)] == [
        "0-10",
        "0-10",
        "10-20",
        "50-60",
        "90-100",
        "90-100",
    ]

    def rows(variant: str, low: list[float], high: list[float]) -> list[dict[str, object]]:
        return [{"variant": variant, "occlusion": 0.2, "err_mm": e} for e in low] + [
            {"variant": variant, "occlusion": 0.7, "err_mm": e} for e in high
        ]

    # AUCs by the step sum: [0, 0] → 100; [50, 200] → ((100 - 50) + 50) / 2 = 50; [10, 10] → 95.
    sentence, numbers = finding(
        rows(VISION, [0.0, 0.0], [50.0, 200.0]) + rows(VISION_TOUCH, [0.0, 0.0], [10.0, 10.0])
    )
    assert sentence.startswith("The data supports the hypothesis")
    assert numbers[VISION]["drop"] == pytest.approx(50.0) and numbers[VISION_TOUCH]["drop"] == pytest.approx(
        5.0
    )
    sentence, _ = finding(
        rows(VISION, [0.0, 0.0], [10.0, 10.0]) + rows(VISION_TOUCH, [0.0, 0.0], [50.0, 200.0])
    )
    assert sentence.startswith("The data contradicts the hypothesis")
    sentence, _ = finding(
        rows(VISION, [0.0, 0.0], [10.0, 10.0]) + rows(VISION_TOUCH, [0.0, 0.0], [10.0, 10.0])
    )
    assert sentence.startswith("The data shows no difference")


def test_taxel_weight_is_the_documented_inverse_variance_ratio() -> None:
    # σ_depth ≈ 1.0 mm, σ_taxel ≈ 0.31 mm (touch_estimate's comment): (1.0 / 0.31)² ≈ 10.
    assert pytest.approx((1.0 / 0.31) ** 2, rel=0.05) == TAXEL_WEIGHT
