"""The render engine: for each view of a grasp, render RGB/depth/mask and write the camera.

Builds the Blender scene once (and renders a tiny warm-up frame so the first task does not pay
for kernel loading); per task it reads `grasps.json` (and the object's model mesh `object.ply`
when the worker staged it), poses the hand and the object, then renders
each view under its own environment (`render.environment` unless the view names one) from a
camera sampled with the view's seed.
"""

from __future__ import annotations

import json
import platform
import shutil
import tempfile
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import bpy
import cv2
import numpy as np

from vint_engines import __version__
from vint_engines import params as P
from vint_engines.objects import MODEL_FILE
from vint_engines.poses import quat_to_matrix, read_pose
from vint_engines.protocol import BadInput, Json, TaskRequest, TaskResult
from vint_engines.render.camera import Intrinsics, look_at, sample_on_hemisphere
from vint_engines.render.passes import Passes
from vint_engines.render.scene import OBJECT_PASS_INDEX, BlenderScene, check_environment

GRASPS_INPUT = "grasps.json"
OUTPUT_KINDS = ("rgb", "depth", "mask")


@dataclass(frozen=True)
class RenderSettings:
    intrinsics: Intrinsics
    samples: int
    environment: str
    radius_m: tuple[float, float]
    elevation_deg: tuple[float, float]

    @staticmethod
    def parse(obj: Mapping[str, Any]) -> RenderSettings:
        where = "params.render"
        return RenderSettings(
            intrinsics=Intrinsics(
                width=P.integer(obj, "width", where, 128, low=8, high=8192),
                height=P.integer(obj, "height", where, 128, low=8, high=8192),
                fov_deg=P.number(obj, "fov_deg", where, 60.0, low=5.0, high=150.0),
            ),
            samples=P.integer(obj, "samples", where, 16, low=1, high=65536),
            environment=environment_param(obj, "environment", where, "studio"),
            radius_m=P.number_range(obj, "radius_m", where, (0.35, 0.5), low=0.05),
            elevation_deg=P.number_range(obj, "elevation_deg", where, (15.0, 75.0), low=-90.0),
        )


@dataclass(frozen=True)
class RenderView:
    index: int
    seed: int
    environment: str

    @staticmethod
    def parse_all(params: Mapping[str, Any], default_environment: str) -> list[RenderView]:
        """`params.views`; a view without `environment` renders under `default_environment`."""
        views = []
        raw_views = P.items(params, "views", "params")
        for i, ((index, seed), raw) in enumerate(zip(P.views(params), raw_views, strict=True)):
            environment = environment_param(raw, "environment", f"params.views[{i}]", default_environment)
            views.append(RenderView(index, seed, environment))
        return views


def environment_param(obj: Mapping[str, Any], key: str, where: str, default: str) -> str:
    """The bundled HDRI named at `obj[key]` (or `default`); BadInput for an unknown name."""
    name = P.string(obj, key, where, default)
    check_environment(name, f"{where}.{key}")
    return name


class RenderEngine:
    def __init__(self) -> None:
        self.scratch = Path(tempfile.mkdtemp(prefix="vint-render-"))
        self.scene = BlenderScene(self.scratch)
        self._warm_up()

    def hello(self) -> Json:
        return {
            "name": "vint-render",
            "version": __version__,
            "libs": {
                "python": platform.python_version(),
                "bpy": bpy.app.version_string,
                "numpy": np.__version__,
                "opencv": cv2.__version__,
            },
        }

    def close(self) -> None:
        shutil.rmtree(self.scratch, ignore_errors=True)

    def _warm_up(self) -> None:
        """Render one tiny empty frame: loads the Cycles kernels and the default HDRI's map."""
        self.scene.set_environment("studio")
        eye = np.array([0.0, -1.0, 0.5])
        self.scene.render(look_at(eye, np.zeros(3)), Intrinsics(8, 8, 60.0), 1, 0, rgb=False)

    def run(self, task: TaskRequest) -> TaskResult:
        params = task.params
        settings = RenderSettings.parse(params.get("render", {}))
        outputs = params.get("outputs", list(OUTPUT_KINDS))
        if not isinstance(outputs, list) or not set(outputs) <= set(OUTPUT_KINDS):
            raise BadInput(f"params.outputs: expected a subset of {list(OUTPUT_KINDS)}, got {outputs!r}")
        grasp_index = P.integer(params, "grasp_index", "params", low=0)
        views = RenderView.parse_all(params, settings.environment)
        grasps = load_grasps(task.input_path(GRASPS_INPUT))

        trial = find_trial(grasps, grasp_index)
        self.scene.set_hand(grasps["hand"])
        self.scene.set_object(grasps["object"], staged_input(task, MODEL_FILE))
        object_pose = read_pose(trial["object_pose"], f"grasps.json trial {grasp_index} object_pose")
        links = {name: read_pose(pose, f"link_poses.{name}") for name, pose in trial["link_poses"].items()}
        self.scene.pose(object_pose, links)

        result = TaskResult()
        render_s = 0.0
        for view in views:
            started = time.perf_counter()
            self.scene.set_environment(view.environment)
            self._render_view(task.out_dir, view, settings, outputs, object_pose, result)
            render_s += time.perf_counter() - started
        result.metrics.update(views=len(views), render_ms_per_view=round(1e3 * render_s / len(views), 3))
        return result

    def _render_view(
        self,
        out_dir: Path,
        view: RenderView,
        settings: RenderSettings,
        outputs: list[str],
        object_pose: tuple[np.ndarray, np.ndarray],
        result: TaskResult,
    ) -> None:
        prefix = f"v{view.index:02d}"
        p_obj, q_obj = object_pose
        camera = sample_on_hemisphere(
            np.random.default_rng(view.seed), p_obj, settings.radius_m, settings.elevation_deg
        )
        passes = self.scene.render(
            camera, settings.intrinsics, settings.samples, view.seed, rgb="rgb" in outputs
        )
        mask = object_mask(passes)
        if passes.rgb is not None:
            result.add(write_png(out_dir / f"{prefix}_rgb.png", passes.rgb), "image/png")
        if "depth" in outputs:
            path = out_dir / f"{prefix}_depth.npy"
            np.save(path, passes.depth)
            result.add(path, "application/x-npy")
        if "mask" in outputs:
            result.add(write_png(out_dir / f"{prefix}_mask.png", mask), "image/png")
        R_m2c, t_m2c = camera.object_in_camera(quat_to_matrix(q_obj), p_obj)
        intrinsics = settings.intrinsics
        record = {
            "K": intrinsics.matrix().tolist(),
            "width": intrinsics.width,
            "height": intrinsics.height,
            "R_w2c": camera.R_w2c.tolist(),
            "t_w2c": camera.t_w2c.tolist(),
            "R_m2c": R_m2c.tolist(),
            "t_m2c": t_m2c.tolist(),
            "visible_px": int(np.count_nonzero(mask)),
            "environment": view.environment,
        }
        path = out_dir / f"{prefix}_camera.json"
        path.write_text(json.dumps(record, indent=1))
        result.add(path, "application/json")


def object_mask(passes: Passes) -> np.ndarray:
    """uint8 mask, 255 where the object is the visible surface."""
    return np.where(passes.index == OBJECT_PASS_INDEX, 255, 0).astype(np.uint8)


def write_png(path: Path, image: np.ndarray) -> Path:
    if not cv2.imwrite(str(path), image):
        raise OSError(f"cannot write {path}")
    return path


def staged_input(task: TaskRequest, name: str) -> Path | None:
    """The path of an optional input, or None when the worker did not stage it."""
    return next((ref.path for ref in task.inputs if ref.name == name), None)


def load_grasps(path: Path) -> dict[str, Any]:
    """The grasp document at `path`. I/O errors propagate (retryable); malformed JSON is BadInput."""
    try:
        grasps = json.loads(path.read_text())
    except ValueError as exc:
        raise BadInput(f"cannot read {GRASPS_INPUT} at {path}: {exc}") from exc
    if not isinstance(grasps, dict) or not all(k in grasps for k in ("hand", "object", "trials")):
        raise BadInput(f"{GRASPS_INPUT}: expected an object with hand, object and trials")
    return grasps


def find_trial(grasps: Mapping[str, Any], grasp_index: int) -> Mapping[str, Any]:
    for trial in grasps["trials"]:
        if trial.get("grasp_index") == grasp_index:
            if not trial.get("accepted"):
                raise BadInput(f"grasp {grasp_index} was rejected ({trial.get('reason')}); nothing to render")
            return trial
    raise BadInput(f"{GRASPS_INPUT} has no trial with grasp_index {grasp_index}")
