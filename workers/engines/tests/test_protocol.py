"""The engine side of PROTOCOL.md, driven through real engine processes (the noise stage: it is the
cheapest to start) plus the frame codec on its own."""

from __future__ import annotations

import errno
import io
import json
import os
import struct
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from conftest import ENGINES_DIR, new_dir

from vint_engines.protocol import (
    MAX_FRAME_BYTES,
    BadInput,
    InputRef,
    ProtocolError,
    TaskRequest,
    TaskResult,
    read_frame,
    run_task,
    write_frame,
)

NOISE_PARAMS = {"noise": {"materials": False}, "views": [{"view_index": 0, "seed": 24680}]}


def write_depth(directory: Path) -> list[Path]:
    """A view's depth and camera record (materials off: no segmentation needed)."""
    path = directory / "v00_depth.npy"
    np.save(path, np.full((8, 8), 0.6, np.float32))
    camera = directory / "v00_camera.json"
    camera.write_text(json.dumps({"K": [[8.0, 0, 3.5], [0, 8.0, 3.5], [0, 0, 1]], "width": 8, "height": 8}))
    return [path, camera]


def test_frames_round_trip_through_the_codec() -> None:
    stream = io.BytesIO()
    messages = [{"type": "hello", "n": 1}, {"type": "task", "text": "ünïcode", "list": [1.5, None]}]
    for message in messages:
        write_frame(stream, message)
    stream.seek(0)
    assert [read_frame(stream), read_frame(stream)] == messages
    assert read_frame(stream) is None


def test_codec_rejects_oversized_and_torn_frames() -> None:
    with pytest.raises(ProtocolError, match="exceeds"):
        read_frame(io.BytesIO(struct.pack(">I", MAX_FRAME_BYTES + 1)))
    with pytest.raises(ProtocolError, match="EOF after"):
        read_frame(io.BytesIO(struct.pack(">I", 10) + b"{}"))
    with pytest.raises(ProtocolError, match="not an object"):
        read_frame(io.BytesIO(struct.pack(">I", 2) + b"[]"))


def test_engine_says_hello_runs_a_task_and_exits_zero_on_shutdown(spawn_engine, tmp_path: Path) -> None:
    engine = spawn_engine("noise")
    hello = engine.receive()
    assert hello is not None, engine.stderr_tail()
    assert hello["type"] == "hello" and hello["stage"] == "noise"
    assert hello["engine"]["name"] == "vint-noise" and hello["engine"]["version"]
    assert {"python", "numpy", "opencv"} <= set(hello["engine"]["libs"])

    out_dir = new_dir(tmp_path, "out")
    reply = engine.task("t-1", NOISE_PARAMS, out_dir, write_depth(new_dir(tmp_path, "in")))
    assert reply["ok"] is True, reply
    assert [o["name"] for o in reply["outputs"]] == ["v00_depth_noisy.png"]
    assert reply["outputs"][0]["media_type"] == "image/png"
    assert Path(reply["outputs"][0]["path"]).parent == out_dir
    assert reply["metrics"]["engine_ms"] > 0
    assert engine.shutdown() == 0


def test_the_noise_engine_reads_a_png_depth_as_the_float_depth_it_holds(tmp_path: Path) -> None:
    """0.6 m is a whole number of 0.1 mm steps: the PNG holds it exactly, so the noise is the same."""
    from vint_engines import depth_file
    from vint_engines.noise.engine import NoiseEngine

    floats = write_depth(new_dir(tmp_path, "npy"))
    pngs = new_dir(tmp_path, "png")
    depth_file.write(pngs / "v00_depth", np.full((8, 8), 0.6, np.float32), "png")
    (pngs / "v00_camera.json").write_text(floats[1].read_text())
    noisy = {}
    for name, files in (("npy", floats), ("png", [pngs / "v00_depth.png", pngs / "v00_camera.json"])):
        inputs = tuple(InputRef(path.name, "render/x", path) for path in files)
        out = new_dir(tmp_path, f"out_{name}")
        NoiseEngine().run(TaskRequest(name, NOISE_PARAMS, inputs, out))
        noisy[name] = depth_file.read(out / "v00_depth_noisy.png")
    assert np.array_equal(noisy["npy"], noisy["png"])


def test_the_noise_engine_stores_noisy_depth_as_the_task_says(tmp_path: Path) -> None:
    """`depth_format = "npy"` gives float32 metres; the default 16-bit PNG holds the same noisy
    depth to the nearest 0.1 mm step (read back here with OpenCV, not the engine's reader), with
    the same holes."""
    from vint_engines.noise.engine import NoiseEngine

    inputs = tuple(InputRef(path.name, "render/x", path) for path in write_depth(new_dir(tmp_path, "in")))
    npy, png = new_dir(tmp_path, "as_npy"), new_dir(tmp_path, "as_png")
    NoiseEngine().run(TaskRequest("npy", {**NOISE_PARAMS, "depth_format": "npy"}, inputs, npy))
    NoiseEngine().run(TaskRequest("png", NOISE_PARAMS, inputs, png))
    assert [p.name for p in npy.iterdir()] == ["v00_depth_noisy.npy"]
    assert [p.name for p in png.iterdir()] == ["v00_depth_noisy.png"]
    exact = np.load(npy / "v00_depth_noisy.npy").astype(np.float64)
    units = cv2.imread(str(png / "v00_depth_noisy.png"), cv2.IMREAD_UNCHANGED)
    assert units.dtype == np.uint16 and np.array_equal(units > 0, exact > 0)
    assert np.abs(units * 1e-4 - exact)[exact > 0].max() <= 0.5e-4 + 1e-9


def test_engine_exits_zero_on_eof(spawn_engine) -> None:
    engine = spawn_engine("noise")
    assert engine.receive() is not None
    engine.proc.stdin.close()
    assert engine.proc.wait(30) == 0


def test_impossible_task_fails_without_retry_and_engine_keeps_serving(spawn_engine, tmp_path: Path) -> None:
    engine = spawn_engine("noise")
    assert engine.receive() is not None
    bad = engine.task("t-bad", {"views": []}, new_dir(tmp_path, "bad"))
    assert bad["ok"] is False and bad["retryable"] is False and "views" in bad["error"]
    missing = engine.task("t-missing", NOISE_PARAMS, new_dir(tmp_path, "missing"))
    assert missing["ok"] is False and missing["retryable"] is False and "v00_depth.npy" in missing["error"]
    good = engine.task(
        "t-good", NOISE_PARAMS, new_dir(tmp_path, "good"), write_depth(new_dir(tmp_path, "in"))
    )
    assert good["ok"] is True
    assert engine.shutdown() == 0


def test_crash_mid_task_gives_eof_and_no_result(spawn_engine, tmp_path: Path) -> None:
    engine = spawn_engine("noise")
    assert engine.receive() is not None
    fifo = new_dir(tmp_path, "in") / "v00_depth.npy"
    os.mkfifo(fifo)
    engine.send(
        {
            "type": "task",
            "task_id": "t-crash",
            "params": NOISE_PARAMS,
            "inputs": [{"name": fifo.name, "task_key": "render/x", "path": str(fifo)}],
            "out_dir": str(new_dir(tmp_path, "out")),
        }
    )
    writer = open_fifo_writer_once_engine_reads(fifo)  # the engine is now blocked inside the task
    try:
        engine.proc.kill()
        assert engine.receive() is None
        assert engine.proc.wait(10) != 0
    finally:
        os.close(writer)


def test_oversized_frame_is_a_crash_not_a_result(spawn_engine) -> None:
    engine = spawn_engine("noise")
    assert engine.receive() is not None
    engine.proc.stdin.write(struct.pack(">I", MAX_FRAME_BYTES + 1))
    engine.proc.stdin.flush()
    assert engine.receive() is None
    assert engine.proc.wait(10) != 0


def test_unknown_stage_exits_2() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "vint_engines", "serve", "--stage", "paint"],
        env={**os.environ, "PYTHONPATH": str(ENGINES_DIR)},
        capture_output=True,
        timeout=30,
    )
    assert done.returncode == 2
    assert b"invalid choice" in done.stderr


def open_fifo_writer_once_engine_reads(fifo: Path, timeout: float = 20.0) -> int:
    """Open the FIFO for writing; this succeeds only once the engine has it open for reading."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            return os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
        except OSError as exc:
            if exc.errno != errno.ENXIO or time.monotonic() > deadline:
                raise
            time.sleep(0.02)


class EngineWithABug:
    """Test double: an engine whose code fails the way a bug does (a KeyError), whatever the task."""

    def hello(self) -> dict[str, Any]:
        return {"name": "engine-with-a-bug", "version": "0", "libs": {}}

    def run(self, task: TaskRequest) -> TaskResult:
        return {}["views"]  # type: ignore[no-any-return]

    def close(self) -> None:
        pass


class EngineBreakingItsContract(EngineWithABug):
    """Test double: an engine that answers a result of the wrong shape for its stage."""

    def run(self, task: TaskRequest) -> TaskResult:
        return TaskResult(result={"views": "all of them"})


def task_message(out_dir: Path) -> dict[str, Any]:
    return {"type": "task", "task_id": "t-1", "params": NOISE_PARAMS, "inputs": [], "out_dir": str(out_dir)}


def test_an_engine_bug_is_retryable_and_says_where_it_happened(tmp_path: Path) -> None:
    reply = run_task("noise", EngineWithABug(), task_message(tmp_path))
    assert reply["ok"] is False and reply["retryable"] is True, reply
    assert (
        "KeyError" in reply["error"] and "test_protocol.py" in reply["error"] and "in run" in reply["error"]
    )


def test_a_result_that_breaks_the_stage_contract_is_never_reported_as_success(tmp_path: Path) -> None:
    reply = run_task("noise", EngineBreakingItsContract(), task_message(tmp_path))
    assert reply["ok"] is False and reply["retryable"] is True, reply
    assert "result.views" in reply["error"], reply["error"]


def test_parameters_outside_the_contract_are_bad_input_naming_field_value_and_bounds() -> None:
    from vint_engines.noise.engine import parse_params

    params = {"noise": {"flying_invalid_share": 1.5}, "views": [{"view_index": 0, "seed": 1}]}
    with pytest.raises(
        BadInput, match=r"^params\.noise\.flying_invalid_share: 1\.5 is outside \[0\.0, 1\.0\]$"
    ):
        parse_params(params)
