"""The render engine's lens (`render/lens.py`) against OpenCV: rays found for distorted pixels are
OpenCV's own undistortion, the canvas holds every ray at the view's focal length, and the map
resamples a canvas onto the distorted image the right way round. No Blender here; the rendered
views are held to OpenCV in test_render_outputs.py."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from vint_engines.protocol import BadInput
from vint_engines.render.camera import Intrinsics
from vint_engines.render.lens import (
    CANVAS_MARGIN_PX,
    PINHOLE,
    border_pixels,
    check_lens,
    project,
    radial_reach,
    undistorted,
    view_lens,
)

WHERE = "params.render.distortion"
# A wide-angle lens with strong decentring, so that swapping p1 and p2 (OpenCV's order is
# [k1, k2, p1, p2, k3]) or a sign would show.
WIDE = (-0.25, 0.05, 0.01, -0.02, 0.01)


def test_rays_are_opencvs_undistortion_and_project_back_onto_their_pixels() -> None:
    intrinsics = Intrinsics(160, 120, 60.0, offset_px=(4.0, -3.0), focal_scale=1.02)
    K = intrinsics.matrix()
    rng = np.random.default_rng(3)
    pixels = rng.uniform((0.0, 0.0), (159.0, 119.0), size=(500, 2))
    rays, folds = undistorted(pixels, K, WIDE)
    assert not folds
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    theirs = cv2.undistortPointsIter(pixels.reshape(-1, 1, 2), K, np.array(WIDE), None, None, criteria)
    assert np.abs(rays - theirs.reshape(-1, 2)).max() * K[0, 0] < 1e-6
    back = project(np.column_stack([rays, np.ones(len(rays))]), K, WIDE)
    assert np.abs(back - pixels).max() < 1e-6
    swapped = (WIDE[0], WIDE[1], WIDE[3], WIDE[2], WIDE[4])
    assert np.abs(project(np.column_stack([rays, np.ones(len(rays))]), K, swapped) - pixels).max() > 1.0


def test_the_canvas_holds_every_ray_at_the_views_focal_length() -> None:
    intrinsics = Intrinsics(96, 128, 40.0, offset_px=(3.0, -2.0), focal_scale=0.97)
    lens = view_lens(intrinsics, WIDE, WHERE, "the test's intrinsics")
    assert lens is not None
    canvas = lens.canvas
    assert canvas.focal_px == pytest.approx(intrinsics.focal_px, rel=1e-12)
    # Barrel: the rays of the image's border spread wider than the image.
    assert canvas.width > intrinsics.width and canvas.height > intrinsics.height
    assert lens.map_x.shape == lens.map_y.shape == (128, 96)
    for coordinate, size in ((lens.map_x, canvas.width), (lens.map_y, canvas.height)):
        assert coordinate.min() >= CANVAS_MARGIN_PX - 1 and coordinate.max() <= size - CANVAS_MARGIN_PX
    # Every pixel's canvas coordinate is its ray through the canvas's pinhole.
    rows, cols = np.indices((128, 96))
    rays, _ = undistorted(
        np.column_stack([cols.ravel(), rows.ravel()]).astype(float), intrinsics.matrix(), WIDE
    )
    on_canvas = np.column_stack([rays, np.ones(len(rays))]) @ canvas.matrix().T
    assert np.abs(on_canvas[:, 0] - lens.map_x.ravel()).max() < 1e-3
    assert np.abs(on_canvas[:, 1] - lens.map_y.ravel()).max() < 1e-3


def test_light_is_resampled_bilinearly_and_labels_by_nearest_neighbour() -> None:
    """A canvas whose light is its own column coordinate comes back as each pixel's canvas
    column (bilinear is exact on a ramp, to OpenCV's 1/32 px weights); labels come back as labels
    the canvas holds, never a blend of two."""
    intrinsics = Intrinsics(64, 48, 60.0)
    lens = view_lens(intrinsics, WIDE, WHERE, "the test's intrinsics")
    assert lens is not None
    h, w = lens.canvas.height, lens.canvas.width
    ramp = np.repeat(np.arange(w, dtype=np.float32)[None, :, None], h, axis=0).repeat(3, axis=2)
    light = lens.light(ramp)
    assert light.shape == (48, 64, 3) and light.dtype == np.float32
    assert np.abs(light[..., 0] - lens.map_x).max() < 1 / 32 + 1e-4
    labels = (np.arange(h * w, dtype=np.int32).reshape(h, w) % 7) * 10
    resampled = lens.nearest(labels)
    assert resampled.dtype == np.int32 and set(np.unique(resampled)) <= set(range(0, 70, 10))
    assert np.array_equal(resampled, labels[np.rint(lens.map_y).astype(int), np.rint(lens.map_x).astype(int)])


def test_a_pinhole_has_no_lens() -> None:
    assert view_lens(Intrinsics(64, 48, 60.0), PINHOLE, WHERE, "the test's intrinsics") is None
    check_lens(Intrinsics(64, 48, 60.0), PINHOLE, WHERE, "the test's intrinsics")


def test_a_lens_that_folds_inside_the_image_is_bad_input_naming_the_field_and_the_rule() -> None:
    # 128×128 at 50° (tiny.toml): corners at radius 0.654; k1 = -0.6 folds back at 0.489.
    with pytest.raises(BadInput) as refused:
        check_lens(Intrinsics(128, 128, 50.0), (-0.6, 0.0, 0.0, 0.0, 0.0), WHERE, "view 3's intrinsics")
    message = str(refused.value)
    assert message.startswith("params.render.distortion: [-0.6, 0.0, 0.0, 0.0, 0.0] must stay invertible")
    assert "view 3's intrinsics" in message and "radius 0.654" in message and "radius 0.489" in message
    # The same lens over a narrower view keeps the fold outside the image.
    check_lens(Intrinsics(128, 128, 30.0), (-0.6, 0.0, 0.0, 0.0, 0.0), WHERE, "view 3's intrinsics")
    # Decentring past what any pixel's ray can reach at the corners.
    with pytest.raises(BadInput, match=r"params\.render\.distortion: .* cannot be inverted over the image"):
        check_lens(Intrinsics(128, 128, 60.0), (0.0, 0.0, 0.1, 0.1, 0.0), WHERE, "view 0's intrinsics")


def test_radial_reach_is_the_specs() -> None:
    """The numbers vint_core's `radial_reach` test holds the spec's check to."""
    barrel = (-0.3, 0.0, 0.0, 0.0, 0.0)
    assert radial_reach(PINHOLE, 0.72) == 0.72
    assert radial_reach((0.5, 0.2, 0.1, -0.1, 0.1), 3.0) == 3.0
    assert radial_reach(barrel, 0.722) == pytest.approx(0.6914, abs=1e-3)
    assert radial_reach(barrel, 0.583) == 0.583
    assert radial_reach((-0.3, 0.1, 0.0, 0.0, 0.0), 0.722) == 0.722


def test_the_border_is_every_outermost_pixel() -> None:
    border = border_pixels(5, 4)
    assert {tuple(p) for p in border} == {
        (u, v) for u in range(5) for v in range(4) if u in (0, 4) or v in (0, 3)
    }


def test_blender_shift_is_a_fraction_of_the_width_also_for_a_tall_image() -> None:
    """The camera's sensor fits horizontally (scene.py): Blender shifts by fractions of the
    width, whichever side is longer (a distorted view's canvas may be taller than wide)."""
    assert Intrinsics(40, 80, 60.0, offset_px=(4.0, -2.0)).blender_shift() == (-0.1, -0.05)
    assert Intrinsics(80, 40, 60.0, offset_px=(4.0, -2.0)).blender_shift() == (-0.05, -0.025)
