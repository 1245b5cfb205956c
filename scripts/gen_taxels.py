#!/usr/bin/env python3
"""Write the built-in taxel layouts, catalog/hands/<hand>/taxels.csv, from the hand models.

    .venv/bin/python scripts/gen_taxels.py            # every hand in the catalog
    .venv/bin/python scripts/gen_taxels.py allegro    # one hand
    .venv/bin/python scripts/gen_taxels.py --check    # exit 1 if a committed layout is stale

Deterministic: the same models give byte-identical files (vint_engines/grasp/skin.py says how
taxels are placed).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    sys.path.insert(0, str(ROOT / "workers" / "engines"))
    from vint_engines.grasp.hands import hand_dims
    from vint_engines.grasp.hands.catalog import read_hand_catalog
    from vint_engines.grasp.skin import generate_layout

    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("hands", nargs="*", help="hand names (default: every hand in the catalog)")
    parser.add_argument("--check", action="store_true", help="compare with the files instead of writing")
    args = parser.parse_args()
    catalog = read_hand_catalog()
    stale = []
    for name in args.hands or list(catalog):
        if name not in catalog:
            parser.error(f"unknown hand {name!r} (catalog: {sorted(catalog)})")
        path = catalog[name].taxels_path()
        text = generate_layout(hand_dims(name)).to_csv()
        if args.check:
            if not path.is_file() or path.read_text(encoding="utf-8") != text:
                stale.append(name)
            continue
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
        print(f"{name}: {text.count(chr(10)) - 1} taxels -> {path.relative_to(ROOT)}")
    if stale:
        print(f"stale taxel layouts: {stale} (run scripts/gen_taxels.py)", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
