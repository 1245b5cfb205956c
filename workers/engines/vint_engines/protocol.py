"""The engine side of PROTOCOL.md: frames, task/result messages and the serve loop.

Owns the process's original stdin/stdout. Engines never touch them: `claim_stdio` moves fd 1 to
stderr so that whatever a library prints (Blender prints from C) cannot corrupt a frame.

Engines report impossible tasks by raising `BadInput` (parameters that break the stage's contract,
`contract.py`, or inputs that make the task impossible: a malformed user file, say): not
retryable, because the same task would fail the same way. Any other exception — a `TypeError` or
`KeyError` is a bug in the engine, an `OSError` a full disk — is retryable, and its reply carries a
crash report (the exception and the innermost frames of its traceback). A `MemoryError` under the
engine's memory limit (`memory.py`) is not retryable either: the same task needs the same memory
again; the engine answers it and serves on (the failed allocation never happened, and the worker
replaces an engine whose resident memory grows past its own limit). Without a limit it is the
node that is short, and another time may do: retryable. A broken frame or an unexpected message is
a `ProtocolError`, which ends the process with a non-zero status: the worker then fails the task
in flight as retryable and starts a new engine.
"""

from __future__ import annotations

import json
import logging
import os
import struct
import sys
import time
import traceback
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, Protocol

from vint_engines import contract, memory
from vint_engines.errors import BadInput, ProtocolError  # engines import both from here

log = logging.getLogger("vint_engines")

MAX_FRAME_BYTES = 64 * 1024 * 1024
_LENGTH = struct.Struct(">I")

Json = dict[str, Any]


@dataclass(frozen=True)
class InputRef:
    """A file the worker staged for the task (an output of an earlier task)."""

    name: str
    task_key: str
    path: Path


@dataclass(frozen=True)
class TaskRequest:
    task_id: str
    params: Mapping[str, Any]
    inputs: tuple[InputRef, ...]
    out_dir: Path

    def input_path(self, name: str) -> Path:
        """The path of the input called `name`; BadInput when the worker did not stage it."""
        for ref in self.inputs:
            if ref.name == name:
                return ref.path
        raise BadInput(f"input {name!r} is missing (have {[ref.name for ref in self.inputs]})")


@dataclass(frozen=True)
class OutputFile:
    name: str
    path: Path
    media_type: str

    def to_json(self) -> Json:
        return {"name": self.name, "path": str(self.path), "media_type": self.media_type}


@dataclass
class TaskResult:
    """What an engine answers for a task: its files, its result in the stage contract's type
    (`contract.schema.json`, `stages.<stage>.result`; the planner reads it) and its metrics
    (timings and counts for people and benchmarks)."""

    outputs: list[OutputFile] = field(default_factory=list)
    result: dict[str, Any] = field(default_factory=dict)
    metrics: dict[str, Any] = field(default_factory=dict)

    def add(self, path: Path, media_type: str) -> None:
        """Record a file the engine wrote into out_dir; its name is the file name."""
        self.outputs.append(OutputFile(path.name, path, media_type))


class Engine(Protocol):
    """A stage's engine: built once (libraries imported, scene ready), then runs many tasks."""

    def hello(self) -> Json:
        """The `engine` object of the hello message: name, version, libs."""
        ...

    def run(self, task: TaskRequest) -> TaskResult:
        """Run one task, writing outputs into task.out_dir. Raise BadInput for impossible tasks."""
        ...

    def close(self) -> None:
        """Release what the engine holds (scratch files); called once before the process exits."""
        ...


# ---------------------------------------------------------------------------------------------
# Frames


def read_frame(stream: BinaryIO) -> Json | None:
    """The next message, or None on a clean EOF (between frames)."""
    header = _read_exact(stream, _LENGTH.size, eof_ok=True)
    if header is None:
        return None
    (length,) = _LENGTH.unpack(header)
    if length > MAX_FRAME_BYTES:
        raise ProtocolError(f"incoming frame of {length} bytes exceeds {MAX_FRAME_BYTES}")
    payload = _read_exact(stream, length, eof_ok=False) or b""
    try:
        message = json.loads(payload.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ProtocolError(f"frame is not UTF-8 JSON: {exc}") from exc
    if not isinstance(message, dict):
        raise ProtocolError(f"frame holds a JSON {type(message).__name__}, not an object")
    return message


def write_frame(stream: BinaryIO, message: Json) -> None:
    payload = json.dumps(message, separators=(",", ":"), allow_nan=False).encode("utf-8")
    if len(payload) > MAX_FRAME_BYTES:
        raise ProtocolError(f"outgoing frame of {len(payload)} bytes exceeds {MAX_FRAME_BYTES}")
    stream.write(_LENGTH.pack(len(payload)) + payload)
    stream.flush()


def _read_exact(stream: BinaryIO, size: int, *, eof_ok: bool) -> bytes | None:
    chunks: list[bytes] = []
    remaining = size
    while remaining > 0:
        chunk = stream.read(remaining)
        if not chunk:
            if eof_ok and remaining == size:
                return None
            raise ProtocolError(f"EOF after {size - remaining} of {size} bytes of a frame")
        chunks.append(chunk)
        remaining -= len(chunk)
    return b"".join(chunks)


def claim_stdio() -> tuple[BinaryIO, BinaryIO]:
    """Take the original stdin/stdout for frames; point fd 1 at stderr and fd 0 at /dev/null."""
    sys.stdout.flush()
    frames_out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    frames_in = os.fdopen(os.dup(0), "rb")
    devnull = os.open(os.devnull, os.O_RDONLY)
    os.dup2(devnull, 0)
    os.close(devnull)
    return frames_in, frames_out


# ---------------------------------------------------------------------------------------------
# Serve loop


def serve(stage: str, make_engine: Callable[[], Engine], memory_limit_mib: int | None = None) -> int:
    """Run the protocol until shutdown or EOF (exit status 0); ProtocolError propagates.
    `memory_limit_mib` is the limit the process runs under (`memory.py`), for failure messages."""
    frames_in, frames_out = claim_stdio()
    started = time.perf_counter()
    engine = make_engine()
    try:
        hello = {"type": "hello", "stage": stage, "engine": engine.hello()}
        write_frame(frames_out, hello)
        log.info("ready in %.0f ms: %s", 1e3 * (time.perf_counter() - started), hello["engine"])
        while True:
            message = read_frame(frames_in)
            if message is None:
                log.info("EOF on stdin, exiting")
                return 0
            kind = message.get("type")
            if kind == "shutdown":
                log.info("shutdown requested, exiting")
                return 0
            if kind != "task":
                raise ProtocolError(f"unexpected message type {kind!r}")
            write_frame(frames_out, run_task(stage, engine, message, memory_limit_mib))
    finally:
        engine.close()


def run_task(stage: str, engine: Engine, message: Json, memory_limit_mib: int | None = None) -> Json:
    """Run one task message and build its result message; never raises for task failures."""
    task_id = message.get("task_id")
    if not isinstance(task_id, str) or not task_id:
        raise ProtocolError(f"task message without a task_id: {sorted(message)}")
    started = time.perf_counter()
    try:
        task = parse_task(message)
        result = engine.run(task)
        outputs = [output.to_json() for output in checked_outputs(task, result)]
        contract.check_result(stage, result.result)
        metrics = {"engine_ms": round(1e3 * (time.perf_counter() - started), 3), **result.metrics}
        reply = {
            "type": "result",
            "task_id": task_id,
            "ok": True,
            "outputs": outputs,
            "result": result.result,
            "metrics": metrics,
        }
        json.dumps(reply, allow_nan=False)  # fail here, as a task failure, rather than in write_frame
    except BadInput as exc:
        log.warning("task %s failed (not retryable): %s", task_id, exc)
        return failure(task_id, str(exc), retryable=False)
    except MemoryError as exc:
        if memory_limit_mib is None:
            log.exception("task %s failed (retryable): the node is short of memory", task_id)
            return failure(task_id, crash_report(exc), retryable=True)
        error = memory.exceeded(memory_limit_mib, exc)
        log.warning("task %s failed (not retryable): %s", task_id, error)
        return failure(task_id, error, retryable=False)
    except Exception as exc:
        log.exception("task %s failed (retryable): engine bug or transient trouble", task_id)
        return failure(task_id, crash_report(exc), retryable=True)
    log.info("task %s done in %.0f ms", task_id, metrics["engine_ms"])
    return reply


def crash_report(exc: BaseException, frames: int = 3) -> str:
    """The exception and where it was raised: its innermost `frames` frames, one line each."""
    stack = traceback.extract_tb(exc.__traceback__)[-frames:]
    where = " <- ".join(f"{Path(f.filename).name}:{f.lineno} in {f.name}" for f in reversed(stack))
    return f"engine crashed: {type(exc).__name__}: {exc} (at {where})"


def failure(task_id: str, error: str, *, retryable: bool) -> Json:
    return {"type": "result", "task_id": task_id, "ok": False, "retryable": retryable, "error": error}


def parse_task(message: Json) -> TaskRequest:
    params = message.get("params")
    if not isinstance(params, dict):
        raise BadInput("task.params: expected an object")
    raw_inputs = message.get("inputs", [])
    if not isinstance(raw_inputs, list):
        raise BadInput("task.inputs: expected a list")
    inputs = []
    for i, raw in enumerate(raw_inputs):
        if not isinstance(raw, dict) or not all(isinstance(raw.get(k), str) for k in ("name", "path")):
            raise BadInput(f"task.inputs[{i}]: expected {{name, task_key, path}}")
        inputs.append(InputRef(raw["name"], str(raw.get("task_key", "")), Path(raw["path"])))
    out_dir = message.get("out_dir")
    if not isinstance(out_dir, str) or not Path(out_dir).is_dir():
        raise BadInput(f"task.out_dir: {out_dir!r} is not an existing directory")
    return TaskRequest(message["task_id"], params, tuple(inputs), Path(out_dir))


def checked_outputs(task: TaskRequest, result: TaskResult) -> list[OutputFile]:
    """The result's outputs, after checking the contract: unique names, files inside out_dir."""
    out_dir = task.out_dir.resolve()
    names = [output.name for output in result.outputs]
    if len(set(names)) != len(names):
        raise RuntimeError(f"engine produced duplicate output names: {names}")
    for output in result.outputs:
        path = output.path.resolve()
        if path.parent != out_dir or not path.is_file():
            raise RuntimeError(f"engine output {output.name!r} is not a file in out_dir: {path}")
    return result.outputs
