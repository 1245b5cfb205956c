"""Reading a dataset for its statistics: the native layout (`vintctl run|export`) or the BOP layout
(`--format bop`), both reduced to the same plain records — one `View` per sample, one `Grasp` per
grasp, the (object, hand) `Pair`s of `dataset.json` — so every number downstream is computed once,
whatever the layout.

Reads only the JSON records (meta.json and grasp.json; BOP's scene_*.json), never pixels: the
statistics are about poses, visibility and touch, all of which the records carry. The palm's pose
comes from the native records' world poses (grasp.json `trial.hand_pose`, meta.json `poses.hand`
with the camera's `R_w2c`, `t_w2c`) or from BOP's `scene_hand.json` (`link_poses_cam.palm`); the
grasp type only from grasp.json (`trial.grasp.type`): BOP's files do not carry it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from vint_engines.poses import quat_to_matrix

Array = npt.NDArray[np.float64]

NATIVE = "native"
BOP = "bop"
BOP_SPLITS = ("train", "val", "test")
MM = 1e-3  # BOP's translations are millimetres; the records here are metres
UNKNOWN = "unknown"  # a grasp record from before grasp types, a view without an environment
PALM_LINK = "palm"  # the hand's root body: its frame is the palm frame (docs/hands.md)


@dataclass(frozen=True)
class Rigid:
    """A rigid transform x -> R x + t (metres): a pose of one frame in another."""

    R: Array  # (3, 3)
    t: Array  # (3,)

    def inverse(self) -> Rigid:
        return Rigid(self.R.T, -self.R.T @ self.t)

    def then(self, outer: Rigid) -> Rigid:
        """This transform followed by `outer`."""
        return Rigid(outer.R @ self.R, outer.R @ self.t + outer.t)


class DatasetError(Exception):
    """The directory is not a dataset this module reads, or a record in it is malformed."""


@dataclass(frozen=True)
class View:
    """One sample: the object in one camera's frame."""

    sample_id: str
    grasp_id: str
    object: str
    hand: str
    occlusion: float  # 1 - visible_px / full_px (docs/rendering.md)
    R_m2c: Array  # (3, 3), object frame to camera frame
    t_m2c: Array  # (3,), metres: the object origin in the camera frame
    environment: str = UNKNOWN  # the HDRI's name
    palm_to_camera: Rigid | None = None  # the palm frame in the camera frame; None: not recorded


@dataclass(frozen=True)
class Grasp:
    """One accepted grasp and where its active taxels are (one region name per active taxel)."""

    grasp_id: str
    object: str
    hand: str
    active_regions: tuple[str, ...]
    grasp_type: str | None = None  # "power", "precision", …, UNKNOWN before types; None: not carried
    object_in_palm: Rigid | None = None  # the object frame in the palm frame; None: not recorded


@dataclass(frozen=True)
class Pair:
    """One (object, hand) pair's grasp trials, as dataset.json counts them."""

    object: str
    hand: str
    trials: int
    accepted: int
    rejected: dict[str, int]


@dataclass(frozen=True)
class Dataset:
    layout: str  # NATIVE or BOP
    views: list[View]
    grasps: list[Grasp]
    pairs: list[Pair] | None  # None: the dataset has no dataset.json (an export from before it)


def read(root: Path) -> Dataset:
    """The dataset at `root`, in whichever layout it is."""
    if not root.is_dir():
        raise DatasetError(f"{root}: not a directory")
    layout = detect(root)
    description = read_json(root / "dataset.json") if (root / "dataset.json").is_file() else None
    pairs = None if description is None else parse_pairs(description)
    if layout == BOP:
        views, grasps = read_bop(root, description)
    else:
        views, grasps = read_native(root)
    if not views:
        raise DatasetError(f"{root}: a {layout} dataset with no samples")
    return Dataset(layout, views, grasps, pairs)


def detect(root: Path) -> str:
    """BOP when dataset.json says so or a split folder holds scenes; native when dataset.json says
    so or any directory holds a meta.json."""
    if (root / "dataset.json").is_file():
        fmt = read_json(root / "dataset.json").get("format")
        if fmt == "vint-bop":
            return BOP
        if fmt == "vint-native":
            return NATIVE
    if any(any(split.glob("*/scene_gt.json")) for split in bop_splits(root)):
        return BOP
    if any(root.glob("*/meta.json")):
        return NATIVE
    raise DatasetError(
        f"{root}: neither a native dataset (<sample_id>/meta.json) "
        "nor a BOP one (<split>/<scene>/scene_gt.json)"
    )


def read_native(root: Path) -> tuple[list[View], list[Grasp]]:
    views: list[View] = []
    grasps: list[Grasp] = []
    for entry in sorted(root.iterdir()):
        if (entry / "meta.json").is_file():
            views.append(native_view(read_json(entry / "meta.json"), entry / "meta.json"))
        elif (entry / "grasp.json").is_file():
            grasps.append(native_grasp(read_json(entry / "grasp.json"), entry / "grasp.json"))
    return views, grasps


def native_view(meta: dict[str, Any], path: Path) -> View:
    try:
        camera = meta["camera"]
        palm_to_camera = None
        if "hand" in meta.get("poses", {}) and "R_w2c" in camera:
            world_to_camera = Rigid(matrix(camera["R_w2c"]), vector(camera["t_w2c"]))
            palm_to_camera = world_pose(meta["poses"]["hand"]).then(world_to_camera)
        return View(
            sample_id=meta["sample_id"],
            grasp_id=meta["grasp_id"],
            object=meta["object"]["name"],
            hand=meta["hand"],
            occlusion=float(meta["visibility"]["occlusion"]),
            R_m2c=matrix(camera["R_m2c"]),
            t_m2c=vector(camera["t_m2c"]),
            environment=environment_name(camera.get("environment")),
            palm_to_camera=palm_to_camera,
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise DatasetError(f"{path}: malformed sample record ({exc!r})") from exc


def native_grasp(record: dict[str, Any], path: Path) -> Grasp:
    """The grasp's type from `trial.grasp.type` (UNKNOWN for a record from before grasp types)
    and the object in the palm frame from the trial's world poses of the palm and the object."""
    try:
        trial = record.get("trial", {})
        object_in_palm = None
        if "hand_pose" in trial and "object_pose" in trial:
            palm_in_world = world_pose(trial["hand_pose"])
            object_in_palm = world_pose(trial["object_pose"]).then(palm_in_world.inverse())
        return Grasp(
            grasp_id=record["grasp_id"],
            object=record["object"]["name"],
            hand=record["hand"]["name"],
            active_regions=tuple(str(taxel["region"]) for taxel in record["touch"]["active"]),
            grasp_type=str((trial.get("grasp") or {}).get("type", UNKNOWN)),
            object_in_palm=object_in_palm,
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise DatasetError(f"{path}: malformed grasp record ({exc!r})") from exc


def read_bop(root: Path, description: dict[str, Any] | None) -> tuple[list[View], list[Grasp]]:
    """One scene per grasp, one image per view: the views from scene_gt (pose, mm) and scene_meta
    (ids, occlusion, hand, environment; the hand from scene_hand where scene_meta lacks it), the
    palm's pose in each image from scene_hand, the grasp's touch from any one image of scene_touch
    (a grasp's views share it) and the object in the palm frame from its first image. The grasp
    type is not in BOP's files: None."""
    if description is None:
        raise DatasetError(f"{root}: a BOP dataset without dataset.json (it names the objects' obj_ids)")
    try:
        names = {int(o["obj_id"]): str(o["name"]) for o in description["objects"]}
    except (KeyError, TypeError, ValueError) as exc:
        raise DatasetError(f"{root / 'dataset.json'}: malformed objects list ({exc!r})") from exc
    views: list[View] = []
    grasps: dict[str, Grasp] = {}
    for split in bop_splits(root):
        for scene in sorted(p for p in split.iterdir() if (p / "scene_gt.json").is_file()):
            scene_views, scene_grasps = bop_scene(scene, names)
            views.extend(scene_views)
            grasps.update(scene_grasps)
    views.sort(key=lambda v: v.sample_id)
    return views, [grasps[g] for g in sorted(grasps)]


def bop_scene(scene: Path, names: dict[int, str]) -> tuple[list[View], dict[str, Grasp]]:
    gt, meta = read_json(scene / "scene_gt.json"), read_json(scene / "scene_meta.json")
    touch = read_json(scene / "scene_touch.json")
    hand_file = scene / "scene_hand.json"
    hands: dict[str, Any] = read_json(hand_file) if hand_file.is_file() else {}
    views: list[View] = []
    grasps: dict[str, Grasp] = {}
    try:
        for im_id in sorted(gt, key=int):
            (instance,) = gt[im_id]  # one object per image
            image_meta = meta[im_id]
            grasp_id, hand_name = image_meta["grasp_id"], image_meta.get("hand")
            if hand_name is None:
                hand_name = hands[im_id]["hand"]
            obj = names[int(instance["obj_id"])]
            palm = hands.get(im_id, {}).get("link_poses_cam", {}).get(PALM_LINK)
            palm_to_camera = None if palm is None else Rigid(matrix(palm["R"]), MM * vector(palm["t_mm"]))
            view = View(
                sample_id=image_meta["sample_id"],
                grasp_id=grasp_id,
                object=obj,
                hand=hand_name,
                occlusion=float(image_meta["occlusion"]),
                R_m2c=matrix(instance["cam_R_m2c"]),
                t_m2c=MM * vector(instance["cam_t_m2c"]),
                environment=environment_name(image_meta.get("environment")),
                palm_to_camera=palm_to_camera,
            )
            views.append(view)
            if grasp_id not in grasps:
                regions = tuple(str(taxel["region"]) for taxel in touch[im_id]["active"])
                object_in_palm = None
                if palm_to_camera is not None:
                    object_in_palm = Rigid(view.R_m2c, view.t_m2c).then(palm_to_camera.inverse())
                grasps[grasp_id] = Grasp(grasp_id, obj, hand_name, regions, None, object_in_palm)
    except (KeyError, TypeError, ValueError) as exc:
        raise DatasetError(f"{scene}: malformed scene record ({exc!r})") from exc
    return views, grasps


def parse_pairs(description: dict[str, Any]) -> list[Pair] | None:
    if "pairs" not in description:
        return None
    try:
        return [
            Pair(
                object=str(p["object"]),
                hand=str(p["hand"]),
                trials=int(p["trials"]),
                accepted=int(p["accepted"]),
                rejected={str(reason): int(n) for reason, n in sorted(p.get("rejected", {}).items())},
            )
            for p in description["pairs"]
        ]
    except (KeyError, TypeError, ValueError) as exc:
        raise DatasetError(f"dataset.json: malformed pairs ({exc!r})") from exc


def bop_splits(root: Path) -> list[Path]:
    return [root / s for s in BOP_SPLITS if (root / s).is_dir()]


def matrix(values: Any) -> Array:
    """A rotation given as 3 rows or as 9 row-major numbers (BOP's form)."""
    return np.asarray(values, dtype=np.float64).reshape(3, 3)


def vector(values: Any) -> Array:
    return np.asarray(values, dtype=np.float64).reshape(3)


def world_pose(pose: dict[str, Any]) -> Rigid:
    """A `{p, q}` record (q = [w, x, y, z], normalised here) as the body's frame in the world."""
    q = np.asarray(pose["q"], dtype=np.float64).reshape(4)
    return Rigid(quat_to_matrix(q / np.linalg.norm(q)), vector(pose["p"]))


def environment_name(environment: Any) -> str:
    """An environment as the render records it (`{name, rotation_deg, strength}`) or by name."""
    if isinstance(environment, dict):
        return str(environment.get("name", UNKNOWN))
    return UNKNOWN if environment is None else str(environment)


def read_json(path: Path) -> dict[str, Any]:
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: cannot read ({exc})") from exc
    if not isinstance(doc, dict):
        raise DatasetError(f"{path}: expected a JSON object")
    return doc
