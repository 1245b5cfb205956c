"""Command line: `python -m vint_engines serve --stage STAGE` (a stage with an engine here:
`vint_engines/stages.py`),
`python -m vint_engines study {grasp|render|touch} --out DIR` (the studies, `vint_engines/study/`),
`python -m vint_engines stats --dataset DIR --out OUT` (a dataset's statistics, `vint_engines/stats/`),
`python -m vint_engines preview --dataset DIR --out SHEET.png` (a contact sheet, `vint_engines/preview/`), and
`python -m vint_engines identity` (each stage's engine identity as JSON, the code and library
versions a task's reuse key names: `vint_engines/identity.py`), and
`python -m vint_engines check-params` (parse planned task parameters with each engine's own
parser, without running anything: a JSON array of `{"stage", "params"}` on stdin, a JSON array of
`{"ok", "error"}` on stdout).

Only parses arguments and wires a stage's engine into the serve loop; heavy libraries are imported
by the chosen stage alone, so a noise engine never pays for Blender.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from pathlib import Path

from vint_engines import memory
from vint_engines.preview import DEFAULT_SAMPLES
from vint_engines.protocol import BadInput, Engine, ProtocolError, serve
from vint_engines.stages import engine_module, python_stages


def make_engine(stage: str) -> Engine:
    """Import the stage's engine and build it (this loads libraries and the scene)."""
    engine: Engine = engine_module(stage).make_engine()
    return engine


def parse_params(stage: str, params: dict[str, object]) -> None:
    """Parse a task's parameters as the stage's engine does before it runs anything; a stage with
    no engine here (package, in Rust) against the contract's schema."""
    if stage in python_stages():
        engine_module(stage).parse_params(params)
    else:
        from vint_engines import contract

        contract.validated(stage, params)


def check_params() -> int:
    tasks = json.load(sys.stdin)
    verdicts = []
    for task in tasks:
        try:
            parse_params(task["stage"], task["params"])
            verdicts.append({"ok": True, "error": None})
        except BadInput as exc:
            verdicts.append({"ok": False, "error": str(exc)})
    json.dump(verdicts, sys.stdout)
    return 0


def names(text: str) -> list[str]:
    return [name.strip() for name in text.split(",") if name.strip()]


def run_study(args: argparse.Namespace) -> int:
    if args.study == "render":
        from vint_engines.study import render

        return render.main(args.out, args.quick)
    if args.study == "touch":
        from vint_engines.study import touch_vs_vision

        if args.vintctl is None:
            print(
                "study touch: --vintctl is required (vintctl study touch passes its own path)",
                file=sys.stderr,
            )
            return 2
        return touch_vs_vision.main(args.out, args.quick, args.vintctl, args.work)
    from vint_engines.study import grasp

    quick_objects = ("tomato_soup_can",) if args.quick else grasp.OBJECTS
    quick_hands = ("trx3",) if args.quick else grasp.HANDS
    return grasp.main(
        args.out, args.quick, args.hands or quick_hands, args.objects or quick_objects, args.seeds
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="vint_engines", description=__doc__)
    commands = parser.add_subparsers(dest="command", required=True)
    serve_cmd = commands.add_parser("serve", help="serve tasks over stdin/stdout (PROTOCOL.md)")
    serve_cmd.add_argument("--stage", required=True, choices=python_stages())
    study_cmd = commands.add_parser("study", help="run a numerics study and write its report")
    study_cmd.add_argument("study", choices=("grasp", "render", "touch"))
    study_cmd.add_argument("--out", required=True, type=Path, help="directory for the CSVs, plot and table")
    study_cmd.add_argument("--quick", action="store_true", help="few seeds and configurations (< 60 s)")
    study_cmd.add_argument("--hands", type=names, help="comma-separated hands (default: trx3,allegro)")
    study_cmd.add_argument("--objects", type=names, help="comma-separated catalog objects")
    study_cmd.add_argument("--seeds", type=int, help="trials per hand and object (default 8, quick 2)")
    study_cmd.add_argument(
        "--vintctl", type=Path, help="touch: the vintctl binary that makes the study's dataset"
    )
    study_cmd.add_argument(
        "--work", type=Path, help="touch: dataset and job state (default .vint/study-touch[-quick]; reused)"
    )
    stats_cmd = commands.add_parser("stats", help="a dataset's statistics: PNG figures, stats.md, stats.json")
    stats_cmd.add_argument("--dataset", required=True, type=Path, help="a native or BOP dataset directory")
    stats_cmd.add_argument("--out", required=True, type=Path, help="directory for the figures and tables")
    stats_cmd.add_argument("--json", action="store_true", help="also print stats.json on stdout")
    preview_cmd = commands.add_parser("preview", help="a native dataset's contact sheet (PNG)")
    preview_cmd.add_argument("--dataset", required=True, type=Path, help="a native dataset directory")
    preview_cmd.add_argument("--out", required=True, type=Path, help="the PNG to write")
    preview_cmd.add_argument(
        "--samples", type=int, default=DEFAULT_SAMPLES, help="rows: samples shown (default 4)"
    )
    preview_cmd.add_argument("--json", action="store_true", help="print a JSON summary")
    commands.add_parser("check-params", help="parse task parameters (JSON on stdin) as the engines do")
    commands.add_parser("identity", help="each stage's engine identity (code and pinned libraries) as JSON")
    args = parser.parse_args(argv)  # exits 2 on a bad command or stage
    if args.command == "study":
        return run_study(args)
    if args.command == "stats":
        from vint_engines import stats

        return stats.main(args.dataset, args.out, args.json)
    if args.command == "preview":
        from vint_engines import preview

        return preview.main(args.dataset, args.out, args.samples, args.json)
    if args.command == "check-params":
        return check_params()
    if args.command == "identity":
        from vint_engines import identity

        json.dump(identity.identities(), sys.stdout, indent=1, sort_keys=True)
        sys.stdout.write("\n")
        return 0

    logging.basicConfig(
        stream=sys.stderr,
        level=logging.INFO,
        format=f"%(asctime)s vint-{args.stage} %(levelname)s %(message)s",
    )
    log = logging.getLogger("vint_engines")
    try:  # before the stage's libraries are imported: their allocations count too
        limit = memory.limit_mib(os.environ)
        if limit is not None:
            memory.apply_limit(limit)
    except memory.LimitError as exc:
        log.error("cannot start: %s", exc)
        return 2
    try:
        return serve(args.stage, lambda: make_engine(args.stage), limit)
    except ProtocolError as exc:
        log.error("protocol error, exiting: %s", exc)
        return 3
    except MemoryError as exc:
        if limit is None:
            raise
        log.error(
            "the engine does not fit in %s=%d MiB (starting or between tasks): %r",
            memory.LIMIT_VARIABLE,
            limit,
            exc,
        )
        return 3


if __name__ == "__main__":
    sys.exit(main())
