"""Blender's own thread pool, sized to the render's threads while Blender starts.

A render is one Cycles session on `render_threads` threads, but Blender does work of its own around
it — evaluating the scene's objects and meshes, loading images — on its task pool (oneTBB), which is
sized once, at its first use, from the CPUs the process may run on: every core by default. That
work is not always the same bits from one process to the next: replaying tiny.toml's render tasks in
one engine (mug/trx3, mustard/trx3, then tomato_soup_can/allegro g000001) made 14 pixels of the
can's six views differ in their float radiance from a fresh engine rendering the can alone (by up
to 0.5 %: a path took another branch), and differ again between two such replays; the same
histories on one CPU (`taskset -c 0`) gave the fresh engine's image every time. A dataset must be
the same bytes for a spec whatever its workers rendered before. (The mechanism, found later: the
pool's threads moved where Blender's allocations landed, and that set the face order of the hand's
spheres, which `meshes.py` now fixes; the replay matches without the narrowing since. It stays, so
that Blender's work around a render is single-threaded by construction, as the render is.)

So while the engine starts Blender and renders its warm-up view, the process may run on
`threads` CPUs only (the first ones it was allowed); the pool is then sized to `threads` for the
process's life, and the CPU mask is widened back — on every thread of the process, since a thread
started meanwhile (Cycles' session thread, which renders every later view) inherited the narrow
mask — so the operating system still moves the engine between cores and several engines on one
machine do not share one core. `threads` 0 (all cores, the documented non-deterministic choice)
leaves the mask alone, as do platforms without CPU masks.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def narrowed(threads: int) -> Iterator[None]:
    """Run the body on at most `threads` CPUs (the first of the process's mask), then restore the
    mask."""
    if threads <= 0 or not hasattr(os, "sched_getaffinity"):
        yield
        return
    allowed = sorted(os.sched_getaffinity(0))
    if len(allowed) <= threads:
        yield
        return
    narrow = allowed[:threads]
    os.sched_setaffinity(0, narrow)
    try:
        yield
    finally:
        widen(set(narrow), allowed)


def widen(narrow: set[int], allowed: list[int]) -> None:
    """Give every thread of this process still on the `narrow` CPU set the `allowed` ones (Linux
    reads a thread id where the call takes a pid)."""
    for tid in thread_ids():
        try:
            if os.sched_getaffinity(tid) == narrow:
                os.sched_setaffinity(tid, allowed)
        except ProcessLookupError:  # the thread ended meanwhile
            continue


def thread_ids() -> list[int]:
    """This process's thread ids (the main thread's alone where /proc is not there)."""
    try:
        return [int(name) for name in os.listdir("/proc/self/task")]
    except OSError:
        return [0]
