"""The grasp engine: parses a grasp task, runs its trials and writes `grasps.json` (poses, hand
geometry, metrics: what the renderer reads), `touch.json` (each accepted trial's tactile reading:
what only the package stage reads) and the object's model mesh `object.ply` (millimetres).

Holds one compiled scene (and its `MjData`) per (hand, object), one object model per object, and
each hand's taxel layout, read from the catalog, all built on first use.
"""

from __future__ import annotations

import hashlib
import json
import platform
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from vint_engines import __version__, contract
from vint_engines.assets import StagedAsset, asset_file, staged_assets
from vint_engines.grasp.hands import GraspHand, MjcfHand, hand_dims, load_mjcf_hand
from vint_engines.grasp.hands.catalog import CATALOG_DIR, read_hand_catalog
from vint_engines.grasp.hands.model import Vec3
from vint_engines.grasp.scene import (
    GraspScene,
    ObjectSpec,
    build_scene,
    hand_geometry,
    hand_meshes,
    object_record,
    write_object_model,
)
from vint_engines.grasp.taxels import TaxelLayout, parse_layout
from vint_engines.grasp.touch import Skin, TouchParams
from vint_engines.grasp.trial import Physics, run_trial
from vint_engines.objects import MODEL_MEDIA_TYPE, ObjectModels
from vint_engines.protocol import BadInput, Json, TaskRequest, TaskResult

OUTPUT_NAME = "grasps.json"
TOUCH_NAME = "touch.json"


class GraspEngine:
    def __init__(self) -> None:
        self._scenes: dict[tuple[str, ObjectSpec], tuple[GraspScene, mujoco.MjData]] = {}
        self._models = ObjectModels()
        self._layouts: dict[str, tuple[TaxelLayout, dict[str, Any]]] = {}
        # A user's hand by name@mjcf, with the spec paths and hashes of the mesh files it read.
        self._user_hands: dict[str, tuple[MjcfHand, dict[str, str]]] = {}

    def hello(self) -> Json:
        return {
            "name": "vint-grasp",
            "version": __version__,
            "libs": {
                "python": platform.python_version(),
                "mujoco": mujoco.__version__,
                "numpy": np.__version__,
            },
        }

    def close(self) -> None:
        self._scenes.clear()
        self._layouts.clear()

    def run(self, task: TaskRequest) -> TaskResult:
        grasp = GraspTask.parse(task.params)
        obj, physics, touch, trials = grasp.object, grasp.physics, grasp.touch, grasp.trials
        assets = staged_assets(task)
        hand_key, hand = self._hand(grasp.hand, assets)

        scene, data = self._scene(hand_key, hand, obj, assets)
        layout, layout_info = self._layout(hand_key, hand, grasp.hand, assets)
        skin = Skin(scene, layout, touch)
        started = time.perf_counter()
        records = run_trials(scene, data, physics, skin, trials, grasp.accept)
        trials_s = time.perf_counter() - started
        document: dict[str, Any] = {
            "object": object_record(scene, grasp.object_params),
            "hand": {
                "name": hand.name,
                "dof": hand.dof,
                "fingers": hand.finger_count,
                "links": hand_geometry(scene),
                **({"meshes": meshes} if (meshes := hand_meshes(scene)) else {}),
                "mount": mount_record(hand.mount),
                "taxels": {**layout_info, "deviation": skin.deviation()},
            },
            "trials": [without_readings(record) for record in records],
            "physics": physics.to_json(),
            "touch": touch.to_json(),
        }
        path = task.out_dir / OUTPUT_NAME
        path.write_text(json.dumps(document, indent=1, allow_nan=False))
        touch_path = task.out_dir / TOUCH_NAME
        touch_path.write_text(
            json.dumps(
                touch_document(hand.name, {**layout_info, "deviation": skin.deviation()}, touch, records),
                allow_nan=False,
            )
        )
        result = TaskResult()
        result.add(path, "application/json")
        result.add(touch_path, "application/json")
        result.add(write_object_model(scene, task.out_dir), MODEL_MEDIA_TYPE)
        accepted = [record for record in records if record["accepted"]]
        result.result = grasp_result(records, layout.regions)
        result.metrics.update(
            trials=len(records),
            accepted=len(accepted),
            reruns=sum(record["stability"]["retries"] for record in records),
            active_taxels_median=float(np.median([r["touch"]["active_count"] for r in accepted] or [0])),
            trials_ms=round(1e3 * trials_s, 3),
            touch_ms=round(1e3 * skin.elapsed_s, 3),
        )
        return result

    def _hand(self, params: Any, assets: dict[str, StagedAsset]) -> tuple[str, GraspHand]:
        """The task's hand and its cache key: a built-in hand by name, or a user's hand from its
        staged MJCF file (`params.hand.mjcf`, a SHA-256; the key includes it, so a changed file
        is a different hand)."""
        name = params["name"]
        if "mjcf" not in params:
            return name, hand_dims(name)
        mjcf = params["mjcf"]
        by_path = {staged.spec_path: sha for sha, staged in assets.items()}
        cached = self._user_hands.get(f"{name}@{mjcf}")
        if cached is None or any(by_path.get(path) != sha for path, sha in cached[1].items()):
            staged = asset_file(assets, mjcf, "params.hand.mjcf")
            where = f"params.hand.mjcf ({staged.spec_path})"
            files = {s.spec_path: s.path for s in assets.values()}
            xml = staged.path.read_text(encoding="utf-8")
            hand = load_mjcf_hand(name, xml, where, staged.spec_path, files)
            cached = (hand, {path: by_path[path] for path in hand.mesh_files})
            self._user_hands[f"{name}@{mjcf}"] = cached
        # The key names the mesh files' contents too: a changed mesh is a different hand.
        key = "@".join([name, mjcf, *(cached[1][path] for path in sorted(cached[1]))])
        return key, cached[0]

    def _scene(
        self, hand_key: str, hand: GraspHand, obj: ObjectSpec, assets: dict[str, StagedAsset]
    ) -> tuple[GraspScene, mujoco.MjData]:
        key = (hand_key, obj)
        if key not in self._scenes:
            files = {sha: staged.path for sha, staged in assets.items()}
            scene = build_scene(hand, obj, self._models.get(obj, assets=files))
            self._scenes[key] = (scene, mujoco.MjData(scene.model))
        return self._scenes[key]

    def _layout(
        self, hand_key: str, hand: GraspHand, params: Any, assets: dict[str, StagedAsset]
    ) -> tuple[TaxelLayout, dict[str, Any]]:
        """The hand's taxel layout — the catalog's, or a user's hand's staged file
        (`params.hand.taxels`, a SHA-256) — checked against the hand's links, and how
        `grasps.json` names it (path, count, SHA-256 of the file, so a dataset records which
        layout its readings index)."""
        if hand_key in self._layouts:
            return self._layouts[hand_key]
        if "mjcf" in params:
            staged = asset_file(assets, params["taxels"], "params.hand.taxels")
            raw = staged.path.read_bytes()
            where = f"params.hand.taxels ({staged.spec_path})"
            layout = parse_layout(raw.decode("utf-8"), hand.link_names(), where)
            info = {
                "layout": staged.spec_path,
                "count": len(layout),
                "sha256": hashlib.sha256(raw).hexdigest(),
            }
            self._layouts[hand_key] = (layout, info)
            return self._layouts[hand_key]
        if hand.name not in self._layouts:
            entry = read_hand_catalog().get(hand.name)
            if entry is None:
                raise BadInput(
                    f"params.hand.name: {hand.name!r} has no entry in {CATALOG_DIR / 'hands.toml'}"
                )
            path = entry.taxels_path()
            raw = path.read_bytes()
            layout = parse_layout(raw.decode("utf-8"), hand.link_names(), str(path))
            info = {"layout": entry.taxels, "count": len(layout), "sha256": hashlib.sha256(raw).hexdigest()}
            self._layouts[hand.name] = (layout, info)
        return self._layouts[hand.name]


def run_trials(
    scene: GraspScene,
    data: mujoco.MjData,
    physics: Physics,
    skin: Skin,
    trials: list[tuple[int, int]],
    accept: int | None,
) -> list[dict[str, Any]]:
    """Run `trials` (grasp index, seed) in order; with a quota `accept`, stop once that many are
    accepted (the trials left are not run and leave no record)."""
    records: list[dict[str, Any]] = []
    accepted = 0
    for index, seed in trials:
        if accept is not None and accepted >= accept:
            break
        record = run_trial(scene, data, physics, skin, index, seed)
        accepted += bool(record["accepted"])
        records.append(record)
    return records


def without_readings(record: dict[str, Any]) -> dict[str, Any]:
    """A trial as `grasps.json` carries it: its touch cut to a summary (the full reading goes to
    `touch.json`, which every render task would otherwise download for nothing)."""
    if "touch" not in record:
        return record
    touch = record["touch"]
    summary = {key: touch[key] for key in ("contact_margin_m", "aging", "active_count")}
    return {**record, "touch": summary}


def touch_document(
    hand: str, layout_info: dict[str, Any], params: TouchParams, records: list[dict[str, Any]]
) -> dict[str, Any]:
    """`touch.json`: the full touch record of every accepted trial, by grasp index."""
    return {
        "hand": hand,
        "taxels": layout_info,
        "touch": params.to_json(),
        "trials": [
            {"grasp_index": record["grasp_index"], **record["touch"]}
            for record in records
            if "touch" in record
        ],
    }


@dataclass(frozen=True)
class GraspTask:
    """A grasp task's parameters, checked against the stage contract and parsed. Needs no staged
    file and no MuJoCo model: `python -m vint_engines check-params` runs it on planned tasks."""

    object: ObjectSpec
    object_params: Mapping[str, Any]
    hand: Mapping[str, Any]
    physics: Physics
    touch: TouchParams
    trials: list[tuple[int, int]]
    accept: int | None

    @staticmethod
    def parse(params: Mapping[str, Any]) -> GraspTask:
        checked = contract.validated("grasp", params)
        trials = [(t["grasp_index"], t["seed"]) for t in checked["trials"]]
        if len({index for index, _ in trials}) != len(trials):
            raise BadInput("params.trials: grasp_index values must be unique")
        hand = checked["hand"]
        if ("mjcf" in hand) != ("taxels" in hand):
            raise BadInput("params.hand: a user's hand needs both mjcf and taxels (a built-in one neither)")
        if "mjcf" not in hand:
            hand_dims(hand["name"])  # a built-in hand must exist
        return GraspTask(
            object=ObjectSpec.parse(checked["object"]),
            object_params=checked["object"],
            hand=hand,
            physics=Physics.parse(checked["physics"]),
            touch=TouchParams.parse(checked["touch"]),
            trials=trials,
            accept=checked.get("accept"),
        )


def grasp_result(records: list[dict[str, Any]], regions: Sequence[str]) -> dict[str, Any]:
    """The stage's result (`GraspResult`): the accepted grasp indices, the rejected trials
    counted by reason class (`penetration: 5.1 mm` counts as `penetration`), and each accepted
    trial's active taxels per region of the layout (`regions`: every taxel's region)."""
    rejected: dict[str, int] = {}
    for record in records:
        if not record["accepted"]:
            reason = str(record["reason"] or "unknown")
            kind = "dropped_shake" if reason == "dropped: shake" else reason.split(":", 1)[0].strip()
            rejected[kind] = rejected.get(kind, 0) + 1
    accepted = [record for record in records if record["accepted"]]
    return {
        "accepted": [record["grasp_index"] for record in accepted],
        "rejected": rejected,
        "active_taxels": [
            {"grasp_index": record["grasp_index"], "by_region": active_by_region(record, regions)}
            for record in accepted
        ],
    }


def active_by_region(record: dict[str, Any], regions: Sequence[str]) -> dict[str, int]:
    """A trial's active taxels counted per region, every region of the layout included."""
    counts = dict.fromkeys(sorted(set(regions)), 0)
    for taxel in record.get("touch", {}).get("active", []):
        counts[taxel["region"]] += 1
    return counts


def mount_record(mount: tuple[Vec3, Vec3] | None) -> dict[str, Any] | None:
    """grasps.json's `hand.mount`: where the renderer attaches the arm's flange (palm frame)."""
    if mount is None:
        return None
    point, axis = mount
    return {"link": "palm", "p": list(point), "axis": list(axis)}


def make_engine() -> GraspEngine:
    """The stage's engine (`vint_engines.stages`' convention)."""
    return GraspEngine()


def parse_params(params: Mapping[str, Any]) -> GraspTask:
    """A task's parameters as the engine parses them before it runs anything."""
    return GraspTask.parse(params)
