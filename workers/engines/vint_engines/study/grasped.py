"""Grasped scenes for render studies and benchmarks: run the real grasp engine once for a hand and
a catalog object and keep what a render task reads (grasps.json, object.ply, accepted indices).

The studies render exactly what the pipeline would render, so they start from the grasp engine's
own outputs rather than from hand-made poses.
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vint_engines.objects import MODEL_FILE, OBJECTS_TOML
from vint_engines.protocol import InputRef, TaskRequest

GRASPS_FILE = "grasps.json"


@dataclass(frozen=True)
class GraspedScene:
    hand: str
    object: str
    directory: Path
    accepted: tuple[int, ...]

    @property
    def grasps_json(self) -> Path:
        return self.directory / GRASPS_FILE

    @property
    def object_ply(self) -> Path:
        return self.directory / MODEL_FILE

    def inputs(self) -> tuple[InputRef, ...]:
        """The render task's inputs, as a worker stages them."""
        key = f"grasp/{self.object}/{self.hand}/c00000"
        return (
            InputRef(GRASPS_FILE, key, self.grasps_json),
            InputRef(MODEL_FILE, key, self.object_ply),
        )


def catalog_entry(name: str) -> dict[str, Any]:
    """A catalog object's table, as the planner sends it in grasp task params."""
    document = tomllib.loads(OBJECTS_TOML.read_text(encoding="utf-8"))
    for entry in document["object"]:
        if entry["name"] == name:
            return dict(entry)
    raise KeyError(f"no catalog object {name!r}")


def grasp(hand: str, obj: str, directory: Path, seeds: list[int]) -> GraspedScene:
    """Run one grasp task (one trial per seed) into `directory`; raises if none is accepted. Any
    grasp type: the render study measures pixels, and keeps the grasps its seeds were chosen for
    (the committed study's, from before power grasps became the default)."""
    from vint_engines.grasp.engine import GraspEngine

    directory.mkdir(parents=True, exist_ok=True)
    params = {
        "object": catalog_entry(obj),
        "hand": {"name": hand},
        "trials": [{"grasp_index": i, "seed": seed} for i, seed in enumerate(seeds)],
        "physics": {"grasp_type": "any"},
    }
    GraspEngine().run(TaskRequest(f"study-{hand}-{obj}", params, (), directory))
    trials = json.loads((directory / GRASPS_FILE).read_text())["trials"]
    accepted = tuple(int(t["grasp_index"]) for t in trials if t.get("accepted"))
    if not accepted:
        reasons = sorted({str(t.get("reason")) for t in trials})
        raise RuntimeError(f"no accepted grasp of {obj} by {hand} in {len(seeds)} trials ({reasons})")
    return GraspedScene(hand, obj, directory, accepted)
