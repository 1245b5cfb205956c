"""The render engine: for each view of a grasp, render what the task's outputs need and write the
camera.

Builds the Blender scenes once (and renders a tiny warm-up frame so the first task does not pay
for kernel loading); per task it reads `grasps.json` (and the object's model mesh `object.ply`
when the worker staged it), poses the hand and the object, then renders each view from a camera
sampled with the view's seed (or given by the view): always the geometry passes (depth, pass
indices, the object's full mask; no path tracing) — for a sampled camera once per attempt, redrawn
until the hand's occlusion of the object is within `render.occlusion` (`viewpoint.py`) —, and the
path-traced RGB image under the view's environment only when `rgb` is requested (once per view,
for the chosen camera), with bounce caps pruned to what the materials can use. A view with lens
distortion renders a pinhole canvas and resamples every image into its distorted camera
(`lens.py`), the geometry passes within each attempt.
Views are rendered grouped by environment, starting with the one already loaded (every view's
output depends on its own parameters only, so the order changes no pixel). An environment is a
bundled HDRI or a user's file staged with the task (`params.assets`), known by its SHA-256.
"""

from __future__ import annotations

import json
import platform
import shutil
import tempfile
import time
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import bpy
import cv2
import numpy as np
import pyoidn

from vint_engines import __version__, contract, depth_file
from vint_engines.assets import StagedAsset, asset_file, staged_assets
from vint_engines.objects import MODEL_FILE, ObjectSpec, build_model, load_catalog
from vint_engines.objects.spec import MeshFile
from vint_engines.objects.textured import MeshSource
from vint_engines.poses import quat_to_matrix, read_pose
from vint_engines.protocol import BadInput, Json, TaskRequest, TaskResult
from vint_engines.render import clutter, cpus, dressing, lighting, viewpoint
from vint_engines.render.camera import CameraPose, Intrinsics, framed, look_at, sample_on_hemisphere
from vint_engines.render.cycles import Bounces, PathTracing, render_threads
from vint_engines.render.denoise import Denoiser
from vint_engines.render.dressing import SceneDressing
from vint_engines.render.fireflies import despeckle
from vint_engines.render.lens import Distortion, Lens, check_lens, is_pinhole, view_lens
from vint_engines.render.scene import OBJECT_PASS_INDEX, BlenderScene, Geometry, Hdri, Radiance, environments
from vint_engines.render.sensor import SensorModel, capture, encode_srgb8
from vint_engines.render.viewpoint import Palm, Viewpoint, ViewpointRule, attempt_rng, occlusion_share

GRASPS_INPUT = "grasps.json"
INTRINSICS_STREAM = 0x1C  # appended to the view's seed: the intrinsics jitter's own random stream
DISTORTION_FIELD = "params.render.distortion"
SIDECAR_SUFFIXES = (".mtl", ".png", ".jpg", ".jpeg", ".bin")  # vint_core::asset::SIDECAR_EXTENSIONS


@dataclass(frozen=True)
class RenderSettings:
    """A render task's `render`: fields, bounds and defaults are `RenderSettings` in the stage
    contract; `parse({})` gives the defaults."""

    intrinsics: Intrinsics
    tracing: PathTracing
    prune_bounces: bool
    environment: str
    radius_m: tuple[float, float]
    elevation_deg: tuple[float, float]
    roll_deg: tuple[float, float]
    offcentre: float
    despeckle: float
    intrinsics_jitter: float
    distortion: Distortion  # OpenCV's [k1, k2, p1, p2, k3]; all 0: a pinhole
    scene: SceneDressing
    sensor: SensorModel
    light: lighting.LightJitter
    viewpoint: ViewpointRule

    @staticmethod
    def parse(obj: Any, where: str = "params.render") -> RenderSettings:
        fields = contract.validated_part("RenderSettings", obj, where)
        for key in ("radius_m", "elevation_deg", "roll_deg", "occlusion"):
            low, high = fields[key]
            if low > high:
                raise BadInput(f"{where}.{key}: min {low} exceeds max {high}")
        low, high = fields["light"]["temperature_k"]
        if low > high:
            raise BadInput(f"{where}.light.temperature_k: min {low} exceeds max {high}")
        if fields["scene"]["distractors"] > 0 and not fields["scene"]["table"]:
            raise BadInput(
                f"{where}.scene.distractors: {fields['scene']['distractors']} needs a table to stand "
                "on (scene.table = true)"
            )
        return RenderSettings(
            intrinsics=Intrinsics(width=fields["width"], height=fields["height"], fov_deg=fields["fov_deg"]),
            tracing=PathTracing(
                samples=fields["samples"],
                denoise=fields["denoise"],
                bounces=Bounces(**fields["bounces"]),
                clamp_indirect=float(fields["clamp_indirect"]),
            ),
            prune_bounces=fields["prune_bounces"],
            environment=fields["environment"],  # checked with the views
            radius_m=(float(fields["radius_m"][0]), float(fields["radius_m"][1])),
            elevation_deg=(float(fields["elevation_deg"][0]), float(fields["elevation_deg"][1])),
            roll_deg=(float(fields["roll_deg"][0]), float(fields["roll_deg"][1])),
            offcentre=float(fields["offcentre"]),
            despeckle=float(fields["despeckle"]),
            intrinsics_jitter=float(fields["intrinsics_jitter"]),
            distortion=distortion_param(fields["distortion"]),
            scene=SceneDressing(
                table=bool(fields["scene"]["table"]),
                table_gap_m=float(fields["scene"]["table_gap_m"]),
                flange=bool(fields["scene"]["flange"]),
                distractors=int(fields["scene"]["distractors"]),
            ),
            sensor=SensorModel.from_fields(fields["sensor"]),
            light=lighting.LightJitter.from_fields(fields["light"]),
            viewpoint=ViewpointRule(
                occlusion=(float(fields["occlusion"][0]), float(fields["occlusion"][1])),
                palm_side=fields["palm_side"],
            ),
        )


@dataclass(frozen=True)
class Environment:
    """An HDRI and how it is turned (about world +z) and scaled: a bundled one by name, or a
    user's file (`asset`, its SHA-256) under a name of the spec's own."""

    name: str
    rotation_deg: float = 0.0
    strength: float = 1.0
    asset: str | None = None

    @property
    def key(self) -> str:
        """What identifies the image: the bundled name or the file's content hash."""
        return self.asset or self.name

    def to_json(self) -> dict[str, Any]:
        record: dict[str, Any] = {
            "name": self.name,
            "rotation_deg": self.rotation_deg,
            "strength": self.strength,
        }
        if self.asset is not None:
            record["asset"] = self.asset
        return record

    @staticmethod
    def parse_all(params: Mapping[str, Any]) -> dict[str, Environment]:
        """`params.environments` (checked against the contract) by name. A bundled HDRI not listed
        is lit as is; an entry with `asset` is a user's HDRI, under a name of its own."""
        found: dict[str, Environment] = {}
        for i, raw in enumerate(params.get("environments", [])):
            where = f"params.environments[{i}]"
            name, asset = raw["name"], raw.get("asset")
            if asset is not None and name in environments():
                raise BadInput(
                    f"{where}.name: {name!r} is a bundled HDRI; a user's file needs a name of its own"
                )
            if asset is None:
                Hdri.bundled(name, f"{where}.name")
            if name in found:
                raise BadInput(f"{where}.name: {name!r} is listed twice")
            found[name] = Environment(name, raw["rotation_deg"], raw["strength"], asset)
        return found


@dataclass(frozen=True)
class RenderView:
    index: int
    seed: int
    environment: Environment
    camera: CameraPose | None  # given by the task, else sampled with `seed`

    @staticmethod
    def parse_all(params: Mapping[str, Any], default_environment: str) -> list[RenderView]:
        """`params.views` (checked against the contract); a view without `environment` renders
        under `default_environment`. Every environment named must be listed in
        `params.environments` or be a bundled HDRI."""
        listed = Environment.parse_all(params)

        def resolve(name: str, where: str) -> Environment:
            if name in listed:
                return listed[name]
            Hdri.bundled(name, where)
            return Environment(name)

        default = resolve(default_environment, "params.render.environment")
        views = []
        for i, raw in enumerate(params["views"]):
            where = f"params.views[{i}]"
            environment = default
            if "environment" in raw:
                environment = resolve(raw["environment"], f"{where}.environment")
            camera = camera_param(raw["camera"], f"{where}.camera") if "camera" in raw else None
            views.append(RenderView(raw["view_index"], raw["seed"], environment, camera))
        if len({view.index for view in views}) != len(views):
            raise BadInput("params.views: view_index values must be unique")
        return views


@dataclass(frozen=True)
class RenderTask:
    """A render task's parameters, checked against the stage contract and parsed. Needs no staged
    file and no scene: `python -m vint_engines check-params` runs it on planned tasks."""

    grasp_index: int
    settings: RenderSettings
    outputs: frozenset[str]
    depth_format: str  # "png" or "npy" (`vint_engines.depth_file`)
    views: list[RenderView]
    dataset_objects: frozenset[str]  # no distractor is one of these (the job's objects)

    @staticmethod
    def parse(params: Mapping[str, Any]) -> RenderTask:
        checked = contract.validated("render", params)
        settings = RenderSettings.parse(checked["render"])
        return RenderTask(
            grasp_index=checked["grasp_index"],
            settings=settings,
            outputs=frozenset(checked["outputs"]),
            depth_format=checked["depth_format"],
            views=RenderView.parse_all(checked, settings.environment),
            dataset_objects=frozenset(checked.get("dataset_objects", [])),
        )

    def check_assets(self, params: Mapping[str, Any], assets: dict[str, StagedAsset]) -> None:
        """With `rgb`, every user HDRI listed must be among the staged files (`params.assets`)."""
        if "rgb" not in self.outputs:
            return
        for i, raw in enumerate(params.get("environments", [])):
            if "asset" in raw:
                asset_file(assets, raw["asset"], f"params.environments[{i}].asset")


def camera_param(obj: Any, where: str) -> CameraPose:
    """An explicit camera `{"R_w2c": 3×3, "t_w2c": 3}` (OpenCV convention); R must be a rotation."""
    if not isinstance(obj, Mapping):
        raise BadInput(f"{where}: expected an object with R_w2c and t_w2c")
    try:
        R = np.array(obj["R_w2c"], dtype=np.float64)
        t = np.array(obj["t_w2c"], dtype=np.float64)
    except (KeyError, TypeError, ValueError) as exc:
        raise BadInput(f"{where}: expected R_w2c (3×3) and t_w2c (3 numbers) ({exc!r})") from exc
    if R.shape != (3, 3) or t.shape != (3,) or not (np.isfinite(R).all() and np.isfinite(t).all()):
        raise BadInput(f"{where}: expected R_w2c (3×3) and t_w2c (3 finite numbers)")
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise BadInput(f"{where}.R_w2c: not a rotation matrix")
    return CameraPose(R, t)


class RenderEngine:
    def __init__(self) -> None:
        self.scratch = Path(tempfile.mkdtemp(prefix="vint-render-"))
        # Blender's own task pool is sized at its first use: to the render's threads (`cpus.py`).
        with cpus.narrowed(render_threads()):
            self.scene = BlenderScene(self.scratch)
            self.denoiser = Denoiser(self.scene.threads)
            self._warm_up()
        self._footprints: dict[str, clutter.Footprint] = {}  # catalog name → how it rests

    def hello(self) -> Json:
        return {
            "name": "vint-render",
            "version": __version__,
            "libs": {
                "python": platform.python_version(),
                "bpy": bpy.app.version_string,
                "numpy": np.__version__,
                "opencv": cv2.__version__,
                "oidn": pyoidn.version.oidn_version,
            },
        }

    def close(self) -> None:
        self.denoiser.close()
        shutil.rmtree(self.scratch, ignore_errors=True)

    def _warm_up(self) -> None:
        """Render one tiny empty frame per scene: loads the Cycles kernels (but no HDRI: only the
        environments a task's views use are ever loaded)."""
        self.scene.place_camera(look_at(np.array([0.0, -1.0, 0.5]), np.zeros(3)), Intrinsics(8, 8, 60.0))
        self.scene.render_geometry()
        self.scene.render_rgb(PathTracing(1, False, Bounces(0, 0, 0, 0, 0)), 0)

    def run(self, task: TaskRequest) -> TaskResult:
        render = RenderTask.parse(task.params)
        settings, outputs, grasp_index, views = (
            render.settings,
            render.outputs,
            render.grasp_index,
            render.views,
        )
        for view in views:  # a lens that cannot be inverted fails the task before any view renders
            check_lens(
                view_intrinsics(view.seed, settings), settings.distortion, DISTORTION_FIELD, whose(view)
            )
        assets = staged_assets(task)
        render.check_assets(task.params, assets)
        grasps = load_grasps(task.input_path(GRASPS_INPUT))
        hdris = (
            {view.environment: hdri(view.environment, assets) for view in views} if "rgb" in outputs else {}
        )
        for image in hdris.values():  # an unreadable file fails the task before any view renders
            self.scene.load_environment(image)

        trial = find_trial(grasps, grasp_index)
        self.scene.set_hand(grasps["hand"])
        textured = object_look(grasps["object"], assets) if "rgb" in outputs else None
        self.scene.set_object(grasps["object"], staged_input(task, MODEL_FILE), textured)
        self.scene.set_dressing(settings.scene)
        object_pose = read_pose(trial["object_pose"], f"grasps.json trial {grasp_index} object_pose")
        object_radius = self.scene.object_radius()
        links = {name: read_pose(pose, f"link_poses.{name}") for name, pose in trial["link_poses"].items()}
        self.scene.pose(object_pose, links)
        self.scene.set_distractors(
            self._bench(settings.scene, trial, grasps["object"], render.dataset_objects, object_pose[0])
        )
        palm = palm_of(links)
        if settings.viewpoint.palm_side == "front" and palm is None:
            raise BadInput(
                f"params.render.palm_side: 'front' needs the palm's pose; "
                f"grasp {grasp_index} has no 'palm' link"
            )

        tracing = settings.tracing
        if settings.prune_bounces:
            bounces = tracing.bounces.pruned(self.scene.lobes())
            tracing = replace(tracing, bounces=bounces)
        result = TaskResult()
        geometry_s = rgb_s = 0.0
        occluded: dict[int, float] = {}
        attempts = renders = out_of_range = 0
        sensors: dict[int, dict[str, Any]] = {}  # what each view's colour sensor drew
        lights: dict[int, lighting.LightDraw] = {}  # what each view's light drew
        fireflies_removed = 0
        for view in self._render_order(views):
            started = time.perf_counter()
            intrinsics = view_intrinsics(view.seed, settings)
            lens = view_lens(intrinsics, settings.distortion, DISTORTION_FIELD, whose(view))
            chosen = self._viewpoint(view, intrinsics, lens, settings, object_pose[0], object_radius, palm)
            camera, geometry = chosen.camera, chosen.geometry
            attempts += chosen.attempts
            renders += chosen.renders
            out_of_range += not chosen.occlusion_in_range
            geometry_s += time.perf_counter() - started
            if "rgb" in outputs:
                started = time.perf_counter()
                environment = view.environment
                light = lighting.draw(
                    settings.light, view.seed, environment.rotation_deg, environment.strength
                )
                lights[view.index] = light
                self.scene.set_environment(hdris[environment], light.rotation_deg, light.strength, light.tint)
                light_in = self.light_in(self.scene.render_rgb(tracing, view.seed))
                if lens is not None:  # the denoised canvas; the sensor's noise is per distorted pixel
                    light_in = lens.light(light_in)
                # The sensor first, then the filter: the sensor's gains could lift a pixel just under
                # the threshold over it (a camera's defect-pixel correction also runs last).
                captured, sensors[view.index] = capture(light_in, settings.sensor, view.seed)
                image, fireflies = despeckle(encode_srgb8(captured), settings.despeckle)
                fireflies_removed += fireflies
                path = task.out_dir / f"v{view.index:02d}_rgb.png"
                result.add(write_png(path, image[:, :, ::-1]), "image/png")  # OpenCV writes BGR
                rgb_s += time.perf_counter() - started
            occluded[view.index] = self._write_view(
                task.out_dir,
                view,
                chosen.record(settings.viewpoint),
                camera,
                intrinsics,
                settings.distortion,
                outputs,
                render.depth_format,
                object_pose,
                geometry,
                sensors.get(view.index),
                lights.get(view.index),
                result,
            )
        n = len(views)
        result.result = {
            "views": n,
            "device": self.scene.device,
            "occlusion": [occluded[view.index] for view in views],
        }
        result.metrics.update(
            views=n,
            render_ms_per_view=round(1e3 * (geometry_s + rgb_s) / n, 3),
            geometry_ms_per_view=round(1e3 * geometry_s / n, 3),
            rgb_ms_per_view=round(1e3 * rgb_s / n, 3),
            device=self.scene.device,
            threads=self.scene.threads,
            bounces=vars(tracing.bounces) if "rgb" in outputs else None,
            fireflies_removed=fireflies_removed,
            camera_attempts_per_view=round(attempts / n, 3),
            geometry_renders_per_view=round(renders / n, 3),
            views_out_of_occlusion_range=out_of_range,
        )
        return result

    def _bench(
        self,
        scene: dressing.SceneDressing,
        trial: Mapping[str, Any],
        grasped: Mapping[str, Any],
        dataset_objects: frozenset[str],
        centre: np.ndarray,
    ) -> list[tuple[clutter.Placed, ObjectSpec]]:
        """The catalog objects standing on the table around this grasp (`clutter.py`): the
        layout drawn from the trial's seed, so all its views (from any worker) share it. Never the
        grasped object nor any object of the job (`dataset_objects`): the dataset annotates those,
        and an unannotated one in a picture would be a label's error."""
        top = self.scene.table_top_z
        if scene.distractors == 0 or top is None:
            return []
        catalog = load_catalog()
        excluded = dataset_objects | {grasped.get("name")}
        names = sorted(name for name in catalog if name not in excluded)

        def footprint(name: str) -> clutter.Footprint:
            if name not in self._footprints:
                rest = build_model(catalog[name], where=f"catalog object {name!r}").rest
                self._footprints[name] = clutter.Footprint(rest.quat, rest.height, rest.radius)
            return self._footprints[name]

        seed = trial.get("seed")
        if not isinstance(seed, int):
            raise BadInput(f"{GRASPS_INPUT}: trial {trial.get('grasp_index')} has no integer seed")
        placed = clutter.place(
            seed,
            names,
            footprint,
            scene.distractors,
            (float(centre[0]), float(centre[1])),
            self.scene.grasp_reach(),
            top,
            (dressing.TABLE_SIZE_M[0] / 2, dressing.TABLE_SIZE_M[1] / 2),
        )
        return [(stand, catalog[stand.name]) for stand in placed]

    def _viewpoint(
        self,
        view: RenderView,
        intrinsics: Intrinsics,
        lens: Lens | None,
        settings: RenderSettings,
        target: np.ndarray,
        object_radius: float,
        palm: Palm | None,
    ) -> Viewpoint[Geometry]:
        """The view's camera (given, or drawn until it meets the spec's viewpoint rules) with its
        geometry passes rendered and placed, ready for the RGB render. With a `lens`, Cycles
        renders its pinhole canvas and each attempt is measured on the distorted images the files
        will hold."""
        rendered = intrinsics if lens is None else lens.canvas

        def measure(camera: CameraPose) -> tuple[Geometry, float]:
            self.scene.place_camera(camera, rendered)
            geometry = through_lens(self.scene.render_geometry(), lens)
            return geometry, geometry_occlusion(geometry)

        def draw(attempt: int) -> CameraPose:
            rng = attempt_rng(view.seed, attempt)
            return sampled_camera(rng, target, object_radius, settings, intrinsics)

        if view.camera is not None:
            return viewpoint.given(view.camera, measure, settings.viewpoint, palm)
        chosen = viewpoint.search(draw, measure, settings.viewpoint, palm)
        self.scene.place_camera(chosen.camera, rendered)  # the RGB render uses the chosen one
        return chosen

    def light_in(self, radiance: Radiance) -> np.ndarray:
        """The light a view's camera receives: the path-traced image, denoised when the render
        stored the denoiser's guides."""
        if radiance.albedo is None or radiance.normal is None:
            return radiance.image
        return self.denoiser(radiance.image, radiance.albedo, radiance.normal)

    def _render_order(self, views: list[RenderView]) -> list[RenderView]:
        """Views grouped by environment (first appearance order), the loaded one first: each switch
        re-syncs the world shader."""
        groups: dict[Environment, list[RenderView]] = {}
        for view in views:
            groups.setdefault(view.environment, []).append(view)
        loaded = self.scene.environment
        return sorted(
            (view for group in groups.values() for view in group),
            key=lambda view: (
                loaded is None
                or (view.environment.key, view.environment.rotation_deg, view.environment.strength)
                != loaded[:3]
            ),
        )

    def _write_view(
        self,
        out_dir: Path,
        view: RenderView,
        viewpoint_record: dict[str, Any],
        camera: CameraPose,
        intrinsics: Intrinsics,
        distortion: Distortion,
        outputs: frozenset[str],
        depth_format: str,
        object_pose: tuple[np.ndarray, np.ndarray],
        geometry: Geometry,
        sensor: dict[str, Any] | None,
        light: lighting.LightDraw | None,
        result: TaskResult,
    ) -> float:
        """Writes one view's files and camera record; returns its occlusion."""
        prefix = f"v{view.index:02d}"
        visible = geometry.index == OBJECT_PASS_INDEX
        if "depth" in outputs:
            path = depth_file.write(out_dir / f"{prefix}_depth", geometry.depth, depth_format)
            result.add(path, depth_file.media_type(path))
        if "mask" in outputs:
            result.add(write_png(out_dir / f"{prefix}_mask.png", as_mask(visible)), "image/png")
            full = write_png(out_dir / f"{prefix}_mask_full.png", as_mask(geometry.object_full))
            result.add(full, "image/png")
        labels = self.scene.segmentation_labels()
        if "segmentation" in outputs:
            dtype = np.uint8 if max(labels) <= np.iinfo(np.uint8).max else np.uint16
            path = write_png(out_dir / f"{prefix}_segmentation.png", geometry.index.astype(dtype))
            result.add(path, "image/png")
        p_obj, q_obj = object_pose
        R_m2c, t_m2c = camera.object_in_camera(quat_to_matrix(q_obj), p_obj)
        visible_px = int(np.count_nonzero(visible))
        full_px = int(np.count_nonzero(geometry.object_full | visible))
        record = {
            "K": intrinsics.matrix().tolist(),
            **({} if is_pinhole(distortion) else {"dist": list(distortion)}),
            "width": intrinsics.width,
            "height": intrinsics.height,
            "R_w2c": camera.R_w2c.tolist(),
            "t_w2c": camera.t_w2c.tolist(),
            "R_m2c": R_m2c.tolist(),
            "t_m2c": t_m2c.tolist(),
            "visible_px": visible_px,
            "full_px": full_px,
            "occlusion": occlusion(visible_px, full_px),
            "viewpoint": viewpoint_record,
            "segmentation": {"0": "background", **{str(k): name for k, name in labels.items()}},
            "materials": {str(k): tag for k, tag in self.scene.segment_materials().items()},
            "environment": view.environment.to_json(),
            "scene": {
                "table": self.scene.table_shown(),
                "table_top_z": self.scene.table_top_z if self.scene.table_shown() else None,
                "flange": "arm/flange" in labels.values(),
                "distractors": [stand.to_json() for stand in self.scene.distractors_shown()],
            },
        }
        if sensor is not None:
            record["sensor"] = sensor
        if light is not None:
            record["light"] = light.to_json()
        path = out_dir / f"{prefix}_camera.json"
        path.write_text(json.dumps(record, indent=1))
        result.add(path, "application/json")
        return float(record["occlusion"])


def distortion_param(coefficients: list[float]) -> Distortion:
    """`render.distortion` (checked against the contract: five bounded numbers)."""
    k1, k2, p1, p2, k3 = (float(k) for k in coefficients)
    return k1, k2, p1, p2, k3


def whose(view: RenderView) -> str:
    """Whose intrinsics a lens error speaks of."""
    return f"view {view.index}'s intrinsics"


def through_lens(geometry: Geometry, lens: Lens | None) -> Geometry:
    """A view's geometry passes as its image holds them: a pinhole's as rendered, a distorted
    view's resampled from its canvas by nearest neighbour (no depth or label is blended)."""
    if lens is None:
        return geometry
    return Geometry(**{name: lens.nearest(pixels) for name, pixels in vars(geometry).items()})


def view_intrinsics(seed: int, settings: RenderSettings) -> Intrinsics:
    """The view's intrinsics: the nominal ones, jittered by `intrinsics_jitter` from the view's
    seed on a stream of its own (so the camera's draws do not move)."""
    rng = np.random.default_rng([seed, INTRINSICS_STREAM])
    return settings.intrinsics.jittered(rng, settings.intrinsics_jitter)


def sampled_camera(
    rng: np.random.Generator,
    target: np.ndarray,
    object_radius: float,
    settings: RenderSettings,
    intrinsics: Intrinsics,
) -> CameraPose:
    """One camera attempt of a view without an explicit one: on the hemisphere around the object,
    then turned so the object lands off the image centre (`framed`), all from `rng` (the attempt's
    stream, `viewpoint.attempt_rng`)."""
    camera = sample_on_hemisphere(rng, target, settings.radius_m, settings.elevation_deg, settings.roll_deg)
    return framed(rng, camera, target, object_radius, intrinsics, settings.offcentre)


def object_look(entry: Mapping[str, Any], assets: dict[str, StagedAsset]) -> MeshSource | None:
    """A user's mesh and its sidecars when the task staged them (the plan does so for an object
    that lists sidecar files, with RGB): the look comes from those files. None otherwise."""
    shape = ObjectSpec.parse(entry, "grasps.json object").shape
    if not isinstance(shape, MeshFile) or not shape.asset or shape.asset not in assets:
        return None
    mesh = assets[shape.asset]
    sidecars = {
        sha: (staged.spec_path, staged.path)
        for sha, staged in assets.items()
        if sha != shape.asset and staged.path.suffix.lower() in SIDECAR_SUFFIXES
    }
    return MeshSource.staged(mesh.path, mesh.spec_path, shape.scale, sidecars)


def hdri(environment: Environment, assets: dict[str, StagedAsset]) -> Hdri:
    """The image `environment` is lit by: a bundled HDRI, or the user's staged file."""
    if environment.asset is None:
        return Hdri.bundled(environment.name, "environment")
    staged = asset_file(assets, environment.asset, f"environment {environment.name!r}")
    return Hdri.user(environment.asset, staged.path, f"environment {environment.name!r} ({staged.spec_path})")


def occlusion(visible_px: int, full_px: int) -> float:
    """`occlusion_share` as camera.json records it (6 decimals)."""
    return round(occlusion_share(visible_px, full_px), 6)


def geometry_occlusion(geometry: Geometry) -> float:
    """The exact occlusion the geometry passes saw (every visible pixel counts in the full mask)."""
    visible = geometry.index == OBJECT_PASS_INDEX
    return occlusion_share(
        int(np.count_nonzero(visible)), int(np.count_nonzero(geometry.object_full | visible))
    )


def palm_of(links: Mapping[str, tuple[np.ndarray, np.ndarray]]) -> Palm | None:
    """The palm's origin and normal (its frame's +z: docs/hands.md) from the trial's link poses."""
    if "palm" not in links:
        return None
    p, q = links["palm"]
    return Palm(point=np.asarray(p, dtype=np.float64), normal=quat_to_matrix(q)[:, 2])


def as_mask(pixels: np.ndarray) -> np.ndarray:
    """uint8 mask, 255 where `pixels` is true."""
    return np.where(pixels, 255, 0).astype(np.uint8)


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


def make_engine() -> RenderEngine:
    """The stage's engine (`vint_engines.stages`' convention)."""
    return RenderEngine()


def parse_params(params: Mapping[str, Any]) -> RenderTask:
    """A task's parameters as the engine parses them before it runs anything."""
    return RenderTask.parse(params)
