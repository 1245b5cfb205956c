"""The render engine starts Blender on as many CPUs as it renders with (`render/cpus.py`), then
gives the process its whole CPU mask back: the narrowing holds inside and is undone after, also
when the body fails, reaches the threads started inside, and every thread of a started render
engine runs on every CPU it was allowed."""

from __future__ import annotations

import os
import threading
from pathlib import Path
from typing import Any

import pytest

from vint_engines.render.cpus import narrowed


def mask() -> set[int]:
    return os.sched_getaffinity(0)


def test_the_body_runs_on_the_first_allowed_cpus_and_the_mask_comes_back() -> None:
    allowed = mask()
    with narrowed(1):
        inside = mask()
    assert inside == {min(allowed)}  # on a one-CPU machine this is the whole mask
    assert mask() == allowed


def test_a_failing_body_still_gets_the_mask_back() -> None:
    allowed = mask()
    with pytest.raises(RuntimeError), narrowed(1):
        raise RuntimeError("boom")
    assert mask() == allowed


def test_all_cores_or_more_threads_than_cpus_change_nothing() -> None:
    allowed = mask()
    for threads in (0, len(allowed), len(allowed) + 3):
        with narrowed(threads):
            assert mask() == allowed, threads


def test_threads_started_inside_get_the_whole_mask_back() -> None:
    allowed = mask()
    seen: dict[str, set[int]] = {}
    started, finish = threading.Event(), threading.Event()

    def inside() -> None:
        seen["started"] = os.sched_getaffinity(0)
        started.set()
        finish.wait(10)
        seen["after"] = os.sched_getaffinity(0)

    with narrowed(1):
        thread = threading.Thread(target=inside)
        thread.start()
        started.wait(10)
    finish.set()
    thread.join(10)
    assert seen == {"started": {min(allowed)}, "after": allowed}


def test_every_thread_of_a_started_render_engine_runs_on_every_allowed_cpu(spawn_engine: Any) -> None:
    """Cycles' session thread, started with the warm-up render, renders every later view."""
    engine = spawn_engine("render")
    assert engine.receive() is not None, engine.stderr_tail()  # hello: Blender has started
    tasks = Path(f"/proc/{engine.proc.pid}/task")
    masks = {int(tid.name): os.sched_getaffinity(int(tid.name)) for tid in tasks.iterdir()}
    assert len(masks) > 1 and all(m == mask() for m in masks.values()), masks
    assert engine.shutdown(60) == 0
