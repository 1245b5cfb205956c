"""Grasp types and readiness, measured from the trial records alone: acceptance and rejection
reasons per (hand, object), how many accepted grasps touch with the palm, how far the object's
centre sits from the palm, how many press the object with the back of a link, and the CPU cost per
accepted grasp.

Usage (from the repository root):
    .venv/bin/python benches/grasp_types.py --trials 16 [--type power] [--json out.json]
    .venv/bin/python benches/grasp_types.py --trials 8 --type power --sweep CLOSE_S=0.2,0.4,0.8
    PYTHONPATH=/tmp/before/workers/engines .venv/bin/python benches/grasp_types.py --trials 16
    .venv/bin/python benches/grasp_types.py --smoke

The second form measures another revision's engines (`git archive <rev> workers/engines catalog |
tar -x -C /tmp/before`); `--type` is left out then (older engines have no `grasp_type`). Physics
are `examples/tiny.toml`'s (2 ms, 0.5 s hold). Seeds follow `benches/grasp_procedure.py`.

`--smoke` is one trial per (hand, object) (seconds: the test command's check that the bench still
runs, not a figure).

`--sweep NAME=v1,v2,...` reruns the same trials once per value of one of the procedure's constants
in `vint_engines/grasp/trial.py` (`SWEEPABLE`: how long the fingers close, how far the palm presses,
how many steps find the standoff), set on the module for the bench's own process only, and prints
one summary line per value: acceptance, reasons, palm and back-contact shares and CPU per accepted
grasp against the procedure's resolution.

Independent of the engine's own checks: the back of a link is read from its geometry in the
record's `hand.links` (a finger link's dorsal half is the side away from the palm, link -x, by the
built-in hands' convention; the palm's is its -z half), and the object's centre from its model's
vertices (`ObjectSurface`) at the recorded pose.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from vint_engines.grasp import trial
from vint_engines.grasp.engine import GraspEngine
from vint_engines.grasp.hands import hand_dims
from vint_engines.grasp.scene import GraspScene, ObjectSpec, hand_geometry
from vint_engines.grasp.touch import Skin, TouchParams
from vint_engines.grasp.trial import Physics, run_trial
from vint_engines.poses import quat_to_matrix

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "python"))
from check_touch_recall import back_forces  # the dataset check's own back rule

ROOT = Path(__file__).resolve().parents[1]
SEED0, SEED_STEP, PAIR_STEP = 1234567890123, 7919, 104729
TINY_PHYSICS = {"timestep": 0.002, "hold_s": 0.5, "lift_height": 0.10, "max_drop_m": 0.02}
ACTIVATION_N = 0.2
# The procedure's constants `--sweep` may set (trial.py's names).
SWEEPABLE = ("CLOSE_S", "SQUEEZE_S", "PALM_PRESS_M", "PALM_APPROACH_S", "STANDOFF_ITERATIONS")


def back_force(record: dict[str, Any], links: dict[str, dict[str, Any]]) -> tuple[float, str]:
    """The largest mean normal force (N) on the back of one link over the record's contact
    samples, and that link, judged as the dataset check judges it (`back_forces` in
    tests/python/check_touch_recall.py: a finger's back is link -x, behind its capsule's axis by
    half its radius, short of its end cap; the palm's is its -z half)."""
    forces = back_forces({"hand": {"links": list(links.values())}, "touch": record["touch"]})
    if not forces:
        return 0.0, ""
    link = max(forces, key=lambda k: forces[k])
    return forces[link], link


def centre_from_palm(scene: GraspScene, record: dict[str, Any]) -> tuple[float, float]:
    """The object's bounding-box centre's height above the palm's palmar face (m) and the
    object's bounding radius about that centre (m)."""
    vertices = scene.obj.surface.vertices
    centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    radius = float(np.linalg.norm(vertices - centre, axis=1).max())
    obj, palm = record["object_pose"], record["hand_pose"]
    world = quat_to_matrix(obj["q"]) @ centre + np.array(obj["p"])
    local = quat_to_matrix(palm["q"]).T @ (world - np.array(palm["p"]))
    return float(local[2] - scene.hand.palm_half[2]), radius


def run_pair(
    engine: GraspEngine, hand: str, entry: dict[str, Any], seeds: list[int], grasp_type: str | None
) -> list[dict]:
    dims, obj = hand_dims(hand), ObjectSpec.parse(entry)
    scene, data = engine._scene(hand, dims, obj, {})
    layout, _ = engine._layout(hand, dims, {"name": hand}, {})
    skin = Skin(scene, layout, TouchParams.parse({}))
    physics = Physics.parse({**TINY_PHYSICS, **({"grasp_type": grasp_type} if grasp_type else {})})
    links = {link["name"]: link for link in hand_geometry(scene)}
    rows = []
    for seed in seeds:
        started = time.process_time()
        record = run_trial(scene, data, physics, skin, 0, seed)
        row: dict[str, Any] = {
            "hand": hand,
            "object": obj.name,
            "seed": seed,
            "accepted": record["accepted"],
            "reason": record["reason"],
            "cpu_s": time.process_time() - started,
        }
        if record["accepted"]:
            height, radius = centre_from_palm(scene, record)
            force, link = back_force(record, links)
            palm = sum(1 for t in record["touch"]["active"] if t["region"] == "palm")
            row.update(palm_active=palm, centre_mm=1e3 * height, radius_mm=1e3 * radius)
            row.update(back_force_n=force, back_link=link, unsensed_n=record["touch"]["unsensed_force_n"])
            row.update(hold={k: v for k, v in record["hold"].items() if k != "steps"})
        rows.append(row)
    return rows


def summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    accepted = [r for r in rows if r["accepted"]]
    reasons: dict[str, int] = {}
    for r in rows:
        if not r["accepted"]:
            kind = str(r["reason"]).split(":", 1)[0]
            reasons[kind] = reasons.get(kind, 0) + 1
    n = max(1, len(accepted))
    return {
        "trials": len(rows),
        "accepted": len(accepted),
        "rejected": dict(sorted(reasons.items())),
        "palm_share": sum(r["palm_active"] > 0 for r in accepted) / n,
        "back_share": sum(r["back_force_n"] > ACTIVATION_N for r in accepted) / n,
        "centre_over_radius_max": max((r["centre_mm"] / r["radius_mm"] for r in accepted), default=0.0),
        "centre_mm_median": statistics.median([r["centre_mm"] for r in accepted]) if accepted else None,
        "cpu_ms_per_accepted": 1e3 * sum(r["cpu_s"] for r in rows) / n,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=16, help="trials per (hand, object)")
    parser.add_argument("--type", default=None, help="grasp_type (power, precision, any)")
    parser.add_argument("--hands", default="trx3,allegro")
    parser.add_argument("--objects", default="tomato_soup_can,mustard_bottle,mug")
    parser.add_argument("--json", type=Path, default=None, help="write every trial's row here")
    parser.add_argument("--sweep", default=None, help=f"NAME=v1,v2,... (NAME: {', '.join(SWEEPABLE)})")
    parser.add_argument("--smoke", action="store_true", help="1 trial per (hand, object) (seconds)")
    args = parser.parse_args()
    if args.smoke:
        args.trials = 1
    catalog = {e["name"]: e for e in tomllib.loads((ROOT / "catalog/objects.toml").read_text())["object"]}
    engine = GraspEngine()
    if args.sweep is None:
        rows = run_all(engine, catalog, args)
        for hand in args.hands.split(","):
            print(hand, "all", json.dumps(summary([r for r in rows if r["hand"] == hand])))
        print("all", json.dumps(summary(rows)))
    else:
        name, _, values = args.sweep.partition("=")
        if name not in SWEEPABLE or not values:
            parser.error(f"--sweep: expected NAME=v1,v2,... with NAME one of {SWEEPABLE}, got {args.sweep!r}")
        kind = type(getattr(trial, name))
        rows = []
        for value in (kind(v) for v in values.split(",")):
            setattr(trial, name, value)
            swept = [{**row, name: value} for row in run_all(engine, catalog, args)]
            print(f"{name}={value}", "all", json.dumps(summary(swept)), flush=True)
            rows += swept
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


def run_all(engine: GraspEngine, catalog: dict[str, Any], args: argparse.Namespace) -> list[dict[str, Any]]:
    """Every (hand, object) pair's trials, one summary line per pair."""
    rows = []
    for i, (hand, name) in enumerate((h, o) for h in args.hands.split(",") for o in args.objects.split(",")):
        seeds = [SEED0 + SEED_STEP * k + PAIR_STEP * i for k in range(args.trials)]
        pair = run_pair(engine, hand, catalog[name], seeds, args.type)
        print(hand, name, json.dumps(summary(pair)), flush=True)
        rows += pair
    return rows


if __name__ == "__main__":
    main()
