"""The noise engine: for each view, read `vNN_depth.npy`, write `vNN_depth_noisy.npy`."""

from __future__ import annotations

import platform
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from vint_engines import __version__, contract
from vint_engines.noise.model import NoiseModel
from vint_engines.protocol import BadInput, Json, TaskRequest, TaskResult


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
        model, views = parse_params(task.params)
        result = TaskResult()
        for index, seed in views:
            depth = load_depth(task.input_path(f"v{index:02d}_depth.npy"))
            noisy = model.apply(depth, np.random.default_rng(seed))
            out = task.out_dir / f"v{index:02d}_depth_noisy.npy"
            np.save(out, noisy)
            result.add(out, "application/x-npy")
        result.result = {"views": len(views)}
        result.metrics["views"] = len(views)
        return result


def parse_params(params: Mapping[str, Any]) -> tuple[NoiseModel, list[tuple[int, int]]]:
    """A noise task's parameters, checked against the stage contract: the model and the views'
    (index, seed) pairs."""
    checked = contract.validated("noise", params)
    views = [(view["view_index"], view["seed"]) for view in checked["views"]]
    if len({index for index, _ in views}) != len(views):
        raise BadInput("params.views: view_index values must be unique")
    return NoiseModel.parse(checked["noise"]), views


def load_depth(path: Path) -> np.ndarray:
    """The depth map at `path`. I/O errors propagate (retryable); a malformed file is BadInput."""
    try:
        depth = np.load(path, allow_pickle=False)
    except ValueError as exc:
        raise BadInput(f"cannot read depth map {path}: {exc}") from exc
    if not np.issubdtype(depth.dtype, np.floating):
        raise BadInput(f"depth map {path} has dtype {depth.dtype}, expected float")
    return depth
