"""The stages with an engine here, and the way to each one: by convention the module
`vint_engines.<stage>.engine` defines `make_engine()` (build the engine: load its libraries and
scene) and `parse_params(params)` (check a task's parameters as the engine does before it runs
anything). A new stage's engine package is found without a list to extend: the stages are the
contract's (the generated `contract.schema.json`) that have such a module.
"""

from __future__ import annotations

import importlib
import json
from pathlib import Path
from types import ModuleType

PACKAGE_DIR = Path(__file__).resolve().parent
SCHEMA_FILE = PACKAGE_DIR / "contract.schema.json"


def python_stages() -> tuple[str, ...]:
    """The stages of the contract with an engine here (`vint_engines/<stage>/engine.py`)."""
    stages = json.loads(SCHEMA_FILE.read_text(encoding="utf-8"))["stages"]
    return tuple(s for s in sorted(stages) if (PACKAGE_DIR / s / "engine.py").is_file())


def engine_module(stage: str) -> ModuleType:
    """The stage's engine module (imports its heavy libraries: only the chosen stage's)."""
    if stage not in python_stages():
        raise ValueError(f"unknown stage {stage!r}: expected one of {', '.join(python_stages())}")
    return importlib.import_module(f"vint_engines.{stage}.engine")
