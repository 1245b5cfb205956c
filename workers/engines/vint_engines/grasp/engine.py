"""The grasp engine: parses a grasp task, runs its trials and writes `grasps.json`.

Holds one compiled scene (and its `MjData`) per (hand, object), built on first use.
"""

from __future__ import annotations

import json
import platform
from typing import Any

import mujoco
import numpy as np

from vint_engines import __version__
from vint_engines import params as P
from vint_engines.grasp.hand import hand_dims
from vint_engines.grasp.scene import GraspScene, ObjectSpec, build_scene, hand_geometry
from vint_engines.grasp.trial import Physics, run_trial
from vint_engines.protocol import BadInput, Json, TaskRequest, TaskResult

OUTPUT_NAME = "grasps.json"


class GraspEngine:
    def __init__(self) -> None:
        self._scenes: dict[tuple[str, ObjectSpec], tuple[GraspScene, mujoco.MjData]] = {}

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

    def run(self, task: TaskRequest) -> TaskResult:
        params = task.params
        obj_params = P.section(params, "object", "params")
        obj = ObjectSpec.parse(obj_params)
        hand = hand_dims(P.string(P.section(params, "hand", "params"), "name", "params.hand"))
        physics = Physics.parse(params.get("physics", {}))
        trials = [
            parse_trial(t, f"params.trials[{i}]") for i, t in enumerate(P.items(params, "trials", "params"))
        ]
        if len({index for index, _ in trials}) != len(trials):
            raise BadInput("params.trials: grasp_index values must be unique")

        scene, data = self._scene(hand.name, obj)
        records = [run_trial(scene, data, physics, index, seed) for index, seed in trials]
        document: dict[str, Any] = {
            "object": dict(obj_params),
            "hand": {"name": hand.name, "dof": hand.dof, "links": hand_geometry(scene)},
            "trials": records,
            "physics": physics.to_json(),
        }
        path = task.out_dir / OUTPUT_NAME
        path.write_text(json.dumps(document, indent=1, allow_nan=False))
        result = TaskResult()
        result.add(path, "application/json")
        accepted = sum(record["accepted"] for record in records)
        result.metrics.update(trials=len(records), accepted=accepted)
        return result

    def _scene(self, hand_name: str, obj: ObjectSpec) -> tuple[GraspScene, mujoco.MjData]:
        key = (hand_name, obj)
        if key not in self._scenes:
            scene = build_scene(hand_dims(hand_name), obj)
            self._scenes[key] = (scene, mujoco.MjData(scene.model))
        return self._scenes[key]


def parse_trial(trial: Any, where: str) -> tuple[int, int]:
    return P.integer(trial, "grasp_index", where, low=0), P.seed(trial, "seed", where)
