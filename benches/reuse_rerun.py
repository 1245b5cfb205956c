"""Task reuse: a finished job's re-run after one noise parameter changes, against the full run.

    benches/reuse_rerun.py [--trials N] [--workers W]
    benches/reuse_rerun.py --smoke

Runs `vintctl run` on examples/tiny.toml with `grasp.trials_per_pair = N` (default 30: about 500
samples) in a fresh state directory, then the same spec with `noise.sigma_scale` raised from 1.0 to
1.5 over the same state: the second job reuses every grasp and render task and runs noise and
package. Each run is timed (wall) and its CPU time taken from the finished process tree
(vintctl, its workers and their engines: RUSAGE_CHILDREN). From the first job's attempts it sums
the engine time of its noise and package tasks — the work the re-run cannot avoid — and prints:

    | run | samples | wall s | CPU s | tasks run | tasks reused |

with the ratios re-run / full run, and the noise + package engine time of the full run, then one
line of JSON. Also checks the re-run's dataset against a fresh run of the changed spec (manifest
hash, this machine) when --check is given (it costs a third full run).

--smoke runs benches/smoke.toml instead (seconds: the test command's check that this still runs).
Needs the engines' Python (.venv, or $VINT_PYTHON) and the target/debug binaries.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
VINTCTL = ROOT / "target" / "debug" / "vintctl"


def cpu_children() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run(spec: Path, out: Path, state: Path, workers: int) -> dict[str, object]:
    """One `vintctl run`: its summary, wall and CPU seconds."""
    env = {**os.environ, "VINT_PYTHON": os.environ.get("VINT_PYTHON", str(ROOT / ".venv/bin/python"))}
    cpu0, t0 = cpu_children(), time.perf_counter()
    done = subprocess.run(
        [
            str(VINTCTL),
            "--json",
            "run",
            str(spec),
            "--out",
            str(out),
            "--state",
            str(state),
            "--workers",
            str(workers),
        ],
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    wall, cpu = time.perf_counter() - t0, cpu_children() - cpu0
    if done.returncode != 0:
        sys.exit(f"reuse_rerun: vintctl run {spec.name} failed:\n{done.stdout}\n{done.stderr}")
    summary = json.loads(done.stdout)
    return {"summary": summary, "wall_s": wall, "cpu_s": cpu}


def counts(summary: dict[str, object]) -> tuple[int, int]:
    """Tasks that ran and tasks reused, over every stage."""
    stages = summary["stages"]
    assert isinstance(stages, dict)
    reused = sum(int(s["reused"]) for s in stages.values())
    return sum(int(s["succeeded"]) for s in stages.values()) - reused, reused


def engine_seconds(state: Path, stages: tuple[str, ...]) -> float:
    """Engine time of the first job's succeeded attempts of `stages`."""
    db = sqlite3.connect(state / "vint.db")
    try:
        job = db.execute("SELECT id FROM jobs ORDER BY created_ms LIMIT 1").fetchone()[0]
        rows = db.execute(
            "SELECT a.timings_json FROM attempts a JOIN tasks t ON t.id = a.task_id "
            f"WHERE t.job_id = ? AND a.outcome = 'succeeded' AND t.stage IN ({','.join('?' * len(stages))})",
            (job, *stages),
        ).fetchall()
    finally:
        db.close()
    return sum(json.loads(r[0])["engine_ms"] for r in rows if r[0]) / 1e3


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--trials", type=int, default=30, help="grasp.trials_per_pair (default 30: ~500 samples)"
    )
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument(
        "--check", action="store_true", help="also compare with a fresh run of the changed spec"
    )
    parser.add_argument("--smoke", action="store_true", help="benches/smoke.toml, seconds")
    args = parser.parse_args()
    base = (ROOT / ("benches/smoke.toml" if args.smoke else "examples/tiny.toml")).read_text()
    if not args.smoke:
        base = base.replace("trials_per_pair = 2", f"trials_per_pair = {args.trials}")
    if "sigma_scale = 1.0" in base:
        changed = base.replace("sigma_scale = 1.0", "sigma_scale = 1.5")
    else:  # smoke.toml leaves it at its default, 1.0
        changed = base.replace("[noise]\n", "[noise]\nsigma_scale = 1.5\n")
    assert changed != base
    with tempfile.TemporaryDirectory(prefix="vint-reuse-bench-") as tmp:
        work = Path(tmp)
        (work / "full.toml").write_text(base)
        (work / "noisier.toml").write_text(changed)
        state = work / "state"
        full = run(work / "full.toml", work / "out-full", state, args.workers)
        rerun = run(work / "noisier.toml", work / "out-rerun", state, args.workers)
        unavoidable = engine_seconds(state, ("noise", "package"))
        identical = None
        if args.check:
            fresh = work / "fresh"
            run(work / "noisier.toml", fresh / "out", fresh / "state", args.workers)
            identical = (work / "out-rerun" / "manifest.jsonl").read_bytes() == (
                fresh / "out" / "manifest.jsonl"
            ).read_bytes()
    spec = "smoke.toml" if args.smoke else f"tiny.toml with trials_per_pair = {args.trials}"
    print(f"{spec}, {args.workers} workers; then noise.sigma_scale 1.0 → 1.5")
    print("| run | samples | wall s | CPU s | tasks run | tasks reused |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, r in (("full", full), ("re-run, noise changed", rerun)):
        summary = r["summary"]
        assert isinstance(summary, dict)
        ran, reused = counts(summary)
        print(f"| {name} | {summary['samples']} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | {ran} | {reused} |")
    ratio_wall = float(rerun["wall_s"]) / float(full["wall_s"])
    ratio_cpu = float(rerun["cpu_s"]) / float(full["cpu_s"])
    print(f"re-run / full: wall {ratio_wall:.3f}, CPU {ratio_cpu:.3f}")
    print(f"the full run's noise + package engine time: {unavoidable:.1f} s")
    if identical is not None:
        print(f"re-run's manifest equals a fresh run of the changed spec: {identical}")
    report = {
        "bench": "reuse_rerun",
        "trials_per_pair": None if args.smoke else args.trials,
        "samples": full["summary"]["samples"],  # type: ignore[index]
        "full_wall_s": round(float(full["wall_s"]), 2),
        "full_cpu_s": round(float(full["cpu_s"]), 2),
        "rerun_wall_s": round(float(rerun["wall_s"]), 2),
        "rerun_cpu_s": round(float(rerun["cpu_s"]), 2),
        "noise_package_engine_s": round(unavoidable, 2),
        "identical_to_fresh": identical,
    }
    print(json.dumps(report))
    return 0 if identical in (None, True) else 1


if __name__ == "__main__":
    sys.exit(main())
