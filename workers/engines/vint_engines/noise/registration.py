"""The depth camera's own viewpoint: which pixels of the colour camera's depth map the time-of-
flight camera beside it cannot see.

An Azure Kinect's depth comes from its ToF camera, a few centimetres from the colour camera and
tilted 6° down against it (Microsoft, "Azure Kinect DK coordinate systems"); a depth image
registered onto the colour camera (the SDK's depth-to-colour transformation) has no reading where
the colour camera sees a surface that something nearer hides from the ToF camera: the occlusion
shadow beside every finger in front of the object. It also has none where the ToF camera's
coarser pixel grid puts a nearer surface in the same pixel: the resampling holes along edges.

The model reprojects the clean depth map. Every valid pixel's 3-D point goes into the ToF camera
(centre `baseline_m` along the colour camera's +x, turned `TILT_DEG` about its x axis) and onto
the ToF's native pixel grid (the mode's resolution and horizontal field of view); each ToF pixel
keeps its nearest point. A colour pixel is seen when its point is that nearest one, within a
tolerance that lets a slanted surface span a ToF pixel; otherwise it reads nothing. Points outside
the mode's field of view read nothing either. Deterministic: it draws no random numbers.

Left out: the ToF's own depth is not re-sampled onto the colour grid (each colour pixel keeps its
clean depth, then gets the noise below), and surfaces the colour camera cannot see at all (behind
its own occluders) cannot cast shadows: the depth map holds only what the colour camera sees.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from vint_engines.noise.geometry import Intrinsics
from vint_engines.noise.sensor import Mode

Depth = npt.NDArray[np.float32]
Mask = npt.NDArray[np.bool_]

TILT_DEG = 6.0  # the depth camera against the colour camera (Microsoft's coordinate-systems page)
# A point is hidden when it lies farther than the nearest point of its ToF pixel by more than
# this, plus SLOPE_PIXELS native pixels' worth of depth (a surface at up to ~70° to the ray spans
# that much depth across one pixel).
HIDDEN_MIN_M = 0.001
SLOPE_PIXELS = 3.0


def nearest_per_pixel(pixel: npt.NDArray[np.int64], z: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """For each point, the smallest z of all points in its pixel (a z-buffer, by sorting)."""
    order = np.lexsort((z, pixel))
    sorted_pixel = pixel[order]
    first = np.r_[True, sorted_pixel[1:] != sorted_pixel[:-1]]  # the nearest point of each pixel
    starts, group = np.flatnonzero(first), np.cumsum(first) - 1
    nearest = np.empty_like(z)
    nearest[order] = z[order][starts][group]
    return nearest


def seen_by_tof(depth: Depth, valid: Mask, k: Intrinsics, mode: Mode, baseline_m: float) -> Mask:
    """Where the ToF camera sees the surface the colour camera's pixel shows (H×W)."""
    rows, cols = np.nonzero(valid)
    seen = np.zeros(depth.shape, bool)
    if rows.size == 0:
        return seen
    z = depth[rows, cols].astype(np.float64)
    # The point in the ToF's frame: shifted by the baseline along x, turned by the tilt about x
    # (the ToF looks 6° further down: its optical axis is the colour's turned towards +y).
    if k.rays is None:
        x = (cols - k.cx) / k.fx * z - baseline_m
        y = (rows - k.cy) / k.fy * z
    else:  # a distorted view: each pixel's own ray
        x = k.rays[0][rows, cols] * z - baseline_m
        y = k.rays[1][rows, cols] * z
    cos_t, sin_t = math.cos(math.radians(TILT_DEG)), math.sin(math.radians(TILT_DEG))
    y_tof = cos_t * y - sin_t * z
    z_tof = sin_t * y + cos_t * z
    ahead = z_tof > 1e-6
    focal = mode.width_px / 2 / math.tan(math.radians(mode.fov_h_deg) / 2)  # native px, square pixels
    safe_z = np.where(ahead, z_tof, 1.0)
    u = x / safe_z * focal
    v = y_tof / safe_z * focal
    inside = ahead & (np.abs(u) < mode.width_px / 2) & (np.abs(v) < mode.height_px / 2)
    pixel = np.floor(u + mode.width_px / 2).astype(np.int64) * mode.height_px + np.floor(
        v + mode.height_px / 2
    ).astype(np.int64)
    front = np.full(z_tof.shape, np.inf)
    front[inside] = nearest_per_pixel(pixel[inside], z_tof[inside])
    tolerance = HIDDEN_MIN_M + SLOPE_PIXELS * z_tof / focal
    seen[rows, cols] = inside & (z_tof <= front + tolerance)
    return seen
