#!/usr/bin/env python3
"""Write the built-in taxel layouts, catalog/hands/<hand>/taxels.csv, from the hand models.

    .venv/bin/python scripts/gen_taxels.py            # every hand in the catalog
    .venv/bin/python scripts/gen_taxels.py allegro    # one hand
    .venv/bin/python scripts/gen_taxels.py --check    # exit 1 if a committed layout is stale
    .venv/bin/python scripts/gen_taxels.py --mjcf examples/assets/gripper.xml --count 240 \
        --out examples/assets/gripper_taxels.csv         # a user's MJCF hand (docs/hands.md)

Deterministic: the same models give byte-identical files on one machine, and the same taxels on any
CPU (vint_engines/grasp/skin.py says how taxels are placed and why the choice cannot depend on the
CPU). `--check` compares as the tests do (`vint_engines.grasp.taxels.layout_differences`): the
same taxels in the same order on the same links and regions, positions and normals within one unit
of the last written digit; the committed files stay authoritative (datasets cite their SHA-256).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from vint_engines.grasp.hands import GraspHand

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    sys.path.insert(0, str(ROOT / "workers" / "engines"))
    from vint_engines.grasp.hands import hand_dims
    from vint_engines.grasp.hands.catalog import read_hand_catalog

    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("hands", nargs="*", help="hand names (default: every hand in the catalog)")
    parser.add_argument("--check", action="store_true", help="compare with the files instead of writing")
    parser.add_argument("--mjcf", type=Path, help="a user's hand model instead of the catalog's hands")
    parser.add_argument("--count", type=int, default=240, help="taxels on an --mjcf hand")
    parser.add_argument("--out", type=Path, help="where an --mjcf hand's layout goes")
    args = parser.parse_args()
    if args.mjcf is not None:
        if args.out is None or args.hands:
            parser.error("--mjcf needs --out and no hand names")
        return mjcf_layout(args.mjcf, args.count, args.out, args.check)
    catalog = read_hand_catalog()
    stale = []
    for name in args.hands or list(catalog):
        if name not in catalog:
            parser.error(f"unknown hand {name!r} (catalog: {sorted(catalog)})")
        if args.check:
            if not is_current(hand_dims(name), None, catalog[name].taxels_path()):
                stale.append(name)
            continue
        write(hand_dims(name), None, catalog[name].taxels_path())
    if stale:
        print(f"stale taxel layouts: {stale} (run scripts/gen_taxels.py)", file=sys.stderr)
        return 1
    return 0


MESH_SUFFIXES = (".stl", ".obj", ".msh")


def mjcf_layout(mjcf: Path, count: int, out: Path, check: bool) -> int:
    from vint_engines.grasp.hands import load_mjcf_hand

    # The MJCF's mesh files are read from beside it (the model's directory is the root they may
    # not leave, as the spec's directory is for a job).
    root = mjcf.resolve().parent
    files = {
        path.relative_to(root).as_posix(): path
        for path in root.rglob("*")
        if path.suffix.lower() in MESH_SUFFIXES
    }
    hand = load_mjcf_hand(mjcf.stem, mjcf.read_text(encoding="utf-8"), str(mjcf), mjcf.name, files)
    if check:
        if not is_current(hand, count, out):
            print(f"stale taxel layout: {out} (run scripts/gen_taxels.py --mjcf {mjcf} ...)", file=sys.stderr)
            return 1
        return 0
    write(hand, count, out)
    return 0


def is_current(hand: GraspHand, count: int | None, path: Path) -> bool:
    """Whether the layout file at `path` is what the generator makes of `hand` (within the
    tolerance the tests use); prints how it differs when it is not."""
    from vint_engines.grasp.skin import generate_layout
    from vint_engines.grasp.taxels import layout_differences, read_layout

    if not path.is_file():
        print(f"{path}: missing", file=sys.stderr)
        return False
    differences = layout_differences(read_layout(path, hand.link_names()), generate_layout(hand, count))
    for difference in differences:
        print(f"{path}: {difference}", file=sys.stderr)
    return not differences


def write(hand: GraspHand, count: int | None, path: Path) -> None:
    from vint_engines.grasp.skin import generate_layout

    text = generate_layout(hand, count).to_csv()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    print(f"{hand.name}: {text.count(chr(10)) - 1} taxels -> {path}")


if __name__ == "__main__":
    sys.exit(main())
