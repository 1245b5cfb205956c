"""Test set-up: the engines' per-test time limit (`workers/engines/tests/timeouts.py`)."""

from __future__ import annotations

import sys
from pathlib import Path

ENGINE_TESTS = Path(__file__).resolve().parents[2] / "workers" / "engines" / "tests"
if str(ENGINE_TESTS) not in sys.path:
    sys.path.insert(0, str(ENGINE_TESTS))

from timeouts import pytest_configure, pytest_runtest_protocol  # noqa: E402, F401  (hooks: time limits)
