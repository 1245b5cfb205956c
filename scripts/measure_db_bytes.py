#!/usr/bin/env python3
"""Bytes per row of each store table on Postgres, measured on a real job's rows.

    scripts/measure_db_bytes.py STATE/vint.db [--copies 400] [--pg URL] [--keep]

Reads the rows a `vintctl run SPEC --state STATE` job wrote to its SQLite database, copies them
`--copies` times under fresh job ids (so that pages and indexes fill as they do at scale, instead
of one half-empty 8 KiB page per table) into a scratch Postgres database with
`migrations/postgres/*.sql` applied, runs `VACUUM ANALYZE`, and prints per table: rows,
`pg_total_relation_size` (heap + indexes + TOAST) and its parts, and bytes per row — the figures
`vint_store::footprint::POSTGRES_BYTES_PER_ROW` holds. It also prints what the job's tasks wrote
(files and dependencies per task by stage), how an `outputs` row's bytes split into the row and
its packed files (`POSTGRES_BYTES_PER_ROW.outputs` and `.output_files`), and the file sizes by
kind, which
the stages' modules (`services/core/src/contract/<stage>.rs`) use for the object store. The scratch database
(`measure_db_bytes_<pid>`) is dropped at the end unless `--keep`.

Standard library and the `psql` client only.
"""

import argparse
import json
import os
import re
import sqlite3
import statistics
import subprocess
import sys
from pathlib import Path

from packed_outputs import unpack

TABLES = ["jobs", "job_assets", "tasks", "task_deps", "attempts", "outputs", "task_keys"]
ROOT = Path(__file__).resolve().parent.parent


def psql(url, *args, stdin=None):
    cmd = ["psql", url, "-v", "ON_ERROR_STOP=1", "-q", "-X", *args]
    r = subprocess.run(cmd, input=stdin, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"psql {' '.join(args)[:200]} failed:\n{r.stderr}")
    return r.stdout


def copy_text(value):
    """A value in COPY's text format: \\N for NULL, backslash escapes for the rest."""
    if value is None:
        return "\\N"
    if isinstance(value, (int, float)):
        return str(value)
    if isinstance(value, bytes):
        return "\\\\x" + value.hex()  # bytea's hex input, its backslash escaped for COPY
    return value.replace("\\", "\\\\").replace("\t", "\\t").replace("\n", "\\n").replace("\r", "\\r")


def with_job_id(value, old, new):
    return value.replace(old, new) if isinstance(value, str) else value


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sqlite", type=Path, help="a vintctl run state's vint.db")
    ap.add_argument("--copies", type=int, default=400, help="copies of the job's rows (default 400)")
    ap.add_argument(
        "--pg",
        default=os.environ.get("VINT_TEST_POSTGRES_URL", "postgres://postgres@127.0.0.1:5432/postgres"),
    )
    ap.add_argument("--keep", action="store_true", help="keep the scratch database")
    args = ap.parse_args()

    src = sqlite3.connect(f"file:{args.sqlite}?mode=ro", uri=True)
    rows, columns = {}, {}
    for t in TABLES:
        cur = src.execute(f"SELECT * FROM {t}")
        columns[t] = [d[0] for d in cur.description]
        rows[t] = cur.fetchall()
    jobs = [r[columns["jobs"].index("id")] for r in rows["jobs"]]
    if len(jobs) != 1:
        sys.exit(f"{args.sqlite}: expected the rows of one job, found {len(jobs)} jobs")
    job_id = jobs[0]

    db = f"measure_db_bytes_{os.getpid()}"
    base = args.pg.rsplit("/", 1)[0]
    url = f"{base}/{db}"
    psql(args.pg, "-c", f"CREATE DATABASE {db}")
    try:
        for migration in sorted((ROOT / "migrations" / "postgres").glob("*.sql")):
            psql(url, "-f", str(migration))
        for t in TABLES:
            lines = []
            for k in range(args.copies):
                new_id = job_id[:-8] + f"{k:08x}"
                for r in rows[t]:
                    lines.append("\t".join(copy_text(with_job_id(v, job_id, new_id)) for v in r))
            if t == "jobs":
                # Idempotency keys are unique: each copy gets its own of the same length.
                key = columns["jobs"].index("idempotency_key")
                lines = [
                    "\t".join(f if i != key else f[:-8] + f"{k:08x}" for i, f in enumerate(line.split("\t")))
                    for k, line in enumerate(lines)
                ]
            cols = ", ".join(columns[t])
            psql(url, "-c", f"\\copy {t} ({cols}) FROM STDIN", stdin="\n".join(lines) + "\n" if lines else "")
        psql(url, "-c", "VACUUM ANALYZE")
        sizes = {}
        for t in TABLES:
            out = psql(
                url,
                "-A",
                "-t",
                "-c",
                f"SELECT COUNT(*), pg_total_relation_size('{t}'), pg_relation_size('{t}'), "
                f"pg_indexes_size('{t}') FROM {t}",
            ).strip()
            n, total, heap, indexes = (int(x) for x in out.split("|"))
            sizes[t] = {
                "rows": n,
                "total_bytes": total,
                "heap_bytes": heap,
                "index_bytes": indexes,
                "toast_bytes": total - heap - indexes,
                "bytes_per_row": round(total / n, 1) if n else None,
            }
        version = psql(url, "-A", "-t", "-c", "SHOW server_version").strip()
    finally:
        if not args.keep:
            psql(args.pg, "-c", f"DROP DATABASE IF EXISTS {db}")

    print(f"Postgres {version}; one job's rows ({args.sqlite}) copied {args.copies} times\n")
    print(
        f"{'table':<14} {'rows':>10} {'total B':>12} {'heap':>12} {'indexes':>12} {'toast':>10} {'B/row':>8}"
    )
    for t in TABLES:
        s = sizes[t]
        per_row = "—" if s["bytes_per_row"] is None else f"{s['bytes_per_row']:.0f}"
        print(
            f"{t:<14} {s['rows']:>10} {s['total_bytes']:>12} {s['heap_bytes']:>12} {s['index_bytes']:>12} "
            f"{s['toast_bytes']:>10} {per_row:>8}"
        )

    # A task row's size is mostly its parameters, which the planner makes per spec: the part of a
    # row beyond params_json (POSTGRES_TASK_BYTES_BEYOND_PARAMS) is what carries over to other specs.
    params = [r[0] for r in src.execute("SELECT length(params_json) FROM tasks")]
    if params and sizes["tasks"]["rows"]:
        mean_params = sum(params) / len(params)
        beyond = sizes["tasks"]["total_bytes"] / sizes["tasks"]["rows"] - mean_params
        print(
            f"\ntasks: params_json {mean_params:.0f} B per row on average; {beyond:.0f} B per row beyond it"
        )
        for stage, n, mean in src.execute(
            "SELECT stage, COUNT(*), AVG(length(params_json)) FROM tasks GROUP BY stage"
        ):
            print(f"  {stage:<8} {n:>4} tasks, params_json {mean:.0f} B")

    # An outputs row = the row (header, key, index entry, TOAST pointer) + its packed files: the
    # files' share is their encoded bytes, the rest is the row's.
    packed = {task_id: unpack(files) for task_id, files in src.execute("SELECT task_id, files FROM outputs")}
    encoded = src.execute("SELECT COALESCE(SUM(length(files)), 0) FROM outputs").fetchone()[0]
    files_total = sum(len(v) for v in packed.values())
    if files_total and sizes["outputs"]["rows"]:
        per_file = encoded / files_total
        outputs = sizes["outputs"]
        per_row = (outputs["total_bytes"] - per_file * files_total * args.copies) / outputs["rows"]
        print(f"\noutputs: {per_row:.0f} B per row beyond its files, {per_file:.1f} B per packed file")

    # What each task wrote, by stage: the footprint model's inputs, checked against a real run.
    stage_of = {r[0]: r[1] for r in src.execute("SELECT id, stage FROM tasks")}
    trials_of = {
        r[0]: len(json.loads(r[1]).get("trials", []))
        for r in src.execute("SELECT id, params_json FROM tasks WHERE stage = 'grasp'")
    }
    per_stage = {}
    for task_id, stage in stage_of.items():
        a = len(packed.get(task_id, []))
        d = src.execute("SELECT COUNT(*) FROM task_deps WHERE task_id = ?", (task_id,)).fetchone()[0]
        per_stage.setdefault(stage, []).append((a, d))
    print("\nper task, by stage: tasks; files, dependencies (min–max)")
    for stage, v in sorted(per_stage.items()):
        artifacts = f"{min(x[0] for x in v)}–{max(x[0] for x in v)}"
        deps = f"{min(x[1] for x in v)}–{max(x[1] for x in v)}"
        print(f"  {stage:<8} {len(v):>4} tasks; files {artifacts}, deps {deps}")

    # Object store: sizes by file kind (the name past the sample, grasp or view prefix).
    kinds = {}
    grasp_per_trial = {}
    for task_id, name, size in ((t, f.name, f.size) for t, fs in packed.items() for f in fs):
        kind = re.sub(r"^v\d\d_", "", name.rsplit("/", 1)[-1])
        kinds.setdefault((stage_of[task_id], kind), []).append(size)
        if stage_of[task_id] == "grasp" and trials_of.get(task_id):
            grasp_per_trial.setdefault(kind, []).append(size / trials_of[task_id])
    print("\nartifact bytes by stage and file kind: count, median (min–max)")
    for (stage, kind), sizes_ in sorted(kinds.items()):
        median = statistics.median(sizes_)
        print(f"  {stage:<8} {kind:<18} {len(sizes_):>5}  {median:>10.0f}  ({min(sizes_)}–{max(sizes_)})")
    print("grasp files per trial the chunk ran: median (min–max)")
    for kind, v in sorted(grasp_per_trial.items()):
        print(f"  {kind:<18} {statistics.median(v):>10.0f}  ({min(v):.0f}–{max(v):.0f})")
    print(json.dumps({"postgres": version, "copies": args.copies, "tables": sizes}))


if __name__ == "__main__":
    main()
