"""Touch's one geometric knob against its error and cost: `touch.contact_margin_m` (which taxels
count as touching, and how a link's force spreads over them) swept over tiny.toml's grasps, each
value's recall and precision measured by `tests/python/check_touch_recall.py` (which places the
taxels and measures their distances to the exported model with its own code) and the read-out's
CPU time per accepted grasp from the grasp tasks' own metrics (`touch_ms` in the engine record).

Usage (from the repository root, after `scripts/setup.sh`):
    .venv/bin/python benches/touch_margin.py [--margins-mm 0.1,0.2,0.3,0.5,1,2] [--trials 4] [--out DIR]
    .venv/bin/python benches/touch_margin.py --smoke      # one margin (0.5 mm), one trial (seconds)

Each value runs `vintctl run` on examples/tiny.toml with that margin, `trials_per_pair` trials per
(hand, object), the pose modality only and one view (the renders are not what is measured), on one
worker. The physics does not read the margin, so every value sees the same grasps; a grasp can only
be accepted or not by its active-taxel count (`min_active_taxels`). The check's own tolerances stay
fixed (a taxel within 0.3 mm of the model, or inside it, touches; an active one within 0.5 mm is in
contact), so a margin below 0.3 mm shows as lost recall and one above 0.5 mm as lost precision.
Prints one JSON line per value and a markdown table.
"""

from __future__ import annotations

import argparse
import json
import re
import sqlite3
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "examples" / "tiny.toml"
VINTCTL = ROOT / "target" / "debug" / "vintctl"
CHECK = ROOT / "tests" / "python" / "check_touch_recall.py"


def spec_text(margin_m: float, trials: int) -> str:
    """tiny.toml with the margin, the trial count, one view and the pose modality only."""
    text = TINY.read_text()
    replacements = [
        (r"(?m)^contact_margin_m = .*$", f"contact_margin_m = {margin_m!r}"),
        (r"(?m)^trials_per_pair = .*$", f"trials_per_pair = {trials}"),
        (r"(?m)^views_per_environment = .*$", "views_per_environment = 1"),
        (r"(?m)^environments = .*$", 'environments = ["studio"]'),
        (r"(?m)^modalities = .*$", 'modalities = ["pose"]'),
    ]
    for pattern, value in replacements:
        text, count = re.subn(pattern, value, text)
        if count != 1:
            raise SystemExit(f"touch_margin: tiny.toml has no single line matching {pattern!r}")
    return text


def touch_cost(state: Path) -> tuple[float, int]:
    """Sum of the grasp tasks' `touch_ms` and their accepted trials, from the run's database."""
    db = sqlite3.connect(state / "vint.db")
    total_ms, accepted = 0.0, 0
    for (text,) in db.execute("select engine_json from tasks where stage = 'grasp'"):
        metrics = json.loads(text)["metrics"]
        total_ms += float(metrics["touch_ms"])
        accepted += int(metrics["accepted"])
    return total_ms, accepted


def measure(margin_m: float, trials: int, work: Path) -> dict[str, Any]:
    spec = work / f"margin_{margin_m}.toml"
    spec.write_text(spec_text(margin_m, trials))
    out, state = work / f"out_{margin_m}", work / f"state_{margin_m}"
    run = subprocess.run(
        [str(VINTCTL), "run", str(spec), "--out", str(out), "--state", str(state), "--workers", "1"],
        capture_output=True,
        text=True,
        check=False,
    )
    if run.returncode != 0:
        raise SystemExit(f"touch_margin: vintctl run failed for margin {margin_m}:\n{run.stderr[-2000:]}")
    check = subprocess.run(
        [sys.executable, str(CHECK), str(out)], capture_output=True, text=True, check=False
    )
    if check.returncode not in (0, 1):
        raise SystemExit(f"touch_margin: the check could not read the dataset:\n{check.stderr}")
    report = json.loads(check.stdout)
    touch_ms, accepted = touch_cost(state)
    return {
        "margin_mm": 1e3 * margin_m,
        "grasps": report["grasps"],
        "recall": report["recall"],
        "precision": report["precision"],
        "active": report["active"],
        "active_per_grasp": report["active"] / max(1, report["grasps"]),
        "touch_ms_per_accepted": touch_ms / max(1, accepted),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--margins-mm", default="0.1,0.2,0.3,0.5,1,2")
    parser.add_argument("--trials", type=int, default=4, help="trials per (hand, object)")
    parser.add_argument("--out", type=Path, default=None, help="keep the datasets here (default: a temp dir)")
    parser.add_argument("--smoke", action="store_true", help="one margin (0.5 mm), one trial (seconds)")
    args = parser.parse_args()
    if args.smoke:
        args.margins_mm, args.trials = "0.5", 1
    if not VINTCTL.exists():
        raise SystemExit(f"touch_margin: {VINTCTL} not built (scripts/setup.sh)")
    margins = [1e-3 * float(v) for v in args.margins_mm.split(",")]
    with tempfile.TemporaryDirectory(prefix="vint-touch-margin-") as scratch:
        work = args.out or Path(scratch)
        work.mkdir(parents=True, exist_ok=True)
        rows = []
        for margin in margins:
            row = measure(margin, args.trials, work)
            print(json.dumps(row), flush=True)
            rows.append(row)
    print("\n| margin (mm) | grasps | recall | precision | active per grasp | read-out CPU ms per grasp |")
    print("|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(
            f"| {r['margin_mm']:g} | {r['grasps']} | {r['recall']:.3f} | {r['precision']:.3f} "
            f"| {r['active_per_grasp']:.1f} | {r['touch_ms_per_accepted']:.2f} |"
        )
    costs = [r["touch_ms_per_accepted"] for r in rows]
    median = statistics.median(costs)
    print(f"\nread-out ms per grasp: {min(costs):.2f}–{max(costs):.2f} (median {median:.2f})")


if __name__ == "__main__":
    main()
