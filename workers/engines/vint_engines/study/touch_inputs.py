"""What the touch-vs-vision estimator sees of a native vint dataset, per view: the back-projected
depth of the object's visible pixels and the active taxels, both in the camera frame (mm), plus
the ground truth it is scored against.

Reads only the dataset's files (`<sample>/meta.json`, `depth_noisy`/`depth` as `.png` or `.npy`,
`mask.png`, `<grasp>/grasp.json`, `models/<object>.ply`, `dataset.json`); knows nothing of how they
were made.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from vint_engines import depth_file
from vint_engines.objects import meshio
from vint_engines.poses import quat_to_matrix
from vint_engines.render import lens

Array = npt.NDArray[np.float64]


@dataclass(frozen=True)
class View:
    """One sample as the estimator and the scorer need it."""

    sample_id: str
    grasp_id: str
    object: str
    hand: str
    view: int  # the BOP im_id
    occlusion: float
    visible_px: int
    R_gt: Array  # model → camera
    t_gt_mm: Array
    vision_mm: Array  # (n, 3) camera frame: the visible pixels' depth, back-projected
    touch_mm: Array  # (k, 3) camera frame: the active taxels' positions


def back_project(
    depth_m: Array, mask: npt.NDArray[np.bool_], K: Array, dist: Sequence[float] | None = None
) -> Array:
    """Camera-frame points (mm) of the masked pixels with a depth reading (z along the optical axis,
    OpenCV axes; 0 = no return, dropped), each along its pixel's ray: through the lens `dist`
    (OpenCV's [k1, k2, p1, p2, k3], the camera record's) when the view has one."""
    v, u = np.nonzero(mask & (depth_m > 0) & np.isfinite(depth_m))
    z = depth_m[v, u].astype(np.float64) * 1000.0
    if dist is not None and any(dist):
        xy = lens.rays(np.column_stack([u, v]).astype(np.float64), K, dist)
        return np.column_stack([xy, np.ones(len(u))]) * z[:, None]
    pixels = np.stack([u.astype(np.float64), v.astype(np.float64), np.ones(len(u))])
    rays = np.linalg.solve(K, pixels)  # columns (x/z, y/z, 1)
    return (rays * z).T


def taxels_in_camera(grasp: dict[str, Any], R_w2c: Array, t_w2c_m: Array) -> Array:
    """The active taxels' positions (mm) in a view's camera frame: `p_palm` is in the palm link's
    frame, whose world pose is the trial's `link_poses.palm`."""
    active = grasp["touch"]["active"]
    if not active:
        return np.zeros((0, 3))
    palm = grasp["trial"]["link_poses"]["palm"]
    R_palm, p_palm = quat_to_matrix(palm["q"]), np.asarray(palm["p"], dtype=np.float64)
    local = np.asarray([taxel["p_palm"] for taxel in active], dtype=np.float64)
    world = local @ R_palm.T + p_palm
    return (world @ R_w2c.T + t_w2c_m) * 1000.0


def read_mask(path: Path) -> npt.NDArray[np.bool_]:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError(f"cannot read mask {path}")
    return np.asarray(image > 0 if image.ndim == 2 else image[..., 0] > 0)


def read_depth(sample: Path, stem: str) -> npt.NDArray[np.float32]:
    """The sample's depth file `stem` in whichever format it has (metres, 0 = no reading)."""
    path = depth_file.find(sample, stem)
    if path is None:
        raise FileNotFoundError(f"{sample}: no {stem}.png or {stem}.npy")
    return depth_file.read(path)


def read_view(data: Path, sample_id: str, noisy: bool, grasps: dict[str, dict[str, Any]]) -> View:
    sample = data / sample_id
    meta = json.loads((sample / "meta.json").read_text(encoding="utf-8"))
    camera = meta["camera"]
    K = np.asarray(camera["K"], dtype=np.float64)
    R_w2c, t_w2c = (
        np.asarray(camera["R_w2c"], dtype=np.float64),
        np.asarray(camera["t_w2c"], dtype=np.float64),
    )
    depth = read_depth(sample, "depth_noisy" if noisy else "depth")
    grasp_id = meta["grasp_id"]
    if grasp_id not in grasps:
        grasps[grasp_id] = json.loads((data / grasp_id / "grasp.json").read_text(encoding="utf-8"))
    return View(
        sample_id=sample_id,
        grasp_id=grasp_id,
        object=grasp_id.split(".")[0],
        hand=meta["hand"],
        view=int(sample_id.rsplit(".v", 1)[1]),
        occlusion=float(camera["occlusion"]),
        visible_px=int(camera["visible_px"]),
        R_gt=np.asarray(camera["R_m2c"], dtype=np.float64),
        t_gt_mm=np.asarray(camera["t_m2c"], dtype=np.float64) * 1000.0,
        vision_mm=back_project(depth, read_mask(sample / "mask.png"), K, camera.get("dist")),
        touch_mm=taxels_in_camera(grasps[grasp_id], R_w2c, t_w2c),
    )


def sample_ids(data: Path) -> list[str]:
    """The dataset's samples in sorted order (from the manifest, the dataset's table of contents)."""
    ids = []
    with (data / "manifest.jsonl").open(encoding="utf-8") as manifest:
        for line in manifest:
            entry = json.loads(line)
            if "sample_id" in entry:
                ids.append(entry["sample_id"])
    return sorted(ids)


def read_views(data: Path, noisy: bool) -> Iterator[View]:
    grasps: dict[str, dict[str, Any]] = {}
    for sample_id in sample_ids(data):
        yield read_view(data, sample_id, noisy, grasps)


def read_model_mm(data: Path, name: str) -> tuple[Array, npt.NDArray[np.int64]]:
    """The object's model mesh as the dataset ships it (`models/<name>.ply`), in mm."""
    vertices_m, faces = meshio.read_ply_m(data / "models" / f"{name}.ply")
    return vertices_m * 1000.0, faces


def object_ids(data: Path) -> dict[str, int]:
    """BOP obj_id per object name (`dataset.json`)."""
    doc = json.loads((data / "dataset.json").read_text(encoding="utf-8"))
    return {entry["name"]: int(entry["obj_id"]) for entry in doc["objects"]}


def sample_rng(seed: int, sample_id: str, stream: str) -> np.random.Generator:
    """A generator for one sample and one purpose, from the job seed and the sample's identity
    (sha256 of `stream:sample_id`), so no sample's draws depend on which others ran."""
    digest = hashlib.sha256(f"{stream}:{sample_id}".encode()).digest()
    return np.random.default_rng([seed, int.from_bytes(digest[:8], "little")])
