"""Touch read-out: its response curve, its cost per capture against the proximity model it replaced,
and how its output moves with its resolution knob (averaged contact steps).

Run: PYTHONPATH=workers/engines .venv/bin/python benches/touch_study.py --out docs [--seeds N] [--reps R]
     PYTHONPATH=workers/engines .venv/bin/python benches/touch_study.py --smoke

`--smoke`: 2 seeds, 1 repetition, written into a temporary directory (seconds: the test command's
check that the bench still runs).

Writes OUT/touch_response.png (reading against force for several gains and aging values) and
OUT/studies/touch_readout/{cost,resolution}.csv, and prints the tables docs/touch.md quotes, then one JSON
object with every figure.

Each hand grasps each object with N seeds through `run_trial` (default physics); on every accepted
grasp's captured state the read-outs run side by side, R times each (medians): the proximity model
of commit `--baseline` (loaded from git, as it was: its distances and response on the links in
contact or within 3 mm) and the contact model with 1, 4 and 16 averaged steps (its contact sampling
included). Times are the thread's CPU time (`time.thread_time`): wall time on a shared machine
swings several-fold. The resolution study reads the same states with every number of steps, against
a 64-step average: the readings' error relative to the reference's mean reading, and the active
set's IoU.
"""

from __future__ import annotations

import argparse
import csv
import importlib.util
import json
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import matplotlib
import mujoco
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from vint_engines.grasp.hands import hand_dims
from vint_engines.grasp.hands.catalog import read_hand_catalog
from vint_engines.grasp.scene import build_scene
from vint_engines.grasp.taxels import parse_layout
from vint_engines.grasp.touch import Skin, TouchParams, held_contacts, response
from vint_engines.grasp.trial import Physics, finger_contacts, run_trial
from vint_engines.objects import load_catalog

HANDS = ("trx3", "allegro")
OBJECTS = ("tomato_soup_can", "mustard_bottle", "mug")
STEPS = (1, 2, 4, 8, 16)
REFERENCE_STEPS = 64
TIMED_STEPS = (1, 4, 16)
BASELINE = "0425b54"
OLD_PARAMS = {
    "sensing_depth_m": 0.003,
    "response_depth_m": 0.002,
    "gain_sigma": 0.1,
    "aging": 1.0,
    "gain_seed": 123,
    "min_active_taxels": 3,
}


def load_baseline(commit: str) -> Any:
    """The proximity model's module as it was at `commit`."""
    source = subprocess.run(
        ["git", "show", f"{commit}:workers/engines/vint_engines/grasp/touch.py"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    with tempfile.TemporaryDirectory(prefix="vint-touch-baseline-") as scratch:
        path = Path(scratch) / "proximity_touch.py"
        path.write_text(source)
        spec = importlib.util.spec_from_file_location("proximity_touch", path)
        if spec is None or spec.loader is None:
            raise RuntimeError("cannot load the baseline touch model")
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module  # dataclasses look their module up there
        spec.loader.exec_module(module)
    return module


def median_ms(fn: Callable[[], object], reps: int) -> float:
    times = []
    for _ in range(reps):
        started = time.thread_time()
        fn()
        times.append(time.thread_time() - started)
    return 1e3 * statistics.median(times)


def spearman(x: list[float], y: list[float]) -> float:
    def ranks(v: np.ndarray) -> np.ndarray:
        r = np.empty(len(v))
        r[np.argsort(v, kind="stable")] = np.arange(len(v), dtype=float)
        return r

    return float(np.corrcoef(ranks(np.array(x)), ranks(np.array(y)))[0, 1])


def compare(reading: dict[str, Any], reference: dict[str, Any]) -> tuple[float, float]:
    """Relative reading error (RMS over taxels active in either, over the reference's mean active
    reading) and the active sets' IoU."""
    a = {t["taxel"] for t in reading["active"]}
    b = {t["taxel"] for t in reference["active"]}
    union = sorted(a | b)
    if not union:
        return 0.0, 1.0
    r, r0 = np.array(reading["readings"])[union], np.array(reference["readings"])[union]
    scale = float(np.mean([t["reading"] for t in reference["active"]])) if b else 1.0
    return float(np.sqrt(np.mean((r - r0) ** 2)) / scale), len(a & b) / len(union)


def unsensed_share(touch: dict[str, Any]) -> float:
    return touch["unsensed_force_n"] / max(touch["contact_force_n"], 1e-12)


def link_pairs(trial: dict[str, Any], touch: dict[str, Any]) -> list[tuple[float, float]]:
    """(link's contact force at the capture, sum of its readings) for every link in contact."""
    force: dict[str, float] = {}
    for contact in trial["contacts"]:
        force[contact["link"]] = force.get(contact["link"], 0.0) + contact["force"]
    summed: dict[str, float] = {}
    for taxel in touch["active"]:
        summed[taxel["link"]] = summed.get(taxel["link"], 0.0) + taxel["reading"]
    return [(f, summed.get(link, 0.0)) for link, f in force.items()]


def time_reads(scene: Any, data: mujoco.MjData, skin: Skin, proximity: Any, reps: int) -> dict[str, Any]:
    """Median times (ms) and active counts of the proximity read-out and the contact read-out with
    each number of averaged steps, on the captured state in `data`."""
    links = {c["link"] for c in finger_contacts(scene, data)}
    row: dict[str, Any] = {
        "proximity_ms": median_ms(lambda: proximity.read(data, links), reps),
        "proximity_active": proximity.read(data, links)["active_count"],
    }
    for steps in TIMED_STEPS:

        def contact_read(steps: int = steps) -> dict[str, Any]:
            return skin.read(data, held_contacts(scene, data, steps, finger_contacts), 1.0)

        row[f"contact_{steps}_ms"] = median_ms(contact_read, reps)
        row[f"contact_{steps}_active"] = contact_read()["active_count"]
    return row


def study(seeds: int, reps: int, baseline: str) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    old = load_baseline(baseline)
    catalog = load_catalog()
    physics = Physics.parse({})
    cost_rows, resolution_rows = [], []
    for hand_name in HANDS:
        hand = hand_dims(hand_name)
        path = read_hand_catalog()[hand_name].taxels_path()
        layout = parse_layout(path.read_text(encoding="utf-8"), hand.link_names(), str(path))
        for obj in OBJECTS:
            scene = build_scene(hand, catalog[obj])
            data = mujoco.MjData(scene.model)
            default = Skin(scene, layout, TouchParams.parse({}))
            proximity = old.Skin(scene, layout, old.TouchParams(**OLD_PARAMS))
            for k in range(seeds):
                seed = 1234567890123 + 7919 * k
                trial = run_trial(scene, data, physics, default, k, seed)
                if not trial["accepted"]:
                    continue
                row = {
                    "hand": hand_name,
                    "object": obj,
                    "seed": seed,
                    **time_reads(scene, data, default, proximity, reps),
                }
                cost_rows.append(row)
                samples = held_contacts(scene, data, REFERENCE_STEPS, finger_contacts)
                reference = default.read(data, samples, 1.0)
                for steps in STEPS:
                    touch = default.read(data, samples[:steps], 1.0)
                    error, iou = compare(touch, reference)
                    resolution_rows.append(
                        {
                            "hand": hand_name,
                            "object": obj,
                            "seed": seed,
                            "steps": steps,
                            "active": touch["active_count"],
                            "unsensed_share": touch["unsensed_force_n"]
                            / max(touch["contact_force_n"], 1e-12),
                            "rel_error": error,
                            "iou": iou,
                            "pairs": json.dumps(link_pairs(trial, touch)),
                        }
                    )
    return cost_rows, resolution_rows


def plot_response(path: Path) -> None:
    params = TouchParams.parse({})
    force = np.geomspace(0.02, 500.0, 600)
    figure, (by_gain, by_age) = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    for gain in (0.8, 1.0, 1.25):
        by_gain.plot(force, response(force, np.full(len(force), gain), params, 1.0), label=f"gain {gain}")
    for aging in (1.0, 0.5, 0.2, 0.05):
        by_age.plot(force, response(force, np.ones(len(force)), params, aging), label=f"aging {aging}")
    for axis, title in ((by_gain, "taxel-to-taxel gains (aging 1)"), (by_age, "aging (gain 1)")):
        axis.set_xscale("log")
        axis.axvline(params.activation_force_n, color="grey", linestyle=":", linewidth=1)
        axis.axvline(params.half_force_n, color="grey", linestyle="--", linewidth=1)
        axis.set_xlabel("local normal force on the taxel (N)")
        axis.set_title(title)
        axis.legend(loc="upper left")
        axis.grid(True, which="both", alpha=0.3)
    by_gain.set_ylabel("reading")
    figure.suptitle(
        f"r = g·x/(1+x), x = aging·f/{params.half_force_n:g} N, zero below aging·f = "
        f"{params.activation_force_n:g} N (dotted); half force dashed"
    )
    figure.tight_layout()
    figure.savefig(path, dpi=110, metadata={"Software": None})
    plt.close(figure)


def write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def summarise(cost: list[dict[str, Any]], resolution: list[dict[str, Any]]) -> dict[str, Any]:
    summary: dict[str, Any] = {"captures": len(cost), "cost": {}, "resolution": []}
    for hand in HANDS:
        rows = [r for r in cost if r["hand"] == hand]
        keys = ["proximity"] + [f"contact_{s}" for s in TIMED_STEPS]
        summary["cost"][hand] = {
            key: {
                "median_ms": statistics.median(r[f"{key}_ms"] for r in rows),
                "median_active": statistics.median(r[f"{key}_active"] for r in rows),
            }
            for key in keys
        }
    for steps in STEPS:
        rows = [r for r in resolution if r["steps"] == steps]
        pairs = [p for r in rows for p in json.loads(r["pairs"])]
        summary["resolution"].append(
            {
                "steps": steps,
                "median_active": statistics.median(r["active"] for r in rows),
                "median_unsensed_share": statistics.median(r["unsensed_share"] for r in rows),
                "median_rel_error": statistics.median(r["rel_error"] for r in rows),
                "p90_rel_error": float(np.percentile([r["rel_error"] for r in rows], 90)),
                "median_iou": statistics.median(r["iou"] for r in rows),
                "link_spearman": spearman([p[0] for p in pairs], [p[1] for p in pairs]),
            }
        )
    return summary


def print_tables(summary: dict[str, Any]) -> None:
    print(f"captures: {summary['captures']}")
    print("| hand | read-out | median ms per capture | median active taxels |")
    print("|---|---|---:|---:|")
    for hand, cost in summary["cost"].items():
        for key, value in cost.items():
            print(f"| {hand} | {key} | {value['median_ms']:.2f} | {value['median_active']:g} |")
    print()
    print("| steps | active | unsensed share | rel. error median / p90 | IoU | link rank corr. |")
    print("|---:|---:|---:|---:|---:|---:|")
    for r in summary["resolution"]:
        print(
            f"| {r['steps']} | {r['median_active']:g} "
            f"| {r['median_unsensed_share']:.2f} "
            f"| {r['median_rel_error']:.3f} / {r['p90_rel_error']:.3f} | {r['median_iou']:.2f} "
            f"| {r['link_spearman']:.2f} |"
        )


def run(out: Path, seeds: int, reps: int, baseline: str) -> None:
    """The study into `out`: the figure, the CSV files, the tables and the JSON line."""
    out.mkdir(parents=True, exist_ok=True)
    plot_response(out / "touch_response.png")
    cost, resolution = study(seeds, reps, baseline)
    write_csv(out / "studies" / "touch_readout" / "cost.csv", cost)
    write_csv(out / "studies" / "touch_readout" / "resolution.csv", resolution)
    summary = summarise(cost, resolution)
    print_tables(summary)
    print(json.dumps(summary))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", type=Path, help="required unless --smoke")
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--reps", type=int, default=15)
    parser.add_argument("--baseline", default=BASELINE)
    parser.add_argument("--smoke", action="store_true", help="2 seeds, 1 repetition, into a temp dir")
    args = parser.parse_args()
    if args.smoke:
        with tempfile.TemporaryDirectory(prefix="vint-touch-study-") as scratch:
            run(args.out or Path(scratch), 2, 1, args.baseline)
    elif args.out is None:
        parser.error("--out is required (without it only --smoke runs, into a temporary directory)")
    else:
        run(args.out, args.seeds, args.reps, args.baseline)
    return 0


if __name__ == "__main__":
    sys.exit(main())
