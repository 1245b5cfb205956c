"""The per-test time limit (`timeouts.py`): a hung test fails with its limit instead of hanging."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

HUNG = """
import subprocess, sys
import pytest

@pytest.mark.timeout(1)
def test_waits_on_a_child_that_never_answers():
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(3600)"], stdout=subprocess.PIPE)
    try:
        child.stdout.read()
    finally:
        child.kill()

def test_after_it_still_runs():
    assert True
"""


def test_a_hung_test_fails_with_its_limit_and_the_next_one_runs(tmp_path: Path) -> None:
    (tmp_path / "test_hung.py").write_text(HUNG)
    (tmp_path / "conftest.py").write_text(
        f"import sys\nsys.path.insert(0, {str(Path(__file__).parent)!r})\n"
        "from timeouts import pytest_configure, pytest_runtest_protocol  # noqa: F401\n"
    )
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=120,  # the limit under test ends it in about a second
        cwd=tmp_path,
    )
    assert done.returncode == 1, done.stdout + done.stderr
    assert "exceeded its time limit of 1 s" in done.stdout, done.stdout
    assert "1 failed, 1 passed" in done.stdout, done.stdout
