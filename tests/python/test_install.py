"""The two installs: README command 1 (`scripts/setup.sh`, which runs `scripts/setup-python.sh`) puts
in the engines' environment what running a dataset needs and nothing for tests only; the test
command adds the dev lock (`scripts/setup-python.sh --dev`).

`test_the_run_install_holds_no_test_only_package` runs the run install into a fresh virtual
environment (pip's cache makes it minutes, not the first download) and looks at what is there;
`test_every_product_import_is_pinned_in_the_runtime_lock` checks the other direction: whatever the
engines import on a product path (not their tests) comes from a package the runtime lock pins, so
the deployment image, which installs that lock alone, can run `vintctl stats` and `study` too.
"""

from __future__ import annotations

import ast
import importlib.metadata
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
ENGINES = ROOT / "workers" / "engines"
RUNTIME_LOCK = ENGINES / "requirements.lock"
DEV_LOCK = ENGINES / "requirements-dev.lock"

# Packages only the tests, lint, the deploy check and the loader example's test use.
TEST_ONLY = re.compile(
    r"^(torch|triton|nvidia-.*|cuda-.*|pytest|ruff|moto|boto3|botocore|flask|webdataset|wids|kubernetes-validate)$"
)


# Modules the bpy wheel puts on the path when `bpy` is imported (Blender's own), not distributions.
BPY_MODULES = {
    "addon_utils",
    "bl_math",
    "bmesh",
    "bpy_extras",
    "bpy_types",
    "freestyle",
    "gpu",
    "idprop",
    "mathutils",
}


def normalized(name: str) -> str:
    """A distribution name as pip compares them (PEP 503)."""
    return re.sub(r"[-_.]+", "-", name).lower()


def pinned(lock: Path) -> set[str]:
    """The distributions a lock pins (`name==version`, extras dropped)."""
    names = set()
    for line in lock.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            names.add(normalized(re.split(r"[\[=<>~!]", line, maxsplit=1)[0]))
    return names


def test_the_locks_split_run_from_test_and_pin_each_package_once() -> None:
    runtime, dev = pinned(RUNTIME_LOCK), pinned(DEV_LOCK)
    assert not {n for n in runtime if TEST_ONLY.match(n)}, "a test-only package is in the runtime lock"
    assert {"torch", "pytest", "webdataset", "wids"} <= dev
    assert {"bpy", "mujoco", "matplotlib"} <= runtime
    assert not runtime & dev, f"pinned in both locks: {sorted(runtime & dev)}"


def product_imports() -> set[str]:
    """Top-level modules imported by the engines' product code (not `tests/`), stdlib excluded."""
    found: set[str] = set()
    for path in (ENGINES / "vint_engines").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                found.update(alias.name.split(".")[0] for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                found.add(node.module.split(".")[0])
    return {m for m in found if m not in sys.stdlib_module_names and m not in {"vint_engines", "__future__"}}


def test_every_product_import_is_pinned_in_the_runtime_lock() -> None:
    providers = importlib.metadata.packages_distributions()
    runtime = pinned(RUNTIME_LOCK)
    imports = product_imports()
    assert {"bpy", "mujoco", "cv2", "numpy", "matplotlib"} <= imports, imports
    unpinned = {}
    for module in sorted(imports):
        dists = {"bpy"} if module in BPY_MODULES else {normalized(d) for d in providers.get(module, [])}
        if not dists & runtime:
            unpinned[module] = sorted(dists) or "no installed distribution"
    assert not unpinned, f"imported by the engines but not pinned in requirements.lock: {unpinned}"


def run_setup(env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    """README command 1's Python half: scripts/setup-python.sh, no arguments."""
    script = str(ROOT / "scripts" / "setup-python.sh")
    return subprocess.run(["bash", script], env=env, capture_output=True, text=True, check=False)


@pytest.mark.timeout(1200)
def test_the_run_install_holds_no_test_only_package(tmp_path: Path) -> None:
    venv = tmp_path / "venv"
    env = {**os.environ, "VINT_VENV": str(venv)}
    done = run_setup(env)
    assert done.returncode == 0, done.stderr[-4000:]
    assert "matplotlib" in done.stdout, "the run install imports what stats and study plot with"
    pip_list = [str(venv / "bin" / "python"), "-m", "pip", "list", "--format", "json"]
    listed = subprocess.run(pip_list, capture_output=True, text=True, check=True)
    installed = {normalized(p["name"]) for p in json.loads(listed.stdout)}
    assert "bpy" in installed and "mujoco" in installed
    test_only = sorted(n for n in installed if TEST_ONLY.match(n))
    assert not test_only, f"the run install holds test-only packages: {test_only}"
    unpinned = sorted(installed - {"pip"} - pinned(RUNTIME_LOCK))
    assert not unpinned, f"the run install holds what the runtime lock does not pin: {unpinned}"
    again = run_setup(env)
    assert again.returncode == 0 and "skipping it" in again.stderr, "a second run installs nothing"
