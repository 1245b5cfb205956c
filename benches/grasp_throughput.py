"""Grasp engine throughput: accepted grasps per CPU-second, and the share of trial time spent on
taxel evaluation (goal: < 5 %), for each hand on three catalog objects with the default physics.

Run: PYTHONPATH=workers/engines .venv/bin/python benches/grasp_throughput.py [--trials N] [--reps R]
     [--smoke]

`--smoke`: one trial per task and one repetition (seconds: the test command's check that the bench
still runs, not a figure).

Drives `GraspEngine.run` as a worker does (one task of N trials per hand, object and repetition),
with the trial seeds the planner would give a job seeded 20261122 (`trial_seed`), on a warm engine:
a one-trial task per pair first builds the scene, outside the timing. CPU time is
`time.process_time` around each task; the taxel share is the engine's own `touch_ms / trials_ms`
metrics. Prints a table and, last, one JSON object with every figure (medians over the repetitions).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import statistics
import sys
import tempfile
import time
import tomllib
from pathlib import Path
from typing import Any

from vint_engines.grasp.engine import GraspEngine
from vint_engines.objects import OBJECTS_TOML
from vint_engines.protocol import TaskRequest

HANDS = ("trx3", "allegro")
OBJECTS = ("tomato_soup_can", "mustard_bottle", "mug")
SEED = 20261122
SEED_MASK = (1 << 53) - 1


def trial_seed(job_seed: int, obj: str, hand: str, grasp_index: int) -> int:
    """The seed the planner gives trial `grasp_index` of (obj, hand) in a job seeded `job_seed`, by
    the product's one rule (services/core/src/seed.rs, `grasp_trial`): SHA-256 over b"vint-seed-v1\0",
    the job seed (8 bytes little-endian), the stream tag "grasp-trial" and each identity part
    (object, hand, decimal grasp index) after its UTF-8 length (8 bytes little-endian); the first 8
    digest bytes little-endian, masked to 53 bits, the contract's bound (every JSON reader holds
    such a seed exactly)."""
    digest = hashlib.sha256(b"vint-seed-v1\0" + job_seed.to_bytes(8, "little") + b"grasp-trial")
    for part in (obj, hand, str(grasp_index)):
        raw = part.encode("utf-8")
        digest.update(len(raw).to_bytes(8, "little") + raw)
    return int.from_bytes(digest.digest()[:8], "little") & SEED_MASK


def catalog_entries() -> dict[str, dict[str, Any]]:
    """The catalog's entries as the planner sends them (the TOML tables as JSON)."""
    document = tomllib.loads(OBJECTS_TOML.read_text(encoding="utf-8"))
    return {entry["name"]: entry for entry in document["object"]}


def task(hand: str, entry: dict[str, Any], seeds: list[int], out: Path) -> TaskRequest:
    params = {
        "object": entry,
        "hand": {"name": hand},
        "trials": [{"grasp_index": i, "seed": seed} for i, seed in enumerate(seeds)],
    }
    out.mkdir(parents=True, exist_ok=True)
    return TaskRequest(f"bench-{hand}-{entry['name']}", params, (), out)


def measure(engine: GraspEngine, request: TaskRequest) -> dict[str, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    metrics = engine.run(request).metrics
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    return {
        "accepted": metrics["accepted"],
        "trials": metrics["trials"],
        "cpu_s": cpu,
        "wall_s": wall,
        "accepted_per_cpu_s": metrics["accepted"] / cpu,
        "touch_share_pct": 100.0 * metrics["touch_ms"] / metrics["trials_ms"],
        "touch_ms_per_trial": metrics["touch_ms"] / metrics["trials"],
        "active_taxels_median": metrics["active_taxels_median"],
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=16, help="trials per task (default 16)")
    parser.add_argument("--reps", type=int, default=3, help="repetitions; medians are reported")
    parser.add_argument("--smoke", action="store_true", help="1 trial, 1 repetition (seconds)")
    args = parser.parse_args()
    if args.smoke:
        args.trials, args.reps = 1, 1
    entries = catalog_entries()
    engine = GraspEngine()
    results = []
    with tempfile.TemporaryDirectory() as scratch:
        root = Path(scratch)
        for hand in HANDS:
            for name in OBJECTS:
                seeds = [trial_seed(SEED, name, hand, i) for i in range(args.trials)]
                engine.run(task(hand, entries[name], seeds[:1], root / f"warm-{hand}-{name}"))
                runs = [
                    measure(engine, task(hand, entries[name], seeds, root / f"{hand}-{name}-{rep}"))
                    for rep in range(args.reps)
                ]
                median = {key: statistics.median(r[key] for r in runs) for key in runs[0]}
                results.append({"hand": hand, "object": name, **median})
                print(
                    f"{hand:>8} {name:>16}  accepted {median['accepted']:>4.0f}/{args.trials}  "
                    f"{median['accepted_per_cpu_s']:6.2f} accepted/CPU-s  "
                    f"touch {median['touch_share_pct']:5.2f} % "
                    f"({median['touch_ms_per_trial']:.2f} ms/trial)  "
                    f"median active taxels {median['active_taxels_median']:.0f}",
                    file=sys.stderr,
                    flush=True,
                )
    for hand in HANDS:
        mine = [r for r in results if r["hand"] == hand]
        accepted = sum(r["accepted"] for r in mine)
        cpu = sum(r["cpu_s"] for r in mine)
        results.append(
            {
                "hand": hand,
                "object": "all",
                "accepted": accepted,
                "trials": sum(r["trials"] for r in mine),
                "accepted_per_cpu_s": accepted / cpu,
                "touch_share_pct": max(r["touch_share_pct"] for r in mine),
            }
        )
    print(
        "| hand | object | accepted / trials | accepted grasps per CPU-s | taxel share of trial time "
        "| median active taxels |"
    )
    print("|---|---|---:|---:|---:|---:|")
    for r in results:
        share = f"{r['touch_share_pct']:.2f} %" + (" (max)" if r["object"] == "all" else "")
        active = f"{r['active_taxels_median']:.0f}" if "active_taxels_median" in r else ""
        print(
            f"| {r['hand']} | {r['object']} | {r['accepted']:.0f} / {r['trials']:.0f} | "
            f"{r['accepted_per_cpu_s']:.2f} | {share} | {active} |"
        )
    print(json.dumps({"trials_per_task": args.trials, "repetitions": args.reps, "results": results}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
