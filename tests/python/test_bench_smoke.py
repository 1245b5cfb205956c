"""Every bench under benches/ runs in its smoke mode, so that none can rot unnoticed.

A smoke is the bench's own code path at its smallest sizes (seconds, not a figure): `--smoke` for
the Python scripts, `VINT_BENCH_SMOKE=1` for the shell scripts, 64 tasks and one run of the dev
build for the coordinator bench (benches/README.md). Each must exit 0 and print a line of its
normal report; in CI (CI=true: a fresh clone that nobody edits meanwhile) it must also leave `git
status` as it found it, since a smoke writes only to temporary directories (elsewhere someone may be
editing the tree while the smokes run). A file under benches/ that SMOKES does not know fails
`test_every_bench_has_a_smoke`: a new bench comes with its smoke.

scripts/test.sh runs this file after the build: the smokes start the target/debug binaries, and
the dispatch, queue and coordinator smokes need the Postgres of VINT_TEST_POSTGRES_URL. Nothing is
skipped: a smoke that cannot run fails.
"""

from __future__ import annotations

import importlib.util
import os
import signal
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType

import pytest

ROOT = Path(__file__).resolve().parents[2]
BENCHES = ROOT / "benches"
ENGINES = ROOT / "workers" / "engines"
# Files under benches/ that are not benches.
NOT_BENCHES = {
    "README.md": "how to run the benches",
    "smoke.toml": "the dataset the smokes run",
}
TIMEOUT_S = 300


@dataclass(frozen=True)
class Smoke:
    """How one bench runs its smoke, and a piece of its normal report the output must hold."""

    command: list[str]
    expect: str
    env: dict[str, str] = field(default_factory=dict)
    # Other files under benches/ that this smoke runs (and so keeps from rotting).
    covers: tuple[str, ...] = ()


def python_smoke(script: str, expect: str) -> Smoke:
    return Smoke([sys.executable, f"benches/{script}", "--smoke"], expect, {"PYTHONPATH": str(ENGINES)})


def shell_smoke(script: str, expect: str, covers: tuple[str, ...] = ()) -> Smoke:
    return Smoke(["bash", f"benches/{script}"], expect, {"VINT_BENCH_SMOKE": "1"}, covers)


SMOKES: dict[str, Smoke] = {
    "chaos.py": python_smoke("chaos.py", "rounds: 1, identical manifests: 1/1, passed: 1/1"),
    "coordinator.rs": Smoke(
        ["cargo", "bench", "--profile", "dev", "-p", "vint-tests", "--bench", "coordinator"],
        '"case":"sqlite/batch64"',
        {"VINT_BENCH_TASKS": "64", "VINT_BENCH_REPEATS": "1"},
    ),
    "depth_png.py": python_smoke("depth_png.py", "largest decode error: "),
    # dispatch.sh ends with dispatch_report.py on its run, which prints the lineage line.
    "dispatch.sh": shell_smoke(
        "dispatch.sh", "lineage: all 5 sampled samples verified end to end", ("dispatch_report.py",)
    ),
    "export_formats.py": python_smoke("export_formats.py", "| smokex2 | 2 | bop |"),
    "grasp_procedure.py": python_smoke("grasp_procedure.py", "after: accepted"),
    "grasp_throughput.py": python_smoke("grasp_throughput.py", '{"trials_per_task": 1, "repetitions": 1,'),
    "grasp_types.py": python_smoke("grasp_types.py", 'all {"trials": 6,'),
    "noise_cost.py": python_smoke("noise_cost.py", "| 128×128 | new, all pieces |"),
    "queue.sh": shell_smoke("queue.sh", "coordinator/postgres/batch64: / ceiling = n/a"),
    "render_textures.py": python_smoke("render_textures.py", '{"size": 16, "samples": 1, "views": 1,'),
    "render_warm_cold.py": python_smoke("render_warm_cold.py", 'memory: {"views": 2,'),
    "reuse_rerun.py": python_smoke("reuse_rerun.py", "| re-run, noise changed |"),
    "scene_cost.py": python_smoke("scene_cost.py", "| variant | median s / view | × bare |"),
    "tiny_overhead.sh": shell_smoke("tiny_overhead.sh", '{"bench": "tiny_overhead", "runs": 1,'),
    "touch_margin.py": python_smoke("touch_margin.py", "| 0.5 |"),
    "touch_study.py": python_smoke("touch_study.py", '{"captures": '),
}


def repository_changes() -> set[str]:
    """`git status` lines: files changed or added outside .gitignore."""
    done = subprocess.run(
        ["git", "status", "--porcelain", "--untracked-files=all"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    )
    return set(done.stdout.splitlines())


def run(smoke: Smoke) -> tuple[int, str]:
    """Exit status and output (stdout and stderr together) of a smoke; past TIMEOUT_S its whole
    process group is killed and the smoke fails."""
    process = subprocess.Popen(
        smoke.command,
        cwd=ROOT,
        env={**os.environ, **smoke.env},
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    try:
        output, _ = process.communicate(timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        output, _ = process.communicate()
        pytest.fail(f"{' '.join(smoke.command)} ran past {TIMEOUT_S} s:\n{output[-4000:]}")
    return process.returncode, output


def test_every_bench_has_a_smoke() -> None:
    present = {path.name for path in BENCHES.iterdir() if path.is_file()} - NOT_BENCHES.keys()
    known = set(SMOKES) | {name for smoke in SMOKES.values() for name in smoke.covers}
    assert not present - known, f"benches without a smoke: add them to SMOKES in {Path(__file__).name}"
    assert not known - present, f"smokes of benches that are gone: remove them from {Path(__file__).name}"


@pytest.mark.parametrize("bench", sorted(SMOKES))
def test_smoke(bench: str) -> None:
    smoke = SMOKES[bench]
    in_ci = os.environ.get("CI") == "true"
    before = repository_changes() if in_ci else set()
    status, output = run(smoke)
    assert status == 0, f"{' '.join(smoke.command)} exited with {status}:\n{output[-4000:]}"
    assert smoke.expect in output, f"no {smoke.expect!r} in the output of {bench}:\n{output[-4000:]}"
    if in_ci:
        written = sorted(repository_changes() - before)
        assert not written, f"{bench}'s smoke wrote into the repository: {written}"


def load_bench(script: str) -> ModuleType:
    sys.path.insert(0, str(ENGINES))
    spec = importlib.util.spec_from_file_location(script.removesuffix(".py"), BENCHES / script)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_grasp_throughput_derives_trial_seeds_as_the_planner_does() -> None:
    """The value services/core/src/seed.rs pins for `grasp_trial(0, "tomato_soup_can", "trx3", 0)`,
    and seeds within the contract's bound of 2^53 - 1."""
    bench = load_bench("grasp_throughput.py")
    assert bench.trial_seed(0, "tomato_soup_can", "trx3", 0) == 2_795_351_020_481_970
    assert all(0 <= bench.trial_seed(2**64 - 1, "mug", "allegro", i) < 2**53 for i in range(1000))
