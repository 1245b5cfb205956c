"""The engine's memory limit (`vint_engines/memory.py`): with `VINT_ENGINE_MEMORY_LIMIT_MIB` set, a
task that allocates beyond it fails inside the engine — not retryable, naming the variable and the
limit — and the engine serves on; a value that breaks the rule stops the engine before its hello.
Driven through real noise engines (the cheapest to start: ~180 MiB of data memory at its hello,
so 600 MiB leaves it room) with a depth map whose 100-byte file declares 1.5 GiB."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import numpy.lib.format
import pytest
from conftest import new_dir

from vint_engines.memory import LIMIT_VARIABLE, LimitError, exceeded, limit_mib
from vint_engines.protocol import TaskRequest, TaskResult, run_task

LIMIT_MIB = 600
NOISE_PARAMS = {"noise": {"materials": False}, "views": [{"view_index": 0, "seed": 24680}]}


def write_view(directory: Path, shape: tuple[int, int], *, declared_only: bool = False) -> list[Path]:
    """A view's depth map and camera record; `declared_only`: a header declaring `shape` and no
    data (np.load allocates what the header declares before it reads)."""
    depth = directory / "v00_depth.npy"
    if declared_only:
        with depth.open("wb") as file:
            header = {"descr": "<f4", "fortran_order": False, "shape": shape}
            numpy.lib.format.write_array_header_1_0(file, header)
    else:
        np.save(depth, np.full(shape, 0.6, np.float32))
    camera = directory / "v00_camera.json"
    height, width = shape
    intrinsics = [[8.0, 0, (width - 1) / 2], [0, 8.0, (height - 1) / 2], [0, 0, 1]]
    camera.write_text(json.dumps({"K": intrinsics, "width": width, "height": height}))
    return [depth, camera]


def test_a_task_beyond_the_limit_fails_not_retryable_naming_it(spawn_engine, tmp_path: Path) -> None:
    engine = spawn_engine("noise", {LIMIT_VARIABLE: str(LIMIT_MIB)})
    assert engine.receive() is not None, engine.stderr_tail()
    huge = write_view(new_dir(tmp_path, "huge"), (20_000, 20_000), declared_only=True)
    assert huge[0].stat().st_size < 200
    reply = engine.task("huge", NOISE_PARAMS, new_dir(tmp_path, "huge_out"), huge)
    assert reply["ok"] is False and reply["retryable"] is False, reply
    assert f"{LIMIT_VARIABLE}={LIMIT_MIB}, i.e. {LIMIT_MIB} MiB" in reply["error"], reply["error"]
    assert "MemoryError" in reply["error"] and "a retry would fail the same way" in reply["error"]

    reply = engine.task("small", NOISE_PARAMS, new_dir(tmp_path, "small_out"), write_view(tmp_path, (8, 8)))
    assert reply["ok"] is True, reply  # the engine serves on
    assert engine.shutdown() == 0


@pytest.mark.parametrize("value", ["abc", "0", "-5", "1.5", " 600", "", "²", str(1 << 40)])
def test_an_invalid_limit_stops_the_engine_before_its_hello(spawn_engine, value: str) -> None:
    engine = spawn_engine("noise", {LIMIT_VARIABLE: value})
    assert engine.receive() is None
    assert engine.proc.wait(30) == 2
    log = engine.stderr_tail()
    assert f"{LIMIT_VARIABLE}={value!r}: must be a whole number of MiB from 1 to" in log, log


def test_the_rule_and_the_message() -> None:
    assert limit_mib({}) is None
    assert limit_mib({LIMIT_VARIABLE: "2048"}) == 2048
    with pytest.raises(LimitError, match=r"VINT_ENGINE_MEMORY_LIMIT_MIB='0x10': must be a whole number"):
        limit_mib({LIMIT_VARIABLE: "0x10"})
    message = exceeded(512, MemoryError("Unable to allocate 2.00 GiB"))
    assert message.startswith("the task needs more memory than the engine may use (")
    assert "VINT_ENGINE_MEMORY_LIMIT_MIB=512, i.e. 512 MiB" in message and "2.00 GiB" in message


class Exhausted:
    """An engine whose every task runs out of memory."""

    def hello(self) -> dict[str, str]:
        return {}

    def run(self, task: TaskRequest) -> TaskResult:
        raise MemoryError("Unable to allocate 8.00 GiB")

    def close(self) -> None:
        pass


def test_a_memory_error_is_permanent_under_a_limit_and_retryable_without(tmp_path: Path) -> None:
    """Under the engine's limit the same task needs the same memory again; without one the node was
    short, and another time (or node) may do."""
    message = {"type": "task", "task_id": "t", "params": {}, "inputs": [], "out_dir": str(tmp_path)}
    limited = run_task("noise", Exhausted(), message, memory_limit_mib=700)
    assert limited["retryable"] is False and "VINT_ENGINE_MEMORY_LIMIT_MIB=700" in limited["error"]
    unlimited = run_task("noise", Exhausted(), message)
    assert unlimited["retryable"] is True and unlimited["error"].startswith("engine crashed: MemoryError")
