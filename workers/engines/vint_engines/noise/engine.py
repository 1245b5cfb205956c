"""The noise engine: for each view, read `vNN_depth.png` or `.npy` (`vint_engines.depth_file`),
`vNN_segmentation.png` and `vNN_camera.json` (intrinsics; the material of each segment), write
`vNN_depth_noisy.png` (or `.npy`, as the task says)."""

from __future__ import annotations

import json
import platform
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from vint_engines import __version__, contract, depth_file
from vint_engines.noise.geometry import Intrinsics
from vint_engines.noise.model import NoiseModel, Surfaces
from vint_engines.protocol import BadInput, Json, TaskRequest, TaskResult
from vint_engines.render import lens


class NoiseEngine:
    def hello(self) -> Json:
        return {
            "name": "vint-noise",
            "version": __version__,
            "libs": {"python": platform.python_version(), "opencv": cv2.__version__, "numpy": np.__version__},
        }

    def close(self) -> None:
        pass

    def run(self, task: TaskRequest) -> TaskResult:
        model, views, depth_format = parse_params(task.params)
        result = TaskResult()
        for index, seed in views:
            prefix = f"v{index:02d}"
            depth = depth_file.read(depth_input(task, prefix))
            camera = load_camera(task.input_path(f"{prefix}_camera.json"))
            surfaces = None
            if model.materials:
                segmentation = load_segmentation(task.input_path(f"{prefix}_segmentation.png"))
                surfaces = Surfaces.from_segmentation(segmentation, segment_materials(camera, prefix))
            noisy = model.apply(
                depth, intrinsics(camera, depth.shape, prefix), surfaces, np.random.default_rng(seed)
            )
            out = depth_file.write(task.out_dir / f"{prefix}_depth_noisy", noisy, depth_format)
            result.add(out, depth_file.media_type(out))
        result.result = {"views": len(views)}
        result.metrics["views"] = len(views)
        return result


def parse_params(params: Mapping[str, Any]) -> tuple[NoiseModel, list[tuple[int, int]], str]:
    """A noise task's parameters, checked against the stage contract: the model, the views'
    (index, seed) pairs and the format the noisy depth is stored in."""
    checked = contract.validated("noise", params)
    views = [(view["view_index"], view["seed"]) for view in checked["views"]]
    if len({index for index, _ in views}) != len(views):
        raise BadInput("params.views: view_index values must be unique")
    return NoiseModel.parse(checked["noise"]), views, checked["depth_format"]


def depth_input(task: TaskRequest, prefix: str) -> Path:
    """The view's clean depth, in whichever format its render task wrote it; BadInput when the
    worker staged neither."""
    names = [f"{prefix}_depth.{fmt}" for fmt in depth_file.FORMATS]
    for ref in task.inputs:
        if ref.name in names:
            return ref.path
    raise BadInput(f"input {' or '.join(map(repr, names))} is missing (have {[r.name for r in task.inputs]})")


def load_camera(path: Path) -> Json:
    """The view's camera record (docs/rendering.md)."""
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise BadInput(f"cannot read camera record {path}: {exc}") from exc
    if not isinstance(record, dict):
        raise BadInput(f"camera record {path} is not a JSON object")
    return record


def load_segmentation(path: Path) -> np.ndarray:
    """The view's segment ids (uint8 or uint16 PNG)."""
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None or image.ndim != 2 or image.dtype not in (np.uint8, np.uint16):
        raise BadInput(f"segmentation {path} is not a single-channel 8- or 16-bit PNG")
    return image


def intrinsics(camera: Json, shape: tuple[int, ...], prefix: str) -> Intrinsics:
    """The intrinsics of `camera`'s `K`, checked against the depth map's size, with each pixel's
    ray through the lens when the record has a non-zero `dist` (OpenCV's [k1, k2, p1, p2, k3])."""
    try:
        K = np.asarray(camera["K"], dtype=np.float64)
        width, height = int(camera["width"]), int(camera["height"])
    except (KeyError, TypeError, ValueError) as exc:
        raise BadInput(f"{prefix}_camera.json: needs K (3×3), width and height: {exc}") from exc
    if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise BadInput(f"{prefix}_camera.json: K must be a finite 3×3 matrix with positive focal lengths")
    if (height, width) != tuple(shape):
        raise BadInput(
            f"{prefix}_camera.json: {width}×{height} does not match the depth map's {shape[1]}×{shape[0]}"
        )
    fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    dist = camera.get("dist")
    if dist is None:
        return Intrinsics(fx, fy, cx, cy)
    try:
        coefficients = np.asarray(dist, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise BadInput(f"{prefix}_camera.json: dist must be 5 numbers [k1, k2, p1, p2, k3]: {exc}") from exc
    if coefficients.shape != (5,) or not np.isfinite(coefficients).all():
        raise BadInput(f"{prefix}_camera.json: dist must be 5 finite numbers [k1, k2, p1, p2, k3]")
    if not coefficients.any():
        return Intrinsics(fx, fy, cx, cy)
    rows, cols = np.indices((height, width), dtype=np.float64)
    try:
        xy = lens.rays(np.column_stack([cols.ravel(), rows.ravel()]), K, coefficients.tolist())
    except lens.NotInvertible as exc:
        raise BadInput(f"{prefix}_camera.json: dist {coefficients.tolist()} does not invert: {exc}") from exc
    return Intrinsics(fx, fy, cx, cy, rays=(xy[:, 0].reshape(height, width), xy[:, 1].reshape(height, width)))


def segment_materials(camera: Json, prefix: str) -> dict[int, str]:
    """Segment id → material tag, from the camera record's `materials`."""
    materials = camera.get("materials")
    if not isinstance(materials, dict) or not all(isinstance(t, str) for t in materials.values()):
        raise BadInput(
            f"{prefix}_camera.json: `materials` (segment id → material tag) is missing or malformed"
        )
    try:
        return {int(segment): tag for segment, tag in materials.items()}
    except ValueError as exc:
        raise BadInput(f"{prefix}_camera.json: a `materials` key is not a segment id: {exc}") from exc


def make_engine() -> NoiseEngine:
    """The stage's engine (`vint_engines.stages`' convention)."""
    return NoiseEngine()
