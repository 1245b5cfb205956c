"""The hand catalog, `catalog/hands.toml`: which hands exist and where each one's taxel layout is.

Entries look like
```toml
[[hand]]
name = "allegro"
fingers = 4
dof = 16
description = "…"
taxels = "hands/allegro/taxels.csv"   # relative to the catalog directory
```
The catalog directory is the repository's `catalog/` (`vint_engines.objects.catalog` finds it).
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

from vint_engines import params as P
from vint_engines.objects.catalog import CATALOG_DIR
from vint_engines.protocol import BadInput

HANDS_FILE = "hands.toml"


@dataclass(frozen=True)
class HandEntry:
    name: str
    fingers: int
    dof: int
    description: str
    taxels: str  # layout path relative to the catalog directory

    def taxels_path(self, catalog_dir: Path = CATALOG_DIR) -> Path:
        return catalog_dir / self.taxels


def read_hand_catalog(catalog_dir: Path = CATALOG_DIR) -> dict[str, HandEntry]:
    path = catalog_dir / HANDS_FILE
    with path.open("rb") as file:
        document = tomllib.load(file)
    entries: dict[str, HandEntry] = {}
    for i, item in enumerate(P.items(document, "hand", str(path))):
        where = f"{path}: hand[{i}]"
        entry = HandEntry(
            name=P.string(item, "name", where),
            fingers=P.integer(item, "fingers", where, low=1),
            dof=P.integer(item, "dof", where, low=1),
            description=P.string(item, "description", where),
            taxels=P.string(item, "taxels", where),
        )
        if entry.name in entries:
            raise BadInput(f"{where}: hand {entry.name!r} is listed twice")
        entries[entry.name] = entry
    return entries
