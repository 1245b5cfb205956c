"""The engines are found by convention (`vint_engines/stages.py`): every stage of the contract with an
engine package has both functions the command line calls, and nothing else is taken for a stage."""

from __future__ import annotations

import json

import pytest

from vint_engines.stages import SCHEMA_FILE, engine_module, python_stages


def test_the_engine_stages_are_the_contracts_stages_with_an_engine_package() -> None:
    contract = set(json.loads(SCHEMA_FILE.read_text(encoding="utf-8"))["stages"])
    stages = python_stages()
    assert set(stages) <= contract
    assert set(stages) == {"grasp", "render", "noise"}, "package runs in Rust, not here"


@pytest.mark.parametrize("stage", python_stages())
def test_each_engine_module_has_the_conventional_functions(stage: str) -> None:
    module = engine_module(stage)
    assert callable(module.make_engine) and callable(module.parse_params)


def test_an_unknown_stage_is_refused_by_name() -> None:
    with pytest.raises(ValueError, match="unknown stage 'paint'"):
        engine_module("paint")
    with pytest.raises(ValueError, match="unknown stage 'package'"):
        engine_module("package")
