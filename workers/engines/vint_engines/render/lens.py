"""Lens distortion: OpenCV's Brown–Conrady model, `[k1, k2, p1, p2, k3]` in OpenCV's order, as a
view's images carry it.

Cycles renders a pinhole. A distorted view renders a pinhole *canvas* instead: the view's focal
length, its principal point moved by the canvas's margin, and large enough to hold where every
pixel of the distorted image looks (each pixel's ray, undistorted, plus `CANVAS_MARGIN_PX`). Every
image is then resampled into the distorted camera through one map — for each distorted pixel, the
canvas coordinate its ray hits: light bilinearly, depth, pass indices and masks by nearest
neighbour (a label or a depth is never blended). A pinhole (every coefficient 0) has no lens here
and nothing is resampled.

The distortion is OpenCV's own (`cv2.projectPoints` takes a camera-frame point to its distorted
pixel; `undistorted` inverts it), so a reader of `camera.json` projects with `K` and `dist` as it
would any calibrated camera; the noise stage and the touch study take each pixel's ray from
`rays`. Pure numpy and OpenCV: no Blender import here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np
import numpy.typing as npt

from vint_engines.errors import BadInput
from vint_engines.render.camera import Intrinsics

Distortion = tuple[float, float, float, float, float]
PINHOLE: Distortion = (0.0, 0.0, 0.0, 0.0, 0.0)
# The radial map's least slope over the image (vint_core::contract::render::MIN_RADIAL_SLOPE): 0 is
# where it folds back; above it the canvas stays within a few times the image.
MIN_RADIAL_SLOPE = 0.2
RADIAL_STEPS = 4096  # vint_core::contract::render::radial_reach's walk
# Canvas pixels beyond the outermost ray on each side: bilinear reads one neighbour, and a pixel
# more keeps nearest-neighbour rounding inside too.
CANVAS_MARGIN_PX = 2
NEWTON_STEPS = 50
RAYS_PER_BLOCK = 1 << 18
# A pixel's undistorted ray must project back onto the pixel within this (OpenCV's projection).
ROUND_TRIP_PX = 1e-3


@dataclass(frozen=True)
class Lens:
    """A distorted view's camera: its image's intrinsics and distortion, the pinhole canvas
    Cycles renders for it, and the canvas coordinate (column, row) of each image pixel's ray."""

    intrinsics: Intrinsics
    distortion: Distortion
    canvas: Intrinsics
    map_x: npt.NDArray[np.float32]  # H×W, for bilinear resampling
    map_y: npt.NDArray[np.float32]
    rows: npt.NDArray[np.intp]  # H×W, the nearest canvas pixel
    cols: npt.NDArray[np.intp]

    def light(self, canvas: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
        """A canvas image of light (H'×W'×C, linear) resampled into the view, bilinearly."""
        resampled = cv2.remap(
            canvas, self.map_x, self.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
        )
        return np.asarray(resampled, dtype=canvas.dtype)

    def nearest[T: np.generic](self, canvas: npt.NDArray[T]) -> npt.NDArray[T]:
        """A canvas array (depth, labels, a mask) resampled into the view: each pixel takes the
        canvas pixel nearest to its ray, so no value is ever blended."""
        return canvas[self.rows, self.cols]


def is_pinhole(distortion: Sequence[float]) -> bool:
    return all(k == 0.0 for k in distortion)


def check_lens(intrinsics: Intrinsics, distortion: Distortion, where: str, whose: str) -> None:
    """BadInput (naming `where`, the parameter, and `whose` intrinsics) unless the lens can be
    inverted over the image: its radial map keeps growing (`radial_reach`) out to the farthest
    corner from the principal point, and every border pixel's ray is found and projects back onto
    it. Cheap (the border only): a task checks all its views before it renders any."""
    if is_pinhole(distortion):
        return
    K = intrinsics.matrix()
    width, height = intrinsics.width, intrinsics.height
    corners = np.array([[0.0, 0.0], [width - 1.0, 0.0], [0.0, height - 1.0], [width - 1.0, height - 1.0]])
    corner = float(np.max(np.hypot(corners[:, 0] - K[0, 2], corners[:, 1] - K[1, 2]))) / K[0, 0]
    reach = radial_reach(distortion, corner)
    if reach < corner:
        raise BadInput(
            f"{where}: {list(distortion)} must stay invertible out to the image's corners: with "
            f"{whose} they lie at radius {corner:.3f} (normalised), but the radial map "
            f"r·(1 + k1·r² + k2·r⁴ + k3·r⁶) stops growing (slope below {MIN_RADIAL_SLOPE}) at radius "
            f"{reach:.3f}: weaken k1, k2 or k3, or narrow the field of view"
        )
    try:
        rays(border_pixels(width, height), K, distortion)
    except NotInvertible as exc:
        raise BadInput(
            f"{where}: {list(distortion)} cannot be inverted over the image with {whose} ({exc})"
        ) from exc


def view_lens(intrinsics: Intrinsics, distortion: Distortion, where: str, whose: str) -> Lens | None:
    """The lens of a view whose image has `intrinsics` (`check_lens` first); None for a pinhole."""
    if is_pinhole(distortion):
        return None
    check_lens(intrinsics, distortion, where, whose)
    try:
        return _lens(intrinsics, distortion)
    except NotInvertible as exc:
        raise BadInput(
            f"{where}: {list(distortion)} cannot be inverted over the image with {whose} ({exc})"
        ) from exc


class NotInvertible(ValueError):
    """A pixel whose ray cannot be found: the lens folds there, or Newton's method missed it."""


@lru_cache(maxsize=1)  # the views of a task without intrinsics jitter share one
def _lens(intrinsics: Intrinsics, distortion: Distortion) -> Lens:
    K = intrinsics.matrix()
    width, height = intrinsics.width, intrinsics.height
    cols, rows = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    pixels = np.column_stack([cols.ravel(), rows.ravel()])
    # Where each ray meets the pinhole of the same K (pixels): the canvas holds them all.
    pinhole_px = rays(pixels, K, distortion) * K[0, 0] + K[:2, 2]
    low = np.floor(pinhole_px.min(axis=0)).astype(int) - CANVAS_MARGIN_PX
    high = np.ceil(pinhole_px.max(axis=0)).astype(int) + CANVAS_MARGIN_PX
    canvas_width, canvas_height = (int(n) for n in high - low + 1)
    cx, cy = float(K[0, 2] - low[0]), float(K[1, 2] - low[1])
    nominal_focal = (canvas_width / 2) / math.tan(math.radians(intrinsics.fov_deg) / 2)
    canvas = Intrinsics(
        width=canvas_width,
        height=canvas_height,
        fov_deg=intrinsics.fov_deg,
        offset_px=(cx - (canvas_width - 1) / 2, cy - (canvas_height - 1) / 2),
        focal_scale=float(K[0, 0]) / nominal_focal,
    )
    on_canvas = pinhole_px - low
    map_x = on_canvas[:, 0].reshape(height, width)
    map_y = on_canvas[:, 1].reshape(height, width)
    return Lens(
        intrinsics=intrinsics,
        distortion=distortion,
        canvas=canvas,
        map_x=map_x.astype(np.float32),
        map_y=map_y.astype(np.float32),
        rows=np.rint(map_y).astype(np.intp),
        cols=np.rint(map_x).astype(np.intp),
    )


def border_pixels(width: int, height: int) -> npt.NDArray[np.float64]:
    """The centres of an image's outermost pixels, (n, 2) as (u, v): under an invertible lens
    their rays bound every other pixel's."""
    u, v = np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64)
    top = np.column_stack([u, np.zeros(width)])
    bottom = np.column_stack([u, np.full(width, height - 1.0)])
    left = np.column_stack([np.zeros(height), v])
    right = np.column_stack([np.full(height, width - 1.0), v])
    return np.concatenate([top, bottom, left, right])


def rays(
    pixels: npt.NDArray[np.float64], K: npt.NDArray[np.float64], distortion: Sequence[float]
) -> npt.NDArray[np.float64]:
    """Each distorted pixel's ray as normalised pinhole coordinates (X/Z, Y/Z), (n, 2): `undistorted`
    in blocks (bounded memory at any resolution), each held to OpenCV's projection — it must land
    back on its pixel within `ROUND_TRIP_PX` — and to a map that does not fold there;
    NotInvertible otherwise."""
    out = np.empty_like(pixels)
    for start in range(0, len(pixels), RAYS_PER_BLOCK):
        block = pixels[start : start + RAYS_PER_BLOCK]
        found, folds = undistorted(block, K, distortion)
        if folds or not np.isfinite(found).all():
            raise NotInvertible("the map folds: weaken the distortion, the tangential terms p1, p2 first")
        back = project(np.column_stack([found, np.ones(len(found))]), K, distortion)
        miss = float(np.max(np.linalg.norm(back - block, axis=1)))
        if not miss <= ROUND_TRIP_PX:
            raise NotInvertible(f"a pixel's ray projects {miss:.3g} px off it: weaken the distortion")
        out[start : start + len(block)] = found
    return out


def radial_reach(distortion: Sequence[float], out_to: float) -> float:
    """How far out the lens stays invertible: the largest distorted radius (normalised) its radial
    map reaches while its slope is at least `MIN_RADIAL_SLOPE`, looking no further than `out_to`
    (returned when the map gets there). The spec's check (vint_core's `radial_reach`), walked on
    the same grid."""
    k1, k2, _, _, k3 = distortion
    if not (out_to > 0.0 and math.isfinite(out_to)):
        return out_to
    step = out_to / RADIAL_STEPS
    r = np.arange(0, math.floor(out_to / MIN_RADIAL_SLOPE / step) + 1) * step
    r2 = r * r
    radius = r * (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3)))
    slope = 1.0 + r2 * (3.0 * k1 + r2 * (5.0 * k2 + r2 * 7.0 * k3))
    flat = np.flatnonzero(slope < MIN_RADIAL_SLOPE)
    there = np.flatnonzero(radius >= out_to)
    if flat.size and (not there.size or flat[0] < there[0]):
        return min(float(radius[flat[0]]), out_to)
    return out_to


def project(
    points: npt.NDArray[np.float64], K: npt.NDArray[np.float64], distortion: Sequence[float]
) -> npt.NDArray[np.float64]:
    """Pixel coordinates (n, 2) of camera-frame points (n, 3) through `K` and `distortion`:
    OpenCV's projection, as any reader of `camera.json` would project."""
    if len(points) == 0:
        return np.zeros((0, 2))
    uv, _ = cv2.projectPoints(
        np.asarray(points, dtype=np.float64).reshape(-1, 1, 3),
        np.zeros(3),
        np.zeros(3),
        np.asarray(K, dtype=np.float64),
        np.asarray(distortion, dtype=np.float64),
    )
    return np.asarray(uv, dtype=np.float64).reshape(-1, 2)


def undistorted(
    pixels: npt.NDArray[np.float64], K: npt.NDArray[np.float64], distortion: Sequence[float]
) -> tuple[npt.NDArray[np.float64], bool]:
    """Each distorted pixel's ray as normalised pinhole coordinates (x, y) = (X/Z, Y/Z), and
    whether the map folds at some pixel's ray (its Jacobian's determinant not positive there).
    Newton's method on OpenCV's model, from the distorted point itself: along a monotone radius it
    approaches the ray from one side (OpenCV's own fixed-point undistortion can oscillate under
    strong pincushion). A pixel no ray reaches ends anywhere; `rays` catches it."""
    target_x = (pixels[:, 0] - K[0, 2]) / K[0, 0]
    target_y = (pixels[:, 1] - K[1, 2]) / K[1, 1]
    x, y = target_x.copy(), target_y.copy()
    for _ in range(NEWTON_STEPS):
        error_x, error_y, (xx, xy, yy) = _distorted(x, y, distortion, target_x, target_y)
        if float(np.max(np.abs(error_x) + np.abs(error_y))) < 1e-13:
            break
        determinant = xx * yy - xy * xy
        with np.errstate(divide="ignore", invalid="ignore"):  # a fold: caught below
            x = x - (yy * error_x - xy * error_y) / determinant
            y = y - (xx * error_y - xy * error_x) / determinant
    _, _, (xx, xy, yy) = _distorted(x, y, distortion, target_x, target_y)
    folds = not bool(np.all(xx * yy - xy * xy > 0.0))
    return np.column_stack([x, y]), folds


def _distorted(
    x: npt.NDArray[np.float64],
    y: npt.NDArray[np.float64],
    distortion: Sequence[float],
    target_x: npt.NDArray[np.float64],
    target_y: npt.NDArray[np.float64],
) -> tuple[
    npt.NDArray[np.float64],
    npt.NDArray[np.float64],
    tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]],
]:
    """OpenCV's distortion of normalised points (x, y) less the targets, and its Jacobian (its
    two diagonal entries and the off-diagonal one, which the model makes symmetric)."""
    k1, k2, p1, p2, k3 = (float(k) for k in distortion)
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    d_radial = k1 + r2 * (2.0 * k2 + r2 * 3.0 * k3)  # d(radial)/d(r²)
    error_x = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - target_x
    error_y = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - target_y
    xx = radial + 2.0 * x * x * d_radial + 2.0 * p1 * y + 6.0 * p2 * x
    xy = 2.0 * x * y * d_radial + 2.0 * p1 * x + 2.0 * p2 * y
    yy = radial + 2.0 * y * y * d_radial + 6.0 * p1 * y + 2.0 * p2 * x
    return error_x, error_y, (xx, xy, yy)
