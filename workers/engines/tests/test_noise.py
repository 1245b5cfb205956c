"""The Azure-Kinect-like depth model against independent computations: σ fitted on noisy synthetic
planes (compared with Microsoft's cited bound), flying pixels at depth steps, glass, specular
metal, multipath in concave corners, the modes' ranges, the seed, and extreme inputs."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from vint_engines.noise import geometry, sensor
from vint_engines.noise.engine import intrinsics
from vint_engines.noise.geometry import Intrinsics
from vint_engines.noise.model import NoiseModel, Surfaces
from vint_engines.protocol import BadInput

MODES = ("nfov_unbinned", "nfov_2x2binned", "wfov_2x2binned", "wfov_unbinned")
# Every piece but the axial noise and the range off, the noise white: what the σ fits measure.
AXIAL_ONLY = {
    "lateral": False,
    "flying_pixels": False,
    "multipath": False,
    "materials": False,
    "registration": False,
    "spatial_sigma_px": 0.0,
}
# Nothing random: σ scaled to 0 and the random pieces off, so geometry effects show alone.
NO_NOISE = {**AXIAL_ONLY, "sigma_scale": 0.0}


def camera(width: int, height: int, f: float) -> Intrinsics:
    return Intrinsics(f, f, (width - 1) / 2, (height - 1) / 2)


def plane(k: Intrinsics, shape: tuple[int, int], distance_m: float, tilt_deg: float = 0.0) -> np.ndarray:
    """Depth of the plane through (0, 0, distance) whose normal is tilted by `tilt_deg` about the
    camera's y axis (ray–plane intersection, written independently of the model's normals)."""
    h, w = shape
    x = (np.arange(w) - k.cx) / k.fx
    y = (np.arange(h) - k.cy) / k.fy
    rx, _ = np.meshgrid(x, y)
    t = math.radians(tilt_deg)
    normal = np.array([math.sin(t), 0.0, -math.cos(t)])
    # n·(z·ray) = n·(0, 0, d)  ⇒  z = n_z d / (n_x x + n_z)
    return (normal[2] * distance_m / (normal[0] * rx + normal[2])).astype(np.float32)


def surfaces(shape: tuple[int, int], rho: float, kind: int = sensor.DIFFUSE) -> Surfaces:
    return Surfaces(np.full(shape, rho, np.float32), np.full(shape, kind, np.uint8))


def fitted_sigma(model: NoiseModel, k: Intrinsics, depth: np.ndarray, rho: float, seed: int) -> float:
    """σ of (noisy - true) over the valid pixels of one view."""
    noisy = model.apply(depth, k, surfaces(depth.shape, rho), np.random.default_rng(seed))
    valid = noisy > 0
    assert valid.mean() > 0.9
    return float(np.std((noisy - depth)[valid]))


@pytest.mark.parametrize("mode", MODES)
def test_sigma_fitted_on_noisy_planes_grows_with_distance_and_meets_microsofts_bound(mode: str) -> None:
    """Fronto-parallel planes across the mode's range on the darkest specified surface (rho = 0.15):
    the fitted σ grows with distance (not a constant), roughly in proportion at range (a shot-
    noise-limited ToF), stays within the specified ≤ 17 mm, and reaches it at the far end."""
    model = NoiseModel.parse({"mode": mode, **AXIAL_ONLY, "materials": True})
    k = camera(160, 120, 2000.0)  # narrow: every ray within 2.3° of the axis
    lo, hi = model.mode.min_range_m, model.mode.max_range_m
    distances = np.linspace(lo, hi, 6)
    sigmas = np.array(
        [fitted_sigma(model, k, plane(k, (120, 160), d), 0.15, seed) for seed, d in enumerate(distances)]
    )
    assert np.all(np.diff(sigmas) > 0), sigmas
    assert sigmas[-1] > 3 * sigmas[0], sigmas
    slope = np.polyfit(np.log(distances[2:]), np.log(sigmas[2:]), 1)[0]
    assert 0.8 < slope < 1.1, (slope, sigmas)
    assert sigmas.max() <= 1.05 * sensor.SPEC_SIGMA_MAX_M
    assert sigmas[-1] == pytest.approx(sensor.SPEC_SIGMA_MAX_M, rel=0.05)


def test_sigma_fitted_on_tilted_planes_grows_with_incidence_as_the_returned_signal_falls() -> None:
    """Planes at 1 m tilted 0–75°: σ grows with the angle; the fitted ratio to normal incidence
    follows 1/√cos θ (the signal falls as cos θ) within 10 %, with no noise floor to speak of at
    1 m on rho = 0.5 (floor 0.5 mm against ~2.4 mm)."""
    model = NoiseModel.parse({"mode": "nfov_unbinned", **AXIAL_ONLY})
    k = camera(200, 40, 3000.0)
    angles = [0.0, 30.0, 45.0, 60.0, 75.0]
    sigmas = []
    for seed, angle in enumerate(angles):
        depth = plane(k, (40, 200), 1.0, angle)
        noisy = model.apply(depth, k, None, np.random.default_rng(seed))
        valid = noisy > 0
        sigmas.append(float(np.std((noisy - depth)[valid])))
    ratios = np.array(sigmas) / sigmas[0]
    assert np.all(np.diff(ratios) > 0), ratios
    floor = sensor.SIGMA_FLOOR_M / sigmas[0]
    for angle, ratio in zip(angles, ratios, strict=True):
        shot = 1 / math.sqrt(math.cos(math.radians(angle)))
        expected = math.sqrt(floor**2 + (1 - floor**2) * shot**2)
        assert ratio == pytest.approx(expected, rel=0.1), (angle, ratios)


def test_dark_surfaces_are_noisier() -> None:
    model = NoiseModel.parse({"mode": "nfov_unbinned", **AXIAL_ONLY, "materials": True})
    k = camera(160, 120, 2000.0)
    depth = plane(k, (120, 160), 1.5)
    bright = fitted_sigma(model, k, depth, 0.8, 1)
    dark = fitted_sigma(model, k, depth, 0.1, 2)
    assert dark > 2 * bright


def step_scene() -> tuple[np.ndarray, Intrinsics]:
    """A 0.6 m box in front of a 1.0 m wall."""
    depth = np.full((60, 80), 1.0, np.float32)
    depth[20:40, 25:55] = 0.6
    return depth, camera(80, 60, 600.0)  # nfov: a native pixel spans 1.2 output pixels here


def test_flying_pixels_at_depth_edges_lie_between_foreground_and_background() -> None:
    depth, k = step_scene()
    model = NoiseModel.parse({**NO_NOISE, "flying_pixels": True, "flying_invalid_share": 0.0})
    noisy = model.apply(depth, k, None, np.random.default_rng(3))
    between = (noisy > 0.6 + 1e-3) & (noisy < 1.0 - 1e-3)
    assert between.sum() >= 20
    rows, cols = np.nonzero(between)
    near_edge = np.zeros_like(between)
    near_edge[18:42, 23:57] = True
    near_edge[22:38, 27:53] = False
    assert near_edge[rows, cols].all(), "flying pixels only at the step"
    assert (noisy == 0).sum() == 0, "no share invalidated: every mixed pixel flies"
    # Away from the step the depth is untouched; without the piece no depth lies between.
    assert np.array_equal(noisy[:10], depth[:10]) and np.array_equal(noisy[28:32, 35:45], depth[28:32, 35:45])
    off = model.without("flying_pixels").apply(depth, k, None, np.random.default_rng(3))
    assert not ((off > 0.6 + 1e-3) & (off < 1.0 - 1e-3)).any()


def test_a_share_of_mixed_pixels_is_invalidated() -> None:
    depth, k = step_scene()
    noisy = NoiseModel.parse({**NO_NOISE, "flying_pixels": True, "flying_invalid_share": 1.0}).apply(
        depth, k, None, np.random.default_rng(3)
    )
    assert (noisy == 0).sum() >= 20
    assert not ((noisy > 0.6 + 1e-3) & (noisy < 1.0 - 1e-3)).any()


def material_scene() -> tuple[np.ndarray, np.ndarray, Intrinsics]:
    """A wall (id 2) at 1.0 m; a glass object (id 1) at 0.6 m in front of it, its right part over
    no-return background (0); a finger (id 3) at 0.5 m in front of the glass."""
    depth = np.full((60, 80), 1.0, np.float32)
    segmentation = np.full((60, 80), 2, np.uint8)
    depth[:, 60:] = 0.0
    segmentation[:, 60:] = 0
    depth[20:40, 20:70] = 0.6
    segmentation[20:40, 20:70] = 1
    depth[28:32, 10:30] = 0.5
    segmentation[28:32, 10:30] = 3
    return depth, segmentation, camera(80, 60, 600.0)


def test_glass_reads_the_surface_behind_it_or_nothing() -> None:
    depth, segmentation, k = material_scene()
    seen = Surfaces.from_segmentation(segmentation, {1: "glass", 2: "plastic", 3: "rubber"})
    noisy = NoiseModel.parse({**NO_NOISE, "materials": True}).apply(depth, k, seen, np.random.default_rng(0))
    assert np.allclose(noisy[21:27, 40:55], 1.0), "glass over the wall shows the wall"
    assert (noisy[21:39, 62:70] == 0).all(), "glass over the background reads nothing"
    assert not np.isclose(noisy[segmentation == 1], 0.6).any(), "never the glass surface itself"
    opaque = Surfaces.from_segmentation(segmentation, {1: "plastic", 2: "plastic", 3: "rubber"})
    plain = NoiseModel.parse({**NO_NOISE, "materials": True}).apply(
        depth, k, opaque, np.random.default_rng(0)
    )
    assert np.allclose(plain[21:27, 21:69], 0.6) and np.allclose(plain[28:32, 10:30], 0.5)


def hemisphere(k: Intrinsics, shape: tuple[int, int], centre_m: float, radius_m: float) -> np.ndarray:
    """Depth of a sphere's near side (ray–sphere intersection); 0 off the sphere."""
    h, w = shape
    x = (np.arange(w) - k.cx) / k.fx
    y = (np.arange(h) - k.cy) / k.fy
    rx, ry = np.meshgrid(x, y)
    a = rx**2 + ry**2 + 1
    b = -2 * centre_m
    c = centre_m**2 - radius_m**2
    disc = b * b - 4 * a * c
    t = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)
    return np.where(disc > 0, t, 0).astype(np.float32)


def test_specular_metal_drops_out_near_the_mirror_direction() -> None:
    """A metal sphere: pixels whose normal points at the camera (θ small) drop out, the flanks
    do not; the same sphere in plastic keeps its centre."""
    k = camera(120, 120, 400.0)
    depth = hemisphere(k, (120, 120), 1.0, 0.12)
    on = depth > 0
    seg = np.where(on, 1, 0).astype(np.uint8)
    model = NoiseModel.parse({**NO_NOISE, "materials": True, "specular_cone_deg": 10.0})
    metal = model.apply(depth, k, Surfaces.from_segmentation(seg, {1: "metal"}), np.random.default_rng(4))
    # Incidence from the sphere's own geometry: the normal is (P - C)/r.
    h, w = depth.shape
    x = (np.arange(w) - k.cx) / k.fx
    y = (np.arange(h) - k.cy) / k.fy
    rx, ry = np.meshgrid(x, y)
    points = np.stack([rx * depth, ry * depth, depth], axis=-1)
    normal = (points - np.array([0, 0, 1.0])) / 0.12
    length = np.maximum(np.linalg.norm(points, axis=-1), 1e-9)
    theta = np.degrees(np.arccos(np.clip(np.abs(np.sum(normal * points, -1)) / length, 0, 1)))
    mirror = on & (theta < 5)
    flank = on & (theta > 25) & (theta < 70)
    assert mirror.sum() > 20 and flank.sum() > 200
    assert (metal[mirror] == 0).mean() > 0.8
    assert (metal[flank] == 0).mean() < 0.05
    plastic = model.apply(depth, k, Surfaces.from_segmentation(seg, {1: "plastic"}), np.random.default_rng(4))
    assert (plastic[mirror] > 0).all()


def corner(k: Intrinsics, shape: tuple[int, int], sign: float) -> np.ndarray:
    """Two planes meeting along the image's centre column, each exactly planar (1/z is linear in
    u on each side): sign +1 a concave crease (the crease farthest), -1 a convex ridge."""
    h, w = shape
    x = np.abs((np.arange(w) - k.cx) / k.fx)
    inverse = (1 + sign * 0.8 * x) / 0.8
    return np.tile((1 / inverse).astype(np.float32), (h, 1))


def test_multipath_biases_concave_corners_positive_and_leaves_planes_and_ridges_alone() -> None:
    k = camera(120, 60, 300.0)
    model = NoiseModel.parse({**NO_NOISE, "multipath": True})
    concave = corner(k, (60, 120), +1)
    biased = model.apply(concave, k, None, np.random.default_rng(0)) - concave
    centre = biased[20:40, 58:62]  # rows away from the image border (a one-sided window reads nothing)
    assert (centre > 1e-4).all(), "the crease reads long"
    assert biased.max() <= 0.011 + 1e-6, "never beyond the specified systematic error"
    assert np.abs(biased[:, :20]).max() < 1e-5, "each face is a plane: no bias away from the crease"
    convex = corner(k, (60, 120), -1)
    ridge = model.apply(convex, k, None, np.random.default_rng(0)) - convex
    assert ridge.max() < 1e-6
    tilted = plane(k, (60, 120), 0.8, 40.0)
    assert np.abs(model.apply(tilted, k, None, np.random.default_rng(0)) - tilted).max() < 1e-5


@pytest.mark.parametrize("mode", MODES)
def test_readings_outside_the_modes_range_are_invalid_and_its_limits_are_valid(mode: str) -> None:
    model = NoiseModel.parse({"mode": mode, **NO_NOISE})
    lo, hi = model.mode.min_range_m, model.mode.max_range_m
    k = camera(16, 16, 1000.0)
    for distance, valid in [(lo, True), (hi, True), (lo - 0.001, False), (hi + 0.001, False)]:
        out = model.apply(np.full((16, 16), distance, np.float32), k, None, np.random.default_rng(0))
        assert (out > 0).all() if valid else (out == 0).all(), (mode, distance)


def test_modes_carry_the_cited_figures() -> None:
    figures = {m: sensor.Mode.named(m) for m in MODES}
    assert (figures["nfov_unbinned"].width_px, figures["nfov_unbinned"].height_px) == (640, 576)
    assert (figures["wfov_unbinned"].min_range_m, figures["wfov_unbinned"].max_range_m) == (0.25, 2.21)
    assert figures["nfov_2x2binned"].max_range_m == 5.46 and figures["wfov_2x2binned"].fov_h_deg == 120.0
    with pytest.raises(BadInput, match="unknown depth mode"):
        sensor.Mode.named("kinect_v2")


def full_scene() -> tuple[np.ndarray, Surfaces, Intrinsics]:
    depth, segmentation, k = material_scene()
    return depth, Surfaces.from_segmentation(segmentation, {1: "metal", 2: "plastic", 3: "rubber"}), k


def test_the_seed_fixes_the_output() -> None:
    depth, seen, k = full_scene()
    model = NoiseModel.parse({"mode": "wfov_2x2binned"})
    a = model.apply(depth, k, seen, np.random.default_rng(7))
    b = model.apply(depth, k, seen, np.random.default_rng(7))
    c = model.apply(depth, k, seen, np.random.default_rng(8))
    assert a.dtype == np.float32 and np.array_equal(a, b)
    assert not np.array_equal(a, c)
    # One stream per piece: switching multipath off leaves the other pieces' draws as they were.
    off = model.without("multipath").apply(depth, k, seen, np.random.default_rng(7))
    same = (a > 0) & (off > 0)
    assert np.abs(a - off)[same].max() <= 0.011 + 1e-6


def test_materials_need_the_segmentation_and_every_segment_needs_a_tag() -> None:
    depth, segmentation, k = material_scene()
    with pytest.raises(BadInput, match="segmentation"):
        NoiseModel.parse({}).apply(depth, k, None, np.random.default_rng(0))
    with pytest.raises(BadInput, match=r"segment ids \[3\]"):
        Surfaces.from_segmentation(segmentation, {1: "glass", 2: "plastic"})
    with pytest.raises(BadInput, match="unknown material tag"):
        Surfaces.from_segmentation(segmentation, {1: "unobtainium", 2: "plastic", 3: "rubber"})


EXTREMES = {
    "all background": np.zeros((32, 32), np.float32),
    "all NaN": np.full((32, 32), np.nan, np.float32),
    "NaN, Inf, negative": np.array([[np.nan, np.inf, -np.inf, -1.0] * 4] * 16, np.float32),
    "16x16": np.full((16, 16), 0.8, np.float32),
    "4096 wide": np.tile(np.linspace(0.3, 2.0, 4096, dtype=np.float32), (48, 1)),
}


@pytest.mark.parametrize("name", list(EXTREMES))
def test_extreme_inputs_end_valid_and_never_nan(name: str) -> None:
    depth = EXTREMES[name]
    h, w = depth.shape
    seg = np.where(np.isfinite(depth) & (depth > 0), 1, 0).astype(np.uint8)
    seen = Surfaces.from_segmentation(seg, {1: "metal"})
    for mode in MODES:
        out = NoiseModel.parse({"mode": mode}).apply(
            depth, camera(w, h, w / 2), seen, np.random.default_rng(1)
        )
        assert out.shape == depth.shape and out.dtype == np.float32
        assert np.isfinite(out).all() and (out >= 0).all(), (name, mode)
        if not (np.isfinite(depth) & (depth > 0)).any():
            assert (out == 0).all()


def test_glass_at_grazing_angles_ends_valid() -> None:
    k = camera(64, 48, 60.0)
    depth = plane(k, (48, 64), 0.6, 80.0)
    depth[depth <= 0] = 0
    seg = np.ones(depth.shape, np.uint8)
    seg[:, :10] = 2
    seen = Surfaces.from_segmentation(seg, {1: "glass", 2: "plastic"})
    out = NoiseModel.parse({"mode": "wfov_unbinned"}).apply(depth, k, seen, np.random.default_rng(2))
    assert np.isfinite(out).all() and (out >= 0).all()


def test_a_depth_map_that_is_not_a_2d_image_is_refused() -> None:
    with pytest.raises(BadInput, match="H×W"):
        NoiseModel.parse({}).apply(
            np.zeros((4, 4, 2), np.float32), camera(4, 4, 4.0), None, np.random.default_rng(0)
        )


def test_a_distorted_views_normals_follow_each_pixels_ray_through_its_lens() -> None:
    """A wall facing the camera has the same depth at every pixel, whatever the lens; its
    incidence cosine at a pixel is 1/|ray|, the ray found by OpenCV through the recorded lens
    (`noise.engine.intrinsics` reads `dist`). The pinhole's rays would be wrong by degrees at a
    wide lens's corners."""
    width, height, f = 160, 120, 110.0
    K = [[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]]
    dist = [-0.25, 0.05, 0.01, -0.01, 0.01]
    wall = np.ones((height, width), np.float32)
    valid = np.ones(wall.shape, bool)
    record = {"K": K, "width": width, "height": height, "dist": dist}
    cos = geometry.cos_incidence(wall, valid, intrinsics(record, wall.shape, "v00"))
    rows, cols = np.indices(wall.shape)
    pixels = np.stack([cols.ravel(), rows.ravel()], axis=-1).reshape(-1, 1, 2).astype(np.float64)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-10)
    xy = cv2.undistortPointsIter(pixels, np.array(K), np.array(dist), None, None, criteria).reshape(-1, 2)
    expected = (1 / np.sqrt(1 + (xy**2).sum(axis=1))).reshape(wall.shape)
    assert np.abs(cos - expected).max() < 1e-5
    pinhole = geometry.cos_incidence(
        wall, valid, intrinsics({**record, "dist": [0.0] * 5}, wall.shape, "v00")
    )
    assert np.degrees(np.abs(np.arccos(pinhole) - np.arccos(expected))).max() > 3.0
    with pytest.raises(BadInput, match=r"v00_camera\.json: dist must be 5 finite numbers"):
        intrinsics({**record, "dist": [0.1, 0.0]}, wall.shape, "v00")
