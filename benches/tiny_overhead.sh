#!/usr/bin/env bash
# Orchestration overhead of `vintctl run examples/tiny.toml`: how much of the end-to-end wall time
# the engines account for, with 1 worker and with 2.
#
#   benches/tiny_overhead.sh [RUNS]        RUNS per worker count, default 3
#   VINT_BENCH_SMOKE=1 benches/tiny_overhead.sh
#
# The smoke (VINT_BENCH_SMOKE=1; seconds: the test command's check that the bench still runs, not a
# figure) runs benches/smoke.toml instead of tiny.toml, once per worker count unless RUNS is given.
#
# Builds the binaries (dev profile, as scripts/setup.sh does), then runs tiny.toml RUNS times with
# --workers 1 and RUNS times with --workers 2, each in a fresh state directory, timing the whole
# vintctl process. Afterwards it reads the run's SQLite state (<state>/vint.db, table attempts:
# timings_json of every succeeded attempt) and the engines' "ready in N ms" log lines
# (<state>/logs/worker-*.log) and prints, per run and as medians:
#   wall       the vintctl process, start to exit (coordinator start, submit, work, export, stop)
#   job        the job's created_ms to finished_ms, as the coordinator recorded them
#   Σengine    engine_ms summed over tasks: engine start-up (when the task started one) and the run
#   Σstartup   the engines' own start-up ("ready in", from their import to their hello; the Python
#              interpreter's start before that is not in it), part of Σengine
#   Σtask      total_ms summed over tasks: fetch + engine + upload as the worker timed them
#   overhead   (wall − Σengine) / wall: the share of wall time no engine was working (1 worker only)
#   efficiency Σengine / (workers × wall): how busy the workers' engines kept them
# the succeeded tasks by stage, and, for 1 worker, where the wall time went: outside the job
# (coordinator start, submit, export, stopping workers), in the job before the first lease (worker
# start), between tasks (lease and completion RPCs, idle polls), in tasks outside the engine (fetch,
# upload), in engines.
# The last line is JSON with the medians. Needs the engines' Python (.venv, or $VINT_PYTHON).
set -euo pipefail

ROOT="$(cd "$(dirname "$0")/.." && pwd)"
cd "$ROOT"
SPEC=examples/tiny.toml
RUNS="${1:-3}"
if [[ "${VINT_BENCH_SMOKE:-0}" == 1 ]]; then
    SPEC=benches/smoke.toml
    RUNS="${1:-1}"
fi
export VINT_PYTHON="${VINT_PYTHON:-$ROOT/.venv/bin/python}"
[[ -x "$VINT_PYTHON" ]] || {
    echo "tiny_overhead: engine Python $VINT_PYTHON is missing: run scripts/setup-python.sh" >&2
    exit 1
}

cargo build --workspace --bins >&2
VINTCTL="$ROOT/target/debug/vintctl"
TMP="$(mktemp -d "${TMPDIR:-/tmp}/vint-tiny-bench.XXXXXX")"
trap 'rm -rf "$TMP"' EXIT

now_ms() { echo $(($(date +%s%N) / 1000000)); }

for workers in 1 2; do
    for run in $(seq "$RUNS"); do
        dir="$TMP/w$workers-r$run"
        mkdir -p "$dir"
        started=$(now_ms)
        if ! "$VINTCTL" run "$SPEC" --out "$dir/out" --state "$dir/state" \
            --workers "$workers" --json >"$dir/stdout.json" 2>"$dir/stderr.log"; then
            cat "$dir/stderr.log" >&2
            echo "tiny_overhead: vintctl run failed (workers=$workers, run $run)" >&2
            exit 1
        fi
        echo $(($(now_ms) - started)) >"$dir/wall_ms"
        echo "tiny_overhead: workers=$workers run $run: $(cat "$dir/wall_ms") ms" >&2
    done
done

"$VINT_PYTHON" - "$TMP" "$RUNS" <<'PY'
import glob
import json
import re
import sqlite3
import statistics
import sys
from pathlib import Path

tmp, runs = Path(sys.argv[1]), int(sys.argv[2])
READY = re.compile(r"vint-(\w+) INFO ready in (\d+) ms")


def measure(dir: Path, workers: int) -> dict:
    db = sqlite3.connect(dir / "state" / "vint.db")
    rows = db.execute(
        "SELECT t.stage, a.timings_json, a.outcome, a.started_ms FROM attempts a "
        "JOIN tasks t ON t.id = a.task_id"
    ).fetchall()
    created, finished = db.execute("SELECT created_ms, finished_ms FROM jobs").fetchone()
    db.close()
    ok = [(stage, json.loads(t)) for stage, t, outcome, _ in rows if outcome == "succeeded"]
    first_lease = min(started for *_, started in rows)
    engine_by_stage: dict[str, float] = {}
    tasks_by_stage: dict[str, int] = {}
    for stage, t in ok:
        engine_by_stage[stage] = engine_by_stage.get(stage, 0.0) + t["engine_ms"]
        tasks_by_stage[stage] = tasks_by_stage.get(stage, 0) + 1
    startup_by_stage: dict[str, float] = {}
    for log in glob.glob(str(dir / "state" / "logs" / "worker-*.log")):
        for m in READY.finditer(Path(log).read_text(errors="replace")):
            startup_by_stage[m[1]] = startup_by_stage.get(m[1], 0.0) + float(m[2])
    wall = float((dir / "wall_ms").read_text())
    engine = sum(engine_by_stage.values())
    task = sum(t["total_ms"] for _, t in ok)
    job = float(finished - created)
    head = float(first_lease - created)
    return {
        "workers": workers,
        "tasks": len(ok),
        "attempts_not_succeeded": len(rows) - len(ok),
        "wall_ms": wall,
        "job_ms": job,
        "engine_ms": engine,
        "startup_ms": sum(startup_by_stage.values()),
        "task_ms": task,
        "outside_job_ms": wall - job,
        "before_first_lease_ms": head,
        "between_tasks_ms": job - head - task if workers == 1 else None,
        "overhead_pct": 100.0 * (wall - engine) / wall if workers == 1 else None,
        "efficiency_pct": 100.0 * engine / (workers * wall),
        "engine_ms_by_stage": engine_by_stage,
        "tasks_by_stage": tasks_by_stage,
        "startup_ms_by_stage": startup_by_stage,
    }


COLS = [
    "wall_ms",
    "job_ms",
    "engine_ms",
    "startup_ms",
    "task_ms",
    "outside_job_ms",
    "before_first_lease_ms",
    "between_tasks_ms",
    "overhead_pct",
    "efficiency_pct",
]
HEAD = f"{'':>14} {'tasks':>5} {'wall ms':>9} {'job ms':>9} {'Σengine':>9} {'Σstartup':>9} {'Σtask':>9} {'overhead':>9} {'effic.':>7}"


def row(label: str, m: dict) -> str:
    overhead = "—" if m["overhead_pct"] is None else f"{m['overhead_pct']:.1f}%"
    return (
        f"{label:>14} {m['tasks']:>5} {m['wall_ms']:>9.0f} {m['job_ms']:>9.0f} {m['engine_ms']:>9.0f} "
        f"{m['startup_ms']:>9.0f} {m['task_ms']:>9.0f} {overhead:>9} {m['efficiency_pct']:>6.1f}%"
    )


def median_of(ms: list[dict], key: str):
    values = [m[key] for m in ms if m[key] is not None]
    return statistics.median(values) if values else None


medians = {}
print(HEAD)
for workers in (1, 2):
    ms = [measure(tmp / f"w{workers}-r{r}", workers) for r in range(1, runs + 1)]
    for r, m in enumerate(ms, 1):
        print(row(f"{workers}w run {r}", m))
        if m["attempts_not_succeeded"]:
            print(f"{'':>14} ({m['attempts_not_succeeded']} attempt(s) did not succeed)")
    med = {c: median_of(ms, c) for c in COLS}
    med["tasks"] = ms[0]["tasks"]
    med["tasks_by_stage"] = ms[0]["tasks_by_stage"]
    if any(m["tasks_by_stage"] != ms[0]["tasks_by_stage"] for m in ms):
        print(f"{'':>14} (runs differ in tasks by stage: {[m['tasks_by_stage'] for m in ms]})")
    med["workers"] = workers
    med["engine_ms_by_stage"] = {
        s: statistics.median(m["engine_ms_by_stage"].get(s, 0.0) for m in ms)
        for s in sorted({s for m in ms for s in m["engine_ms_by_stage"]})
    }
    med["startup_ms_by_stage"] = {
        s: statistics.median(m["startup_ms_by_stage"].get(s, 0.0) for m in ms)
        for s in sorted({s for m in ms for s in m["startup_ms_by_stage"]})
    }
    print(row(f"{workers}w median", med))
    medians[workers] = med

print()
for workers in (1, 2):
    m = medians[workers]
    by_stage = ", ".join(f"{s} {v:.0f}" for s, v in m["engine_ms_by_stage"].items())
    startup = ", ".join(f"{s} {v:.0f}" for s, v in m["startup_ms_by_stage"].items())
    tasks = ", ".join(f"{s} {n}" for s, n in sorted(m["tasks_by_stage"].items()))
    print(f"{workers}w succeeded tasks by stage: {tasks}")
    print(f"{workers}w median Σengine by stage (ms): {by_stage}")
    print(f"{workers}w median Σstartup by stage (ms): {startup}")
m = medians[1]
print(
    "1w median wall by where it went (ms): "
    f"outside the job {m['outside_job_ms']:.0f}, before the first lease {m['before_first_lease_ms']:.0f}, "
    f"between tasks {m['between_tasks_ms']:.0f}, in tasks outside engines {m['task_ms'] - m['engine_ms']:.0f}, "
    f"in engines {m['engine_ms']:.0f} (of which engine start-up ≥ {m['startup_ms']:.0f})"
)
print(f"speed-up 2 workers / 1 worker (median wall): {medians[1]['wall_ms'] / medians[2]['wall_ms']:.2f}x")
print(json.dumps({"bench": "tiny_overhead", "runs": runs, "medians": [medians[1], medians[2]]}))
PY
