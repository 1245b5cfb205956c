"""Command line: `python -m vint_engines serve --stage {grasp|render|noise}`.

Only parses arguments and wires a stage's engine into the serve loop; heavy libraries are imported
by the chosen stage alone, so a noise engine never pays for Blender.
"""

from __future__ import annotations

import argparse
import logging
import sys

from vint_engines.protocol import Engine, ProtocolError, serve

STAGES = ("grasp", "render", "noise")


def make_engine(stage: str) -> Engine:
    """Import the stage's engine and build it (this loads libraries and the scene)."""
    if stage == "grasp":
        from vint_engines.grasp.engine import GraspEngine

        return GraspEngine()
    if stage == "render":
        from vint_engines.render.engine import RenderEngine

        return RenderEngine()
    if stage == "noise":
        from vint_engines.noise.engine import NoiseEngine

        return NoiseEngine()
    raise ValueError(f"unknown stage {stage!r}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="vint_engines", description=__doc__)
    commands = parser.add_subparsers(dest="command", required=True)
    serve_cmd = commands.add_parser("serve", help="serve tasks over stdin/stdout (PROTOCOL.md)")
    serve_cmd.add_argument("--stage", required=True, choices=STAGES)
    args = parser.parse_args(argv)  # exits 2 on a bad command or stage

    logging.basicConfig(
        stream=sys.stderr,
        level=logging.INFO,
        format=f"%(asctime)s vint-{args.stage} %(levelname)s %(message)s",
    )
    try:
        return serve(args.stage, lambda: make_engine(args.stage))
    except ProtocolError as exc:
        logging.getLogger("vint_engines").error("protocol error, exiting: %s", exc)
        return 3


if __name__ == "__main__":
    sys.exit(main())
