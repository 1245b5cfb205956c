"""What the noise model reads off a depth map's geometry: incidence angles (from normals estimated
with the camera's intrinsics) and the concavity of the surface around each pixel."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
import numpy.typing as npt

Image = npt.NDArray[np.float32]
Mask = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class Intrinsics:
    """A camera: K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (OpenCV, docs/rendering.md) and, for a
    view with lens distortion, each pixel's ray through the lens: `rays` = (X/Z, Y/Z), H×W each,
    in place of the pinhole's ((u - cx) / fx, (v - cy) / fy)."""

    fx: float
    fy: float
    cx: float
    cy: float
    rays: tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]] | None = field(default=None, compare=False)


def cos_incidence(depth: Image, valid: Mask, k: Intrinsics) -> Image:
    """|cos| of the angle between each pixel's ray and its surface normal. The normal is the cross
    product of the back-projected point's differences along u and v, each taken on the side whose
    depth step is smaller (so a depth edge does not tilt the surfaces beside it). A pixel without a
    valid neighbour along an axis gets 1 (nothing to estimate from)."""
    h, w = depth.shape
    if k.rays is None:
        u = (np.arange(w, dtype=np.float32) - np.float32(k.cx)) / np.float32(k.fx)
        v = (np.arange(h, dtype=np.float32) - np.float32(k.cy)) / np.float32(k.fy)
        x = depth * u[None, :]
        y = depth * v[:, None]
    else:
        x = depth * k.rays[0].astype(np.float32)
        y = depth * k.rays[1].astype(np.float32)
    points = np.stack([x, y, depth], axis=-1)
    du = _one_sided_difference(points, valid, axis=1)
    dv = _one_sided_difference(points, valid, axis=0)
    normal = np.cross(du, dv)
    n_norm = np.linalg.norm(normal, axis=-1)
    p_norm = np.linalg.norm(points, axis=-1)
    dot = np.abs(np.sum(normal * points, axis=-1))
    known = (n_norm > 0) & (p_norm > 0) & valid
    cos = np.ones(depth.shape, np.float32)
    np.divide(dot, n_norm * p_norm, out=cos, where=known)
    return np.clip(cos, 0.0, 1.0).astype(np.float32)


def _one_sided_difference(points: npt.NDArray[np.float32], valid: Mask, axis: int) -> npt.NDArray[np.float32]:
    """Per pixel, the forward or the backward difference of `points` along `axis`, whichever has the
    smaller |Δz| among those whose neighbour is valid; zero where neither neighbour is."""
    forward = np.zeros_like(points)
    backward = np.zeros_like(points)
    ok_f = np.zeros(valid.shape, bool)
    ok_b = np.zeros(valid.shape, bool)
    ahead = [slice(None)] * 2
    behind = [slice(None)] * 2
    ahead[axis], behind[axis] = slice(1, None), slice(None, -1)
    a, b = tuple(ahead), tuple(behind)
    forward[b] = points[a] - points[b]
    ok_f[b] = valid[a] & valid[b]
    backward[a] = points[a] - points[b]
    ok_b[a] = valid[a] & valid[b]
    dz_f = np.where(ok_f, np.abs(forward[..., 2]), np.inf)
    dz_b = np.where(ok_b, np.abs(backward[..., 2]), np.inf)
    use_b = dz_b < dz_f
    out = np.where(use_b[..., None], backward, forward)
    out[~(ok_f | ok_b)] = 0
    return out


def concavity(depth: Image, valid: Mask, sigma_px: float) -> Image:
    """How far (m, positive) each pixel lies behind the smooth surface its neighbours span: the
    Gaussian-weighted mean of valid neighbours' inverse depth minus the pixel's own, times z².
    Inverse depth is linear in (u, v) on a plane, so any plane, however tilted, reads 0; a concave
    corner (a finger against an object) reads positive, a convex edge negative."""
    inverse = np.where(valid, 1.0 / np.where(valid, depth, 1.0), 0.0).astype(np.float32)
    weight = valid.astype(np.float32)
    size = 2 * int(np.ceil(3 * sigma_px)) + 1
    blurred = cv2.GaussianBlur(inverse, (size, size), sigma_px, borderType=cv2.BORDER_REPLICATE)
    norm = cv2.GaussianBlur(weight, (size, size), sigma_px, borderType=cv2.BORDER_REPLICATE)
    mean = np.zeros_like(inverse)
    np.divide(blurred, norm, out=mean, where=norm > 1e-6)
    return np.where(valid, (mean - inverse) * depth * depth, 0.0).astype(np.float32)


def local_span(depth: Image, valid: Mask, size: int) -> tuple[Image, Image]:
    """The (min, max) of valid depths in each pixel's size×size window; an invalid pixel counts as
    infinitely far for the max and is ignored for the min."""
    kernel = np.ones((size, size), np.uint8)
    far = np.float32(1e6)
    source = np.where(valid, depth, far).astype(np.float32)
    low = cv2.erode(source, kernel, borderType=cv2.BORDER_REPLICATE)
    high = cv2.dilate(source, kernel, borderType=cv2.BORDER_REPLICATE)
    return low, high
