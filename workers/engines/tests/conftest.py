"""Test set-up: import `vint_engines` from this checkout and drive real engine processes."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

ENGINES_DIR = Path(__file__).resolve().parents[1]
if str(ENGINES_DIR) not in sys.path:
    sys.path.insert(0, str(ENGINES_DIR))

from timeouts import pytest_configure, pytest_runtest_protocol  # noqa: E402, F401  (hooks: time limits)


class EngineProcess:
    """A worker's view of an engine: a child process spoken to in frames (written independently of
    `vint_engines.protocol`, so the tests check the wire format rather than trust it)."""

    def __init__(self, stage: str, cwd: Path, env: Mapping[str, str] | None = None) -> None:
        env = {**os.environ, "PYTHONPATH": str(ENGINES_DIR), **(env or {})}
        # stderr goes to a file: a chatty engine (Blender) must never block on a full pipe.
        self.log_path = cwd / f"{stage}-{id(self)}.stderr"
        with self.log_path.open("wb") as log:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "vint_engines", "serve", "--stage", stage],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=log,
                cwd=cwd,
                env=env,
            )

    def send(self, message: dict[str, Any]) -> None:
        assert self.proc.stdin is not None
        payload = json.dumps(message).encode()
        self.proc.stdin.write(struct.pack(">I", len(payload)) + payload)
        self.proc.stdin.flush()

    def receive(self) -> dict[str, Any] | None:
        """The next frame, or None on EOF."""
        assert self.proc.stdout is not None
        header = self.proc.stdout.read(4)
        if not header:
            return None
        assert len(header) == 4, f"torn frame header: {header!r}"
        (length,) = struct.unpack(">I", header)
        payload = self.proc.stdout.read(length)
        assert len(payload) == length, "torn frame payload"
        message = json.loads(payload)
        assert isinstance(message, dict)
        return message

    def task(
        self,
        task_id: str,
        params: dict[str, Any],
        out_dir: Path,
        inputs: Sequence[Path | tuple[str, Path]] = (),
    ) -> dict:
        """Run one task; an input is a file (named by its file name) or a (name, file) pair, as the
        worker stages a user's file under its SHA-256."""
        named = [item if isinstance(item, tuple) else (item.name, item) for item in inputs]
        self.send(
            {
                "type": "task",
                "task_id": task_id,
                "params": params,
                "inputs": [{"name": n, "task_key": "test/" + n, "path": str(p)} for n, p in named],
                "out_dir": str(out_dir),
            }
        )
        reply = self.receive()
        assert reply is not None, f"engine died: {self.stderr_tail()}"
        assert reply["type"] == "result" and reply["task_id"] == task_id
        return reply

    def shutdown(self, timeout: float = 30.0) -> int:
        self.send({"type": "shutdown"})
        return self.proc.wait(timeout)

    def stderr_tail(self) -> str:
        return self.log_path.read_text(errors="replace")[-4000:]

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        for stream in (self.proc.stdin, self.proc.stdout):
            if stream is not None:
                stream.close()


@contextmanager
def started_engine(stage: str, cwd: Path) -> Iterator[EngineProcess]:
    """An engine process that has said hello; at the end it must shut down cleanly (exit 0)."""
    process = EngineProcess(stage, cwd)
    try:
        assert process.receive() is not None, process.stderr_tail()
        yield process
        assert process.shutdown(60) == 0
    finally:
        process.kill()


@pytest.fixture
def spawn_engine(tmp_path: Path) -> Iterator[Any]:
    """Start engines as the worker does; they are killed at the end of the test."""
    started: list[EngineProcess] = []

    def spawn(stage: str, env: Mapping[str, str] | None = None) -> EngineProcess:
        engine = EngineProcess(stage, tmp_path, env)
        started.append(engine)
        return engine

    yield spawn
    for engine in started:
        engine.kill()


def trx3_grasps(out: Path, obj: dict[str, Any], physics: dict[str, Any] | None = None) -> dict[str, Any]:
    """The real grasp engine's task of three trx3 trials (seeds 42–44) of `obj` (a catalog entry's
    JSON), run into `out`: its grasps.json."""
    from vint_engines.grasp.engine import GraspEngine
    from vint_engines.protocol import TaskRequest

    params: dict[str, Any] = {
        "object": obj,
        "hand": {"name": "trx3"},
        "trials": [{"grasp_index": i, "seed": 42 + i} for i in range(3)],
    }
    if physics is not None:
        params["physics"] = physics
    GraspEngine().run(TaskRequest("grasp", params, (), out))
    return json.loads((out / "grasps.json").read_text())


def new_dir(root: Path, name: str) -> Path:
    path = root / name
    path.mkdir(parents=True)
    return path


def read_grasps_with_touch(out_dir: Path) -> dict[str, Any]:
    """A grasp task's `grasps.json` with each accepted trial's full touch record from `touch.json`
    put back in place of its summary (after checking that the two agree)."""
    doc = json.loads((out_dir / "grasps.json").read_text())
    touch = json.loads((out_dir / "touch.json").read_text())
    assert touch["hand"] == doc["hand"]["name"] and touch["taxels"] == doc["hand"]["taxels"]
    assert touch["touch"] == doc["touch"]
    full = {entry.pop("grasp_index"): entry for entry in touch["trials"]}
    accepted = [trial for trial in doc["trials"] if trial["accepted"]]
    assert sorted(full) == sorted(trial["grasp_index"] for trial in accepted)
    for trial in accepted:
        record = full[trial["grasp_index"]]
        assert set(trial["touch"]) == {"contact_margin_m", "aging", "active_count"}
        assert {key: record[key] for key in trial["touch"]} == trial["touch"]
        trial["touch"] = record
    return doc
