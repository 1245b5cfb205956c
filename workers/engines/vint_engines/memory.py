"""The engine process's own memory limit: `VINT_ENGINE_MEMORY_LIMIT_MIB`.

An engine parses users' files; one that makes it allocate without bound (a mesh, an image, a depth
map that declares more than it holds) must fail its task, not take the node's memory with it.
The worker sets the variable; `serve` applies it with `setrlimit(RLIMIT_DATA)` before the stage's
libraries are imported, so every later allocation beyond it — Python's, numpy's, a C library's
`malloc` — fails inside the engine: Python raises `MemoryError`, which the serve loop answers as a
task failure naming the variable and the limit (`exceeded`). RLIMIT_DATA counts the process's
private writable memory (heap and anonymous mappings, Linux ≥ 4.7), allocated whether or not yet
touched: size it from `VmData` in `/proc/PID/status`, not from the resident set. Unset: no limit.
"""

from __future__ import annotations

import resource
from collections.abc import Mapping

LIMIT_VARIABLE = "VINT_ENGINE_MEMORY_LIMIT_MIB"
MAX_LIMIT_MIB = 1 << 30  # 1 PiB: beyond any node; keeps `mib << 20` inside the kernel's rlim_t


class LimitError(ValueError):
    """The variable's value breaks its rule; the engine cannot start."""


def limit_mib(environ: Mapping[str, str]) -> int | None:
    """The limit the environment asks for, in MiB; None when the variable is unset. LimitError
    naming the variable, the value and the rule otherwise."""
    raw = environ.get(LIMIT_VARIABLE)
    if raw is None:
        return None
    if not (raw.isascii() and raw.isdigit()) or not 1 <= int(raw) <= MAX_LIMIT_MIB:
        raise LimitError(
            f"{LIMIT_VARIABLE}={raw!r}: must be a whole number of MiB from 1 to {MAX_LIMIT_MIB} "
            "(unset it for no limit)"
        )
    return int(raw)


def apply_limit(mib: int) -> None:
    """Cap the process's data memory at `mib` MiB (soft and hard: a library cannot lift it).
    LimitError when the process may not set it (a hard limit below it already)."""
    try:
        resource.setrlimit(resource.RLIMIT_DATA, (mib << 20, mib << 20))
    except (ValueError, OSError) as exc:
        _, hard = resource.getrlimit(resource.RLIMIT_DATA)
        held = "unlimited" if hard == resource.RLIM_INFINITY else f"{hard >> 20} MiB"
        raise LimitError(f"{LIMIT_VARIABLE}={mib}: cannot set it (the hard limit is {held}): {exc}") from exc


def exceeded(mib: int, exc: MemoryError) -> str:
    """A task's failure when it ran out of the engine's memory: not retryable, since the same task
    needs the same memory again."""
    detail = str(exc) or "an allocation failed"
    return (
        f"the task needs more memory than the engine may use ({LIMIT_VARIABLE}={mib}, i.e. {mib} MiB): "
        f"{type(exc).__name__}: {detail}; a retry would fail the same way: make the task smaller "
        f"(fewer or smaller views, a smaller input) or raise {LIMIT_VARIABLE}"
    )
