"""Check `vintctl eval` against independent_add.py on perturbed ground truth.

    check_eval.py --dataset BOP_DIR --vintctl PATH --out DIR [--seed N]
        exit 0 and a JSON summary on stdout, or exit 1 and every mismatch on stderr

From the dataset's scene_gt.json it writes a BOP results CSV (DIR/estimates.csv) in which, seeded:
each instance gets its ground-truth pose turned by 0–30° (about a random axis, or about the
object's symmetry axis — models_info's continuous one, else the model's z — with its offset) and
moved by 0–50 mm; a few keep the exact ground truth; some have no estimate at all; some get
lower-scored duplicates (and some equal-scored ones later in the file, which must not count); a
few rows name images or objects that are not annotated. Rows are shuffled. Then it runs
`vintctl eval --json` and independent_add.py's computation and compares, instance by instance, the
estimate chosen and add_mm / adds_mm (1e-6 relative or 1e-4 mm), and every summary (overall, per
object, per occlusion bucket: AUCs and success rates to 1e-6 percentage points).
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import independent_add as ind

HEADER = "scene_id,im_id,obj_id,score,R,t,time"
ERROR_REL, ERROR_ABS_MM = 1e-6, 1e-4
SUMMARY_ABS = 1e-6
SUMMARY_KEYS = ("n", "estimated", "add_auc", "adds_auc", "add_s_auc", "add_s_0.1d", "add_s_0.05d")


def rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues' formula: the turn by `angle` about the unit vector `axis`."""
    a = axis / np.linalg.norm(axis)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def symmetry_axis(root: Path, obj_id: int) -> tuple[np.ndarray, np.ndarray]:
    """The object's continuous symmetry axis and offset (mm), else the model's z through its origin."""
    entry = json.loads((ind.models_folder(root) / "models_info.json").read_text())[str(obj_id)]
    for sym in entry.get("symmetries_continuous") or []:
        return np.array(sym["axis"], dtype=np.float64), np.array(sym["offset"], dtype=np.float64)
    return np.array([0.0, 0.0, 1.0]), np.zeros(3)


def row(scene: int, im: int, obj: int, score: float, R: np.ndarray, t: np.ndarray) -> str:
    r = " ".join(repr(float(v)) for v in R.reshape(-1))
    return f"{scene},{im},{obj},{score!r},{r},{' '.join(repr(float(v)) for v in t)},-1"


def perturbed_csv(root: Path, splits: list[str], seed: int) -> tuple[str, dict[str, int]]:
    rng = np.random.default_rng(seed)
    _, instances = ind.load_dataset(root, splits)
    rows: list[str] = []
    tally = {"instances": len(instances), "missing": 0, "exact": 0, "about_axis": 0, "duplicates": 0}
    for inst in instances:
        u = rng.random()
        if u < 0.1:
            tally["missing"] += 1
            continue
        if u < 0.15:
            R, t = inst.R, inst.t
            tally["exact"] += 1
        else:
            angle = math.radians(rng.uniform(0.0, 30.0))
            if rng.random() < 0.3:  # about the symmetry axis, in the model frame: x ↦ S(x - o) + o
                axis, offset = symmetry_axis(root, inst.obj_id)
                S = rotation(axis, angle)
                R, t = inst.R @ S, inst.t + inst.R @ (offset - S @ offset)
                tally["about_axis"] += 1
            else:
                R, t = rotation(rng.normal(size=3), angle) @ inst.R, inst.t
            direction = rng.normal(size=3)
            t = t + direction / np.linalg.norm(direction) * rng.uniform(0.0, 50.0)
        score = float(rng.uniform(0.5, 1.0))
        rows.append(row(inst.scene_id, inst.im_id, inst.obj_id, score, R, t))
        if rng.random() < 0.3:  # a worse guess with a lower score, or as high a score later on
            wrong = rotation(rng.normal(size=3), math.radians(rng.uniform(0.0, 90.0))) @ inst.R
            lower = score if rng.random() < 0.3 else float(rng.uniform(0.0, score))
            rows.append(
                row(inst.scene_id, inst.im_id, inst.obj_id, lower, wrong, inst.t + rng.normal(size=3) * 30)
            )
            tally["duplicates"] += 1
    if instances:
        i = instances[0]
        rows.append(row(999_999, 0, i.obj_id, 1.0, i.R, i.t))  # no such scene
        rows.append(row(i.scene_id, i.im_id, 999, 1.0, i.R, i.t))  # no such object in the image
    # Shuffle, but keep the order of each (scene, image, object)'s rows: an equal-scored duplicate
    # must stay after the row it ties with (the earlier line wins a tie).
    shuffled = [rows[i] for i in rng.permutation(len(rows))]
    positions: dict[str, list[int]] = {}
    for position, r in enumerate(shuffled):
        positions.setdefault(group_key(r), []).append(position)
    for key, slots in positions.items():
        for position, r in zip(slots, [r for r in rows if group_key(r) == key], strict=True):
            shuffled[position] = r
    return HEADER + "\n" + "\n".join(shuffled) + "\n", tally


def group_key(csv_row: str) -> str:
    return ",".join(csv_row.split(",")[:3])


def close(a: float | None, b: float | None, rel: float, abs_: float) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return abs(a - b) <= max(abs_, rel * max(abs(a), abs(b)))


def compare(vint: dict[str, Any], mine: dict[str, Any], failures: list[str]) -> dict[str, float]:
    worst = {"add_mm": 0.0, "adds_mm": 0.0}
    ours = {(p["scene_id"], p["im_id"], p["gt_index"]): p for p in mine["per_estimate"]}
    theirs = {(p["scene_id"], p["im_id"], p["gt_index"]): p for p in vint["per_estimate"]}
    if set(ours) != set(theirs):
        failures.append(f"instances differ: {sorted(set(ours) ^ set(theirs))[:10]}")
    for key in sorted(set(ours) & set(theirs)):
        o, t = ours[key], theirs[key]
        if o["line"] != t["line"]:
            failures.append(f"{key}: vintctl scored line {t['line']}, expected line {o['line']}")
        for k in ("add_mm", "adds_mm", "add_s_mm"):
            expected = None if math.isinf(o[k]) else o[k]
            if not close(t[k], expected, ERROR_REL, ERROR_ABS_MM):
                failures.append(f"{key} {k}: vintctl {t[k]}, independent {expected}")
            elif k in worst and expected is not None:
                worst[k] = max(worst[k], abs(t[k] - expected))
    groups = {"overall": vint["overall"]}
    groups.update({f"object {o['obj_id']}": o for o in vint["objects"]})
    groups.update({f"bucket {b}": g for b, g in enumerate(vint["occlusion"])})
    if set(groups) != set(mine["groups"]):
        failures.append(f"groups differ: {sorted(set(groups) ^ set(mine['groups']))}")
    for name in sorted(set(groups) & set(mine["groups"])):
        for k in SUMMARY_KEYS:
            if not close(groups[name][k], mine["groups"][name][k], 0.0, SUMMARY_ABS):
                failures.append(
                    f"{name} {k}: vintctl {groups[name][k]}, independent {mine['groups'][name][k]}"
                )
    return worst


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--dataset", type=Path, required=True)
    parser.add_argument("--vintctl", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--split", action="append", default=[])
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    csv_text, tally = perturbed_csv(args.dataset, args.split, args.seed)
    csv_path = args.out / "estimates.csv"
    csv_path.write_text(csv_text)
    command = [
        str(args.vintctl),
        "eval",
        "--dataset",
        str(args.dataset),
        "--estimates",
        str(csv_path),
        "--json",
    ]
    command += [a for s in args.split for a in ("--split", s)]
    run = subprocess.run(command, capture_output=True, text=True, check=False)
    if run.returncode != 0:
        print(f"vintctl eval exited {run.returncode}:\n{run.stdout}\n{run.stderr}", file=sys.stderr)
        return 1
    vint = json.loads(run.stdout)
    mine = ind.evaluate(args.dataset, csv_path, args.split)
    failures: list[str] = []
    worst = compare(vint, mine, failures)
    counted = vint["estimates"]
    expected = {"rows": len(csv_text.splitlines()) - 1, "duplicates": tally["duplicates"], "unmatched": 2}
    for key, value in expected.items():
        if counted[key] != value:
            failures.append(f"estimates.{key}: vintctl {counted[key]}, expected {value}")
    models = ind.models_folder(args.dataset).name
    if vint["models"] != models:
        failures.append(f"vintctl scored on {vint['models']}/, the dataset's evaluation models are {models}/")
    if failures:
        print(f"{len(failures)} mismatches:", *failures[:50], sep="\n  ", file=sys.stderr)
        return 1
    summary = {"tally": tally, "worst_abs_diff_mm": worst, "overall": vint["overall"], "models": models}
    json.dump(summary, sys.stdout, indent=1)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
