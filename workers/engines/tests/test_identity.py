"""Engine identities (`vint_engines/identity.py`): what a task's reuse key says about the code.

The behaviour that matters is checked on a copy of the package: an edit to one stage's code changes
that stage's identity and only the identities of stages that import it.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

from vint_engines import identity

ENGINES = Path(__file__).resolve().parents[1]
REPO = ENGINES.parents[1]


def copy_checkout(dest: Path) -> Path:
    """The engines package, its lock and the catalog, laid out as in the repository."""
    engines = dest / "workers" / "engines"
    shutil.copytree(
        ENGINES / "vint_engines",
        engines / "vint_engines",
        ignore=shutil.ignore_patterns("__pycache__"),
    )
    shutil.copy(ENGINES / "requirements.lock", engines / "requirements.lock")
    shutil.copytree(REPO / "catalog", dest / "catalog")
    return engines


def identities_of(engines: Path) -> dict[str, str]:
    env = {**os.environ, "PYTHONPATH": str(engines)}
    out = subprocess.run(
        [sys.executable, "-m", "vint_engines", "identity"],
        env=env,
        cwd=engines,
        capture_output=True,
        text=True,
        check=True,
    )
    return {stage: entry["identity"] for stage, entry in json.loads(out.stdout).items()}


def test_each_stage_covers_its_engine_and_what_it_imports() -> None:
    noise = identity.stage_files("noise")
    assert "vint_engines/noise/engine.py" in noise
    assert "vint_engines/noise/model.py" in noise
    assert "vint_engines/protocol.py" in noise
    # The noise engine undistorts with the render package's lens model: that file is in...
    assert "vint_engines/render/lens.py" in noise
    # ... and Blender's scene code is not.
    assert "vint_engines/render/engine.py" not in noise
    assert not any(name.startswith("catalog/") for name in noise)
    grasp = identity.stage_files("grasp")
    assert "vint_engines/grasp/hands/trx3.py" in grasp
    assert "catalog/objects.toml" in grasp and "catalog/hands/trx3/taxels.csv" in grasp
    assert "vint_engines/contract.schema.json" in grasp
    assert not any(name.startswith("vint_engines/noise/") for name in grasp)


def test_identities_are_stable_and_name_the_pinned_libraries() -> None:
    first = identity.identities()
    assert first == identity.identities()
    assert set(first) == set(identity.STAGES)
    libraries = first["render"]["libraries"]
    assert isinstance(libraries, dict)
    assert libraries["bpy"] != "absent" and libraries["mujoco"] != "absent"
    assert len({entry["identity"] for entry in first.values()}) == 3


def test_an_edit_changes_only_the_identities_of_stages_that_import_it(tmp_path: Path) -> None:
    engines = copy_checkout(tmp_path)
    before = identities_of(engines)
    assert before == {stage: entry["identity"] for stage, entry in identity.identities().items()}

    model = engines / "vint_engines" / "noise" / "model.py"
    model.write_text(model.read_text() + "\n# a changed noise model\n")
    after_noise = identities_of(engines)
    assert after_noise["noise"] != before["noise"]
    assert after_noise["render"] == before["render"] and after_noise["grasp"] == before["grasp"]

    lens = engines / "vint_engines" / "render" / "lens.py"
    lens.write_text(lens.read_text() + "\n# a changed lens model\n")
    after_lens = identities_of(engines)
    assert after_lens["render"] != after_noise["render"]  # render draws with it
    assert after_lens["noise"] != after_noise["noise"]  # noise undistorts with it
    assert after_lens["grasp"] == before["grasp"]

    objects = tmp_path / "catalog" / "objects.toml"
    objects.write_text(objects.read_text() + "\n# a changed catalog\n")
    after_catalog = identities_of(engines)
    assert after_catalog["grasp"] != before["grasp"]
    assert after_catalog["noise"] == after_lens["noise"]
