"""Where a grasp's taxels fall in a view: the camera of the sample's `meta.json` (OpenCV: `K`,
`R_w2c`, `t_w2c`, and `dist` when the view has a distorted lens; `docs/rendering.md`) applied to
the grasp record's taxels.

Active taxels come from `grasp.json`'s `touch.active` (position in the palm frame, reading), taken
into the world by the palm's pose `trial.hand_pose`: `p_cam = R_w2c (R_palm p_palm + t_palm) +
t_w2c`, as `docs/formats.md` defines `scene_touch.json`'s `p_cam_mm`. The whole layout (to draw the
inactive taxels faintly) is the catalog's file the record names (`hand.taxels.layout`), used only
when its SHA-256 is the one the record cites: positions in each link's frame, taken into the world
by `trial.link_poses`. A hand brought by a spec has no catalog file here, and gets no faint skin.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from vint_engines.errors import BadInput
from vint_engines.grasp.taxels import parse_layout
from vint_engines.poses import quat_to_matrix

Array = npt.NDArray[np.float64]

SEEN_WITHIN_M = 0.004  # a taxel this far behind the surface its pixel shows still counts as seen


@dataclass(frozen=True)
class Camera:
    """A view's camera: pixel (u, v) centred on integer coordinates, OpenCV's lens distortion
    `dist` ([k1, k2, p1, p2, k3]; all 0, as a record without it says: a pinhole;
    `docs/rendering.md`)."""

    K: Array  # (3, 3)
    R_w2c: Array  # (3, 3)
    t_w2c: Array  # (3,)
    width: int
    height: int
    dist: Array = field(default_factory=lambda: np.zeros(5))  # (5,)

    @staticmethod
    def from_record(camera: dict[str, Any]) -> Camera:
        """From a `meta.json` `camera` record (the render stage's `camera.json`)."""
        return Camera(
            K=np.asarray(camera["K"], dtype=np.float64).reshape(3, 3),
            R_w2c=np.asarray(camera["R_w2c"], dtype=np.float64).reshape(3, 3),
            t_w2c=np.asarray(camera["t_w2c"], dtype=np.float64).reshape(3),
            width=int(camera["width"]),
            height=int(camera["height"]),
            dist=np.asarray(camera.get("dist", [0.0] * 5), dtype=np.float64).reshape(5),
        )

    def project(self, points_world: Array) -> tuple[Array, Array]:
        """Pixel coordinates (n, 2) and camera-frame depth z (n,) of world points (n, 3); a point
        behind the camera (z ≤ 0) gets a pixel no caller draws."""
        p_cam = points_world @ self.R_w2c.T + self.t_w2c
        z = p_cam[:, 2]
        if np.any(self.dist) and len(p_cam):
            uv, _ = cv2.projectPoints(p_cam.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), self.K, self.dist)
            return uv.reshape(-1, 2), z
        with np.errstate(divide="ignore", invalid="ignore"):
            uvw = p_cam @ self.K.T
            uv = uvw[:, :2] / uvw[:, 2:3]
        return uv, z


@dataclass(frozen=True)
class ProjectedTaxels:
    """Taxels in one view: pixel (u, v), camera-frame depth z (m) and reading (0 when inactive)."""

    uv: Array  # (n, 2)
    z: Array  # (n,)
    reading: Array  # (n,)

    @staticmethod
    def empty() -> ProjectedTaxels:
        return ProjectedTaxels(np.zeros((0, 2)), np.zeros(0), np.zeros(0))

    def __len__(self) -> int:
        return len(self.z)


def pose_matrix(pose: dict[str, Any]) -> tuple[Array, Array]:
    """(R, t) of a `{p, q}` pose (q = [w, x, y, z])."""
    q = np.asarray(pose["q"], dtype=np.float64)
    return quat_to_matrix(q / np.linalg.norm(q)), np.asarray(pose["p"], dtype=np.float64).reshape(3)


def active_taxels(grasp: dict[str, Any], camera: Camera) -> ProjectedTaxels:
    """The grasp's active taxels in `camera`'s image."""
    active = grasp["touch"]["active"]
    if not active:
        return ProjectedTaxels.empty()
    R_palm, t_palm = pose_matrix(grasp["trial"]["hand_pose"])
    p_palm = np.asarray([taxel["p_palm"] for taxel in active], dtype=np.float64).reshape(-1, 3)
    uv, z = camera.project(p_palm @ R_palm.T + t_palm)
    return ProjectedTaxels(uv, z, np.asarray([float(taxel["reading"]) for taxel in active]))


def layout_taxels(grasp: dict[str, Any], camera: Camera, catalog_dir: Path) -> ProjectedTaxels | None:
    """Every taxel of the hand's layout in `camera`'s image, or None when the layout the record
    cites is not this catalog's file (a spec's own hand, or a catalog changed since)."""
    info = grasp.get("hand", {}).get("taxels", {})
    name, sha256 = info.get("layout"), info.get("sha256")
    if not isinstance(name, str) or not isinstance(sha256, str):
        return None
    path = (catalog_dir / name).resolve()
    if not path.is_relative_to(catalog_dir.resolve()) or not path.is_file():
        return None
    raw = path.read_bytes()
    if hashlib.sha256(raw).hexdigest() != sha256:
        return None
    poses = {link: pose_matrix(pose) for link, pose in grasp["trial"].get("link_poses", {}).items()}
    try:
        layout = parse_layout(raw.decode("utf-8"), poses.keys(), str(path))
    except BadInput:
        return None  # a layout for other links than the record's
    world = np.array(
        [poses[link][0] @ p + poses[link][1] for link, p in zip(layout.links, layout.positions, strict=True)]
    ).reshape(-1, 3)
    uv, z = camera.project(world)
    readings = np.asarray(grasp["touch"].get("readings", []), dtype=np.float64)
    if readings.shape != (len(layout),):
        readings = np.zeros(len(layout))
    return ProjectedTaxels(uv, z, readings)


def in_view(taxels: ProjectedTaxels, camera: Camera) -> npt.NDArray[np.bool_]:
    """In front of the camera and on the image (pixel centres on integers, so the image spans
    -0.5 … width - 0.5)."""
    u, v = taxels.uv[:, 0], taxels.uv[:, 1]
    with np.errstate(invalid="ignore"):
        return (
            (taxels.z > 0) & (u >= -0.5) & (u < camera.width - 0.5) & (v >= -0.5) & (v < camera.height - 0.5)
        )


def unoccluded(taxels: ProjectedTaxels, depth: npt.NDArray[np.floating] | None) -> npt.NDArray[np.bool_]:
    """Taxels no surface hides: the depth at their pixel is no nearer than their own z less
    `SEEN_WITHIN_M` (the skin lies on its link's surface; a contact taxel facing away from the
    camera has its own finger in front). Without a depth image, or where it has no return, every
    taxel counts as seen."""
    if depth is None or len(taxels) == 0:
        return np.ones(len(taxels), dtype=bool)
    h, w = depth.shape
    col = np.clip(np.round(np.nan_to_num(taxels.uv[:, 0])).astype(np.int64), 0, w - 1)
    row = np.clip(np.round(np.nan_to_num(taxels.uv[:, 1])).astype(np.int64), 0, h - 1)
    surface = depth[row, col].astype(np.float64)
    no_return = ~np.isfinite(surface) | (surface <= 0)
    return no_return | (surface >= taxels.z - SEEN_WITHIN_M)
