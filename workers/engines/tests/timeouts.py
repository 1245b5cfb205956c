"""A time limit on every test, so that a hung engine fails its test instead of hanging the suite.

Each test's whole run (set-up, call, tear-down) gets `DEFAULT_S` seconds, `VINT_PYTEST_TIMEOUT_S`
when set, or what its `@pytest.mark.timeout(seconds)` says. When the limit passes, SIGALRM raises
`TimeoutError` in the main thread, wherever it waits (an engine's reply, a subprocess), and the test
fails with the limit in its message. Registered by the conftest of each test directory."""

from __future__ import annotations

import os
import signal
from collections.abc import Iterator
from types import FrameType

import pytest

DEFAULT_S = 900.0


def limit_of(item: pytest.Item) -> float:
    marker = item.get_closest_marker("timeout")
    if marker is not None and marker.args:
        return float(marker.args[0])
    return float(os.environ.get("VINT_PYTEST_TIMEOUT_S", DEFAULT_S))


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "timeout(seconds): this test's time limit (set-up, call, tear-down)")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    limit = limit_of(item)

    def expire(signum: int, frame: FrameType | None) -> None:
        raise TimeoutError(f"{item.nodeid} exceeded its time limit of {limit:g} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, limit)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
