"""The figures of a benches/dispatch.sh run, and a random sample of its samples checked end to end.

Reads what dispatch.sh left in --out (plan.json, rss.csv, progress.csv, latency-*.csv,
db-before.json, db-after.json), checks --verify random samples' lineage through `vintctl lineage`
against the database and the object store, and writes summary.json and lineage.json.

A sample passes when its lineage is its package task, its grasp's own tasks (render, noise) and its
grasp task, every task succeeded in timing-only mode, its grasp's tasks are keyed by its grasp and
its grasp task ran that trial, each task's inputs are outputs of the tasks upstream of it (by
hash), each packaged file is an artifact of its grasp's own tasks (by hash), and every output on
the chain is in the object store at its size.

It has no smoke mode of its own: it reads a dispatch run, and `VINT_BENCH_SMOKE=1 bash
benches/dispatch.sh`, the smoke the test command runs, ends with this report on its small run.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
from packed_outputs import unpack  # the store's packed outputs, read from SQL

LATENCY_FIELDS = ["unix_ms", "slot", "tasks", "lease_ms", "complete_ms"]  # vint-worker --latency-log


def read_csv(path: Path, fields: list[str] | None = None) -> list[dict[str, float]]:
    """Rows of a CSV file as numbers; `fields` names the columns of a file without a header."""
    if not path.exists():
        return []
    with path.open() as f:
        rows = csv.DictReader(f, fieldnames=fields)
        return [{k: float(v) for k, v in row.items()} for row in rows if all(row.values())]


def sample_ids(database: str, job: str, n: int) -> list[str]:
    """`n` samples of `job` in a fixed pseudo-random order: one of each of `n` package tasks (a
    package task's files are named `<sample id>/<file>`)."""
    query = (
        "SELECT t.id, encode(o.files, 'hex') FROM tasks t JOIN outputs o ON o.task_id = t.id "
        f"WHERE t.job_id = '{job}' AND t.stage = 'package' ORDER BY md5(t.id || 'dispatch-check') LIMIT {n}"
    )
    out = subprocess.run(["psql", database, "-At", "-c", query], check=True, capture_output=True, text=True)
    picked = []
    for line in out.stdout.split():
        task_id, files = line.split("|")
        # Sample ids are OBJECT.HAND.gNNNNNN.vNN; the grasp records' directories have no view.
        samples = sorted({f.name.split("/")[0] for f in unpack(bytes.fromhex(files))})
        samples = [s for s in samples if len(s.split(".")) == 4]
        if samples:
            picked.append(min(samples, key=lambda s: hashlib.md5((s + task_id).encode()).hexdigest()))
    return picked


def check_sample(sample: str, lineage: dict[str, Any], store: Path) -> list[str]:
    """What is wrong with one sample's lineage (nothing, when it passes). The chain is its package
    task, its grasp's own tasks (a render task, and whatever stages the job adds between), then its
    grasp task, in pipeline order as `vintctl lineage` shows it; no stage between is named here."""
    problems = []
    tasks = lineage["tasks"]
    stages = [t["stage"] for t in tasks]
    if len(tasks) < 3 or stages[0] != "package" or stages[-1] != "grasp" or len(set(stages)) != len(stages):
        return [f"stages {stages}"]
    package, own, grasp = tasks[0], tasks[1:-1], tasks[-1]
    object_, hand, grasp_part, view_part = sample.split(".")
    grasp_index, view_index = int(grasp_part[1:]), int(view_part[1:])
    for t in tasks:
        if t["state"] != "succeeded":
            problems.append(f"{t['key']} is {t['state']}")
        if t["engine"].get("mode") != "timing-only":
            problems.append(f"{t['key']} engine {t['engine']}")
    for t in own:
        if t["key"] != f"{t['stage']}/{object_}/{hand}/g{grasp_index:06d}":
            problems.append(f"{t['key']} is not grasp {grasp_index}'s {t['stage']} task")
        if t["params"].get("grasp_index", grasp_index) != grasp_index:
            problems.append(f"{t['key']} is for grasp {t['params']['grasp_index']}")
    if grasp_index not in [trial["grasp_index"] for trial in grasp["params"]["trials"]]:
        problems.append(f"grasp task {grasp['key']} did not run trial {grasp_index}")
    if not grasp["key"].startswith(f"grasp/{object_}/{hand}/"):
        problems.append(f"grasp task {grasp['key']} is of another pair")

    def hashes(t: dict[str, Any]) -> set[str]:
        return {a["sha256"] for a in t["outputs"]}

    # Each task reads only what the tasks upstream of it on the chain made.
    for i, child in enumerate(tasks[:-1]):
        made = set().union(*(hashes(p) for p in tasks[i + 1 :]))
        stray = [a["name"] for a in child["inputs"] if a["sha256"] not in made]
        if stray:
            problems.append(f"{child['key']} reads {stray[:3]} that its dependencies did not make")
    mine = [a for a in package["outputs"] if a["name"].startswith(sample + "/")]
    names = {a["name"].split("/", 1)[1] for a in mine}
    if "meta.json" not in names:
        problems.append("no meta.json")
    view = f"v{view_index:02d}_"
    pixels = set().union(*(hashes(t) for t in own))
    for a in mine:
        if a["name"].endswith("/meta.json"):
            continue
        if a["sha256"] not in pixels:
            problems.append(f"{a['name']} is not an artifact of its grasp's own tasks")
    view_files = [a for t in own for a in t["outputs"] if a["name"].startswith(view)]
    if len(view_files) < len(mine) - 1:
        problems.append(f"{len(view_files)} files of view {view_index}, {len(mine) - 1} packaged")
    for t in tasks:
        for a in t["outputs"]:
            path = store / "sha256" / a["sha256"][:2] / a["sha256"]  # vint_artifacts::key_for
            if not path.exists() or path.stat().st_size != a["size"]:
                problems.append(f"{a['name']} of {t['key']}: not in the object store at {a['size']} B")
                break
    return problems


def verify(args: argparse.Namespace) -> dict[str, Any]:
    checked, failures = 0, {}
    for sample in sample_ids(args.database, args.job, args.verify):
        out = subprocess.run(
            [args.vintctl, "lineage", sample, "--job", args.job, "--coordinator", args.coordinator, "--json"],
            capture_output=True,
            text=True,
        )
        checked += 1
        if out.returncode != 0:
            failures[sample] = [out.stderr.strip()]
            continue
        problems = check_sample(sample, json.loads(out.stdout), Path(args.store))
        if problems:
            failures[sample] = problems
    return {"checked": checked, "passed": checked - len(failures), "failures": failures}


def deciles(rows: list[dict[str, float]], field: str) -> list[float]:
    """Median of `field` over each tenth of the rows, in time order."""
    rows = sorted(rows, key=lambda r: r["unix_ms"])
    n = len(rows)
    tenths = [rows[i * n // 10 : max((i + 1) * n // 10, i * n // 10 + 1)] for i in range(10)] if n else []
    return [round(statistics.median(r[field] for r in tenth), 2) for tenth in tenths]


def per_sample(state: dict[str, Any]) -> dict[str, Any]:
    samples = max(state["samples"], 1)
    return {
        "database_bytes": state["database_bytes"],
        "database_bytes_per_sample": round(state["database_bytes"] / samples, 1),
        "tables": {
            t["name"]: {
                "bytes_per_sample": round(t["total_bytes"] / samples, 1),
                "live_rows": t["live_rows"],
                "dead_rows": t["dead_rows"],
            }
            for t in state["tables"]
        },
        "indexes": {i["name"]: i["bytes"] for i in state["indexes"]},
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__)
    for flag in ("out", "job", "database", "coordinator", "vintctl", "store"):
        p.add_argument(f"--{flag}", required=True)
    for flag in ("submitted", "finished", "start"):
        p.add_argument(f"--{flag}", type=float, required=True)
    for flag in ("verify", "workers", "batch", "concurrency"):
        p.add_argument(f"--{flag}", type=int, required=True)
    args = p.parse_args()
    out = Path(args.out)

    plan = json.loads((out / "plan.json").read_text())
    before = json.loads((out / "db-before.json").read_text())
    after = json.loads((out / "db-after.json").read_text())
    rss = read_csv(out / "rss.csv")
    batches = [row for f in sorted(out.glob("latency-*.csv")) for row in read_csv(f, LATENCY_FIELDS)]
    wall_s = args.finished - args.submitted
    rss_mib = [r["rss_kib"] / 1024 for r in rss]
    lineage = verify(args)
    (out / "lineage.json").write_text(json.dumps(lineage, indent=2) + "\n")

    summary = {
        "workers": args.workers,
        "batch": args.batch,
        "concurrency": args.concurrency,
        "samples": before["samples"],
        "samples_planned": plan["counts"]["samples"],
        "tasks_planned": plan["totals"]["tasks"],
        "database_bytes_per_sample_planned": round(plan["database"]["bytes_per_sample"], 1),
        "tasks": before["tasks"],
        "submit_s": round(args.submitted - args.start, 2),
        "wall_s": round(wall_s, 1),
        "tasks_per_s": round(before["tasks"] / wall_s, 1),
        "samples_per_s": round(before["samples"] / wall_s, 1),
        "coordinator_rss_mib": {
            "first": round(rss_mib[0], 1) if rss_mib else None,
            "median": round(statistics.median(rss_mib), 1) if rss_mib else None,
            "max": round(max(rss_mib), 1) if rss_mib else None,
            "last": round(rss_mib[-1], 1) if rss_mib else None,
            "deciles": deciles([{"unix_ms": r["t_s"], "mib": r["rss_kib"] / 1024} for r in rss], "mib"),
        },
        "lease_ms_by_decile": deciles(batches, "lease_ms"),
        "complete_ms_by_decile": deciles(batches, "complete_ms"),
        "batches": len(batches),
        "tasks_per_batch_median": statistics.median(r["tasks"] for r in batches) if batches else None,
        "before_vacuum": per_sample(before),
        "after_vacuum": per_sample(after),
        "lineage_checked": lineage["checked"],
        "lineage_passed": lineage["passed"],
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    sizes = ("before_vacuum", "after_vacuum")
    print(json.dumps({k: v for k, v in summary.items() if k not in sizes}, indent=2))
    for when in sizes:
        s = summary[when]
        print(f"{when}: {s['database_bytes'] / 1e9:.2f} GB, {s['database_bytes_per_sample']:.0f} B/sample")
        for name, t in sorted(s["tables"].items(), key=lambda kv: -kv[1]["bytes_per_sample"]):
            rows = f"live {t['live_rows']:>11,}  dead {t['dead_rows']:>9,}"
            print(f"  {name:<12} {t['bytes_per_sample']:>8.0f} B/sample  {rows}")
        for name, size in sorted(s["indexes"].items()):
            print(f"  index {name:<28} {size / 1e6:>9.1f} MB")
    if lineage["failures"]:
        failed = len(lineage["failures"])
        print(f"lineage: {failed} of {lineage['checked']} samples FAILED, e.g.:", file=sys.stderr)
        for sample, problems in list(lineage["failures"].items())[:5]:
            print(f"  {sample}: {problems}", file=sys.stderr)
        return 1
    print(f"lineage: all {lineage['checked']} sampled samples verified end to end")
    return 0


if __name__ == "__main__":
    sys.exit(main())
