"""Cameras in the OpenCV convention (x right, y down, z forward) and the ONE conversion to Blender's
camera frame (x right, y up, looking down -z).

Intrinsics follow OpenCV's pixel convention: pixel (u, v) has its centre at integer coordinates,
so the principal point of a W×H image is ((W-1)/2, (H-1)/2). `fov_deg` is the horizontal field of
view; pixels are square. Pure numpy: no Blender import here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

Mat = npt.NDArray[np.float64]

# OpenCV camera axes expressed in Blender's camera axes: flip y and z.
_CV_TO_BLENDER = np.diag([1.0, -1.0, -1.0])

# Look-at targets jitter uniformly within this many metres per axis around the object centre.
TARGET_JITTER_M = 0.01
# A framed object's bounding circle keeps this share of the image's half-size from the edge.
FRAME_MARGIN = 0.05


@dataclass(frozen=True)
class Intrinsics:
    """A pinhole of `fov_deg` horizontal field of view over a `width`×`height` image, its principal
    point `offset_px` (x, y) pixels from the image centre and its focal length scaled by
    `focal_scale` (both as a calibrated real camera's differ from the nominal: `jittered`)."""

    width: int
    height: int
    fov_deg: float
    offset_px: tuple[float, float] = (0.0, 0.0)
    focal_scale: float = 1.0

    @property
    def focal_px(self) -> float:
        return self.focal_scale * (self.width / 2) / math.tan(math.radians(self.fov_deg) / 2)

    @property
    def principal_point(self) -> tuple[float, float]:
        return (self.width - 1) / 2 + self.offset_px[0], (self.height - 1) / 2 + self.offset_px[1]

    def matrix(self) -> Mat:
        f = self.focal_px
        cx, cy = self.principal_point
        return np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])

    def jittered(self, rng: np.random.Generator, sigma: float) -> Intrinsics:
        """These intrinsics as one unit of a camera model calibrates: the focal length scaled by
        1 + N(0, σ), the principal point moved by N(0, σ) of the image width and height. Three
        draws, always made; σ 0 returns them unchanged."""
        scale, dx, dy = rng.normal(0.0, 1.0, size=3)
        if sigma <= 0.0:
            return self
        return replace(
            self,
            offset_px=(float(dx * sigma * self.width), float(dy * sigma * self.height)),
            focal_scale=float(1.0 + scale * sigma),
        )

    def blender_shift(self) -> tuple[float, float]:
        """Blender's camera shift that puts the principal point at `principal_point`: a shift to
        the right moves the optical axis's image left, a shift up moves it down (image v grows
        downwards). Shifts are fractions of the sensor's fitted side, the image width (the
        camera's `sensor_fit` is horizontal, `scene.py`) — also for a taller than wide image,
        such as a distorted view's canvas (`lens.py`)."""
        return -self.offset_px[0] / self.width, self.offset_px[1] / self.width

    @property
    def angle_rad(self) -> float:
        """Blender's horizontal field of view for `focal_px`."""
        return 2.0 * math.atan((self.width / 2) / self.focal_px)


@dataclass(frozen=True)
class CameraPose:
    """World-to-camera transform in the OpenCV convention: x_c = R_w2c @ x_w + t_w2c."""

    R_w2c: Mat
    t_w2c: Mat

    @property
    def position(self) -> Mat:
        return -self.R_w2c.T @ self.t_w2c

    def blender_matrix_world(self) -> Mat:
        """4×4 camera-to-world matrix for a Blender camera object."""
        m = np.eye(4)
        m[:3, :3] = self.R_w2c.T @ _CV_TO_BLENDER
        m[:3, 3] = self.position
        return m

    def object_in_camera(self, R_m2w: Mat, t_m2w: Mat) -> tuple[Mat, Mat]:
        """(R_m2c, t_m2c) of an object whose pose in the world is (R_m2w, t_m2w)."""
        return self.R_w2c @ R_m2w, self.R_w2c @ t_m2w + self.t_w2c


def look_at(eye: Mat, target: Mat, up: Mat | None = None) -> CameraPose:
    """A camera at `eye` whose optical axis passes through `target`, image "up" towards `up`.

    Near the pole (optical axis almost parallel to `up`) another up vector is used, so the frame is
    always well defined.
    """
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - np.asarray(eye, dtype=np.float64)
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-6:
        x = np.cross(z, np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.9 else np.array([1.0, 0.0, 0.0]))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R_w2c = np.stack([x, y, z])
    return CameraPose(R_w2c, -R_w2c @ np.asarray(eye, dtype=np.float64))


def sample_on_hemisphere(
    rng: np.random.Generator,
    target: Mat,
    radius_m: tuple[float, float],
    elevation_deg: tuple[float, float],
    roll_deg: tuple[float, float] = (0.0, 0.0),
) -> CameraPose:
    """A camera at a random radius, elevation and (uniform) azimuth around `target`, looking at it
    with a small jitter, rolled about its optical axis by a uniform angle in `roll_deg`. The draw
    order is fixed: radius, elevation, azimuth, jitter, roll — the roll comes last, so a spec
    without one places its cameras exactly where it did before rolls existed."""
    radius = rng.uniform(*radius_m)
    elevation = math.radians(rng.uniform(*elevation_deg))
    azimuth = rng.uniform(0.0, 2.0 * math.pi)
    jitter = rng.uniform(-TARGET_JITTER_M, TARGET_JITTER_M, size=3)
    direction = np.array(
        [
            math.cos(elevation) * math.cos(azimuth),
            math.cos(elevation) * math.sin(azimuth),
            math.sin(elevation),
        ]
    )
    roll = math.radians(rng.uniform(*roll_deg))
    return rolled(look_at(target + radius * direction, target + jitter), roll)


def rolled(camera: CameraPose, angle: float) -> CameraPose:
    """`camera` turned by `angle` (radians) about its optical axis, in place: its x axis turns
    towards its y axis, so what it sees turns by `angle` counter-clockwise on screen."""
    c, s = math.cos(angle), math.sin(angle)
    turn = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    return CameraPose(turn @ camera.R_w2c, turn @ camera.t_w2c)


def framed(
    rng: np.random.Generator,
    camera: CameraPose,
    target: Mat,
    radius_m: float,
    intrinsics: Intrinsics,
    offcentre: float,
) -> CameraPose:
    """`camera` turned about its own centre so that `target` lands at a random pixel instead of
    near the image centre: uniformly within `offcentre` of the way to the image edge on each axis,
    but never so far that a sphere of `radius_m` around `target` leaves the image (less a margin of
    `FRAME_MARGIN` of the half-size). The turn is the smallest one that moves the target's ray onto
    the chosen pixel's ray, so the roll barely changes. Two uniform draws, always made (a fixed
    draw order); `offcentre` 0 returns the camera as it was."""
    a, b = rng.uniform(-1.0, 1.0, size=2)
    if offcentre <= 0.0:
        return camera
    seen = camera.R_w2c @ np.asarray(target, dtype=np.float64) + camera.t_w2c
    distance = float(np.linalg.norm(seen))
    if distance <= radius_m or seen[2] <= 0.0:
        return camera  # inside the object's sphere, or looking away: nothing to frame
    f = intrinsics.focal_px
    radius_px = f * math.tan(math.asin(radius_m / distance))
    half_w, half_h = intrinsics.width / 2, intrinsics.height / 2
    margin_px = FRAME_MARGIN * min(half_w, half_h)
    reach_x = max(0.0, min(offcentre * half_w, half_w - radius_px - margin_px))
    reach_y = max(0.0, min(offcentre * half_h, half_h - radius_px - margin_px))
    K = intrinsics.matrix()
    pixel = np.array([K[0, 2] + a * reach_x, K[1, 2] + b * reach_y, 1.0])
    wanted = np.linalg.solve(K, pixel)
    return turned_onto(camera, seen / distance, wanted / np.linalg.norm(wanted))


def turned_onto(camera: CameraPose, ray: Mat, wanted: Mat) -> CameraPose:
    """`camera` turned about its centre by the smallest rotation that takes the camera-frame
    direction `ray` to `wanted` (both unit vectors)."""
    axis = np.cross(ray, wanted)
    sin = float(np.linalg.norm(axis))
    cos = float(np.dot(ray, wanted))
    if sin < 1e-12:
        return camera
    k = axis / sin
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    turn = np.eye(3) + sin * cross + (1.0 - cos) * (cross @ cross)
    return CameraPose(turn @ camera.R_w2c, turn @ camera.t_w2c)
