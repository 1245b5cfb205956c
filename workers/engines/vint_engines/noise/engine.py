"""The noise engine: for each view, read `vNN_depth.npy`, write `vNN_depth_noisy.npy`."""

from __future__ import annotations

import platform
from pathlib import Path

import cv2
import numpy as np

from vint_engines import __version__
from vint_engines import params as P
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
        model = NoiseModel.parse(task.params.get("noise", {}))
        views = P.views(task.params)
        result = TaskResult()
        for index, seed in views:
            depth = load_depth(task.input_path(f"v{index:02d}_depth.npy"))
            noisy = model.apply(depth, np.random.default_rng(seed))
            out = task.out_dir / f"v{index:02d}_depth_noisy.npy"
            np.save(out, noisy)
            result.add(out, "application/x-npy")
        result.metrics["views"] = len(views)
        return result


def load_depth(path: Path) -> np.ndarray:
    """The depth map at `path`. I/O errors propagate (retryable); a malformed file is BadInput."""
    try:
        depth = np.load(path, allow_pickle=False)
    except ValueError as exc:
        raise BadInput(f"cannot read depth map {path}: {exc}") from exc
    if not np.issubdtype(depth.dtype, np.floating):
        raise BadInput(f"depth map {path} has dtype {depth.dtype}, expected float")
    return depth
