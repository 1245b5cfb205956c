"""The grasp procedure before and after a change, side by side in one run: acceptance per
(object, hand), the spread of the held object's orientation and the cost per trial.

Usage (from the repository root):
    .venv/bin/python benches/grasp_procedure.py --before 0425b54 --trials 6 [--objects a,b] [--hands trx3]
    .venv/bin/python benches/grasp_procedure.py --smoke

`--smoke`: one trial per hand on the tomato soup can, HEAD's engines against the working tree's
(seconds: the test command's check that the bench still runs, not a figure; it needs no history).

The engines of revision `--before` (extracted with `git archive` into a temporary directory) and
of the working tree each run in a worker process; the parent hands them the same trials (same
object, hand and seed) alternately, one at a time, so both see the same machine load. A worker
times `run_trial` alone (`time.perf_counter`; scenes are built before the first timed trial).

Orientation spread: the held object's +z axis after the hold, in the world frame and in the palm
frame, binned into 32 equal-area cells of the sphere (4 bands of equal height times 8 sectors);
reported as the fraction of cells hit and the largest angle of the axis from world up.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
# Trial k of the i-th (object, hand) pair has seed SEED0 + SEED_STEP * k + PAIR_STEP * i: every
# trial its own seed, as the planner derives them (one seed for all pairs would give every object
# the same few orientations).
SEED0, SEED_STEP, PAIR_STEP = 1234567890123, 7919, 104729

# Runs inside a worker process with its engines on PYTHONPATH; one JSON request per line.
WORKER = r"""
import json, sys, time, tomllib
import numpy as np
from vint_engines.grasp.engine import GraspEngine
from vint_engines.grasp.hands import hand_dims
from vint_engines.grasp.scene import ObjectSpec
from vint_engines.grasp.touch import Skin, TouchParams
from vint_engines.grasp.trial import Physics, run_trial
from vint_engines.poses import quat_to_matrix

catalog = {e["name"]: e for e in tomllib.loads(open("catalog/objects.toml").read())["object"]}
engine, skins = GraspEngine(), {}
for line in sys.stdin:
    ask = json.loads(line)
    hand, obj = hand_dims(ask["hand"]), ObjectSpec.parse(catalog[ask["object"]])
    scene, data = engine._scene(hand.name, hand, obj, {})
    key = (hand.name, obj.name)
    if key not in skins:
        layout, _ = engine._layout(hand.name, hand, {"name": hand.name}, {})
        skins[key] = Skin(scene, layout, TouchParams.parse({}))
    physics = Physics.parse({"hold_s": ask["hold_s"]})
    started = time.perf_counter()
    record = run_trial(scene, data, physics, skins[key], 0, ask["seed"])
    ms = 1e3 * (time.perf_counter() - started)
    out = {"ms": ms, "accepted": record["accepted"], "reason": record["reason"]}
    if record["accepted"]:
        obj_rot = quat_to_matrix(record["object_pose"]["q"])
        palm_rot = quat_to_matrix(record["hand_pose"]["q"])
        out["axis_world"] = obj_rot[:, 2].tolist()
        out["axis_palm"] = (palm_rot.T @ obj_rot[:, 2]).tolist()
        out["joints"] = record["joints"]
    print(json.dumps(out), flush=True)
"""


def extract(revision: str, into: Path) -> Path:
    archive = subprocess.run(
        ["git", "archive", revision, "workers/engines", "catalog"], cwd=ROOT, check=True, capture_output=True
    ).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    return into


def worker(tree: Path) -> subprocess.Popen[str]:
    env = {**os.environ, "PYTHONPATH": str(tree / "workers" / "engines")}
    return subprocess.Popen(
        [sys.executable, "-c", WORKER],
        cwd=tree,
        env=env,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )


def ask(process: subprocess.Popen[str], request: dict[str, Any]) -> dict[str, Any]:
    assert process.stdin is not None and process.stdout is not None
    process.stdin.write(json.dumps(request) + "\n")
    process.stdin.flush()
    line = process.stdout.readline()
    if not line:
        raise RuntimeError(f"worker exited while running {request}")
    return json.loads(line)


def sphere_cells(axes: list[list[float]], bands: int = 4, sectors: int = 8) -> int:
    cells = set()
    for x, y, z in axes:
        band = min(int((z + 1.0) / 2.0 * bands), bands - 1)
        sector = min(int((math.atan2(y, x) + math.pi) / (2 * math.pi) * sectors), sectors - 1)
        cells.add((band, sector))
    return len(cells)


def summary(results: list[dict[str, Any]]) -> dict[str, Any]:
    accepted = [r for r in results if r["accepted"]]
    world = [r["axis_world"] for r in accepted]
    return {
        "trials": len(results),
        "accepted": len(accepted),
        "median_ms": statistics.median(r["ms"] for r in results) if results else math.nan,
        "cells_world": sphere_cells(world),
        "cells_palm": sphere_cells([r["axis_palm"] for r in accepted]),
        "max_tilt_deg": max((math.degrees(math.acos(max(-1.0, min(1.0, a[2])))) for a in world), default=0.0),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", default="0425b54", help="revision of the engines to compare with")
    parser.add_argument("--trials", type=int, default=6, help="trials per (object, hand)")
    parser.add_argument("--hold", type=float, default=1.0, help="hold_s of every trial")
    parser.add_argument("--objects", default="", help="comma-separated catalog names (default: all)")
    parser.add_argument("--hands", default="trx3,allegro")
    parser.add_argument("--json", type=Path, help="write every trial's result here")
    parser.add_argument("--smoke", action="store_true", help="1 trial per hand on one object (seconds)")
    args = parser.parse_args()
    if args.smoke:  # against HEAD's own engines: the check needs no history (a shallow clone)
        args.trials, args.objects, args.before = 1, "tomato_soup_can", "HEAD"
    catalog = tomllib.loads((ROOT / "catalog" / "objects.toml").read_text())["object"]
    objects = args.objects.split(",") if args.objects else [e["name"] for e in catalog]
    hands = args.hands.split(",")
    with tempfile.TemporaryDirectory() as tmp:
        workers = {"before": worker(extract(args.before, Path(tmp))), "after": worker(ROOT)}
        results: dict[str, dict[tuple[str, str], list[dict[str, Any]]]] = {name: {} for name in workers}
        pairs = [(obj, hand) for obj in objects for hand in hands]
        for i, (obj, hand) in enumerate(pairs):
            for k in range(args.trials):
                seed = SEED0 + SEED_STEP * k + PAIR_STEP * i
                request = {"object": obj, "hand": hand, "seed": seed, "hold_s": args.hold}
                order = ("before", "after") if k % 2 == 0 else ("after", "before")
                for name in order:
                    results[name].setdefault((obj, hand), []).append(ask(workers[name], request))
        for process in workers.values():
            assert process.stdin is not None
            process.stdin.close()
            process.wait()
    print("| object | hand | accepted before | after | median ms before | after |")
    print("|---|---|---:|---:|---:|---:|")
    for obj, hand in results["after"]:
        b, a = summary(results["before"][(obj, hand)]), summary(results["after"][(obj, hand)])
        reasons = sorted(
            {str(r["reason"]).split(":")[0] for r in results["after"][(obj, hand)] if not r["accepted"]}
        )
        why = f" ({', '.join(reasons)})" if reasons else ""
        print(
            f"| {obj} | {hand} | {b['accepted']}/{b['trials']} | {a['accepted']}/{a['trials']}{why}"
            f" | {b['median_ms']:.0f} | {a['median_ms']:.0f} |"
        )
    print()
    for name in workers:
        every = [r for rows in results[name].values() for r in rows]
        total = summary(every)
        by_hand = {
            h: summary([r for (o, hh), rows in results[name].items() if hh == h for r in rows]) for h in hands
        }
        print(
            f"{name}: accepted {total['accepted']}/{total['trials']},"
            f" median {total['median_ms']:.1f} ms per trial, object +z axis over 32 sphere cells:"
            f" world {total['cells_world']}, palm frame {total['cells_palm']}, "
            f"largest tilt from up {total['max_tilt_deg']:.0f} deg; per hand "
            + ", ".join(
                f"{h} {s['accepted']}/{s['trials']} {s['median_ms']:.1f} ms" for h, s in by_hand.items()
            )
        )
        allegro = [
            r for (o, h), rows in results[name].items() if h == "allegro" for r in rows if r["accepted"]
        ]
        if allegro:
            spread = {
                j: statistics.pstdev(r["joints"][j] for r in allegro)
                for j in ("f0_j0", "f1_j0", "f2_j0", "f3_j1")
            }
            rounded = json.dumps({j: round(v, 3) for j, v in spread.items()})
            print(f"  allegro abduction std over accepted grasps (rad): {rounded}")
    if args.json:
        args.json.write_text(
            json.dumps(
                {n: {f"{o}/{h}": rows for (o, h), rows in r.items()} for n, r in results.items()}, indent=1
            )
        )


if __name__ == "__main__":
    main()
