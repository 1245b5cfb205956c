"""The grasp engine: parses a grasp task, runs its trials and writes `grasps.json` and the object's
model mesh `object.ply` (millimetres).

Holds one compiled scene (and its `MjData`) per (hand, object), one object model per object, and
each hand's taxel layout, read from the catalog, all built on first use.
"""

from __future__ import annotations

import hashlib
import json
import platform
import time
from typing import Any

import mujoco
import numpy as np

from vint_engines import __version__
from vint_engines import params as P
from vint_engines.grasp.hands import HandDims, hand_dims
from vint_engines.grasp.hands.catalog import CATALOG_DIR, read_hand_catalog
from vint_engines.grasp.scene import (
    GraspScene,
    ObjectSpec,
    build_scene,
    hand_geometry,
    object_record,
    write_object_model,
)
from vint_engines.grasp.taxels import TaxelLayout, parse_layout
from vint_engines.grasp.touch import Skin, TouchParams
from vint_engines.grasp.trial import Physics, run_trial
from vint_engines.objects import MODEL_MEDIA_TYPE, ObjectModels
from vint_engines.protocol import BadInput, Json, TaskRequest, TaskResult

OUTPUT_NAME = "grasps.json"


class GraspEngine:
    def __init__(self) -> None:
        self._scenes: dict[tuple[str, ObjectSpec], tuple[GraspScene, mujoco.MjData]] = {}
        self._models = ObjectModels()
        self._layouts: dict[str, tuple[TaxelLayout, dict[str, Any]]] = {}

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
        params = task.params
        obj_params = P.section(params, "object", "params")
        obj = ObjectSpec.parse(obj_params)
        hand = hand_dims(P.string(P.section(params, "hand", "params"), "name", "params.hand"))
        physics = Physics.parse(params.get("physics", {}))
        touch = TouchParams.parse(params.get("touch", {}))
        trials = [
            parse_trial(t, f"params.trials[{i}]") for i, t in enumerate(P.items(params, "trials", "params"))
        ]
        if len({index for index, _ in trials}) != len(trials):
            raise BadInput("params.trials: grasp_index values must be unique")

        scene, data = self._scene(hand, obj)
        layout, layout_info = self._layout(hand)
        skin = Skin(scene, layout, touch)
        started = time.perf_counter()
        records = [run_trial(scene, data, physics, skin, index, seed) for index, seed in trials]
        trials_s = time.perf_counter() - started
        document: dict[str, Any] = {
            "object": object_record(scene, obj_params),
            "hand": {
                "name": hand.name,
                "dof": hand.dof,
                "fingers": len(hand.fingers),
                "links": hand_geometry(scene),
                "taxels": layout_info,
            },
            "trials": records,
            "physics": physics.to_json(),
            "touch": touch.to_json(),
        }
        path = task.out_dir / OUTPUT_NAME
        path.write_text(json.dumps(document, indent=1, allow_nan=False))
        result = TaskResult()
        result.add(path, "application/json")
        result.add(write_object_model(scene, task.out_dir), MODEL_MEDIA_TYPE)
        accepted = [record for record in records if record["accepted"]]
        result.metrics.update(
            trials=len(records),
            accepted=len(accepted),
            reruns=sum(record["stability"]["retries"] for record in records),
            active_taxels_median=float(np.median([r["touch"]["active_count"] for r in accepted] or [0])),
            trials_ms=round(1e3 * trials_s, 3),
            touch_ms=round(1e3 * skin.elapsed_s, 3),
        )
        return result

    def _scene(self, hand: HandDims, obj: ObjectSpec) -> tuple[GraspScene, mujoco.MjData]:
        key = (hand.name, obj)
        if key not in self._scenes:
            scene = build_scene(hand, obj, self._models.get(obj))
            self._scenes[key] = (scene, mujoco.MjData(scene.model))
        return self._scenes[key]

    def _layout(self, hand: HandDims) -> tuple[TaxelLayout, dict[str, Any]]:
        """The hand's taxel layout from the catalog, and how `grasps.json` names it (path, count,
        SHA-256 of the file, so a dataset records which layout its readings index)."""
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


def parse_trial(trial: Any, where: str) -> tuple[int, int]:
    return P.integer(trial, "grasp_index", where, low=0), P.seed(trial, "seed", where)
