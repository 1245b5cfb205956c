"""The built-in object catalog, `catalog/objects.toml` at the repository root: the one definition
of the objects a dataset spec can name (the Rust side reads the same file). Mesh-file shapes in it
resolve their `path` against the catalog directory.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

from vint_engines.objects.spec import ObjectSpec
from vint_engines.protocol import BadInput

CATALOG_DIR = Path(__file__).resolve().parents[4] / "catalog"
OBJECTS_TOML = CATALOG_DIR / "objects.toml"


def load_catalog(path: Path = OBJECTS_TOML) -> dict[str, ObjectSpec]:
    """Every `[[object]]` of the catalog by name, validated; BadInput names the offending entry."""
    try:
        document = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise BadInput(f"{path.name}: {exc}") from exc
    entries = document.get("object")
    if not isinstance(entries, list) or not entries:
        raise BadInput(f"{path.name}: expected [[object]] tables")
    objects: dict[str, ObjectSpec] = {}
    for i, entry in enumerate(entries):
        spec = ObjectSpec.parse(entry, f"{path.name} object[{i}]")
        if spec.name in objects:
            raise BadInput(f"{path.name} object[{i}].name: {spec.name!r} is defined twice")
        objects[spec.name] = spec
    return objects
