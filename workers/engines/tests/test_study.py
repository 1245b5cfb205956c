"""The grasp physics study (`python -m vint_engines study grasp --quick`), run as a user would."""

from __future__ import annotations

import csv
import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ENGINES_DIR

from vint_engines.study.grasp import COARSEST, DEFAULT, QUICK_CONFIGS, REFERENCE
from vint_engines.study.report import SUMMARY_COLUMNS, TRIAL_COLUMNS

Rows = list[dict[str, str]]


def read_csv(path: Path) -> tuple[list[str], Rows]:
    with path.open(newline="", encoding="utf-8") as file:
        reader = csv.DictReader(file)
        return list(reader.fieldnames or []), list(reader)


@pytest.fixture(scope="module")
def quick_study(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("study")
    env = {**os.environ, "PYTHONPATH": str(ENGINES_DIR)}
    command = [sys.executable, "-m", "vint_engines", "study", "grasp", "--out", str(out), "--quick"]
    done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-4000:]
    return out


def test_quick_study_writes_its_csvs_plot_and_table(quick_study: Path) -> None:
    names = {"grasp_study.csv", "grasp_study_summary.csv", "grasp_study.png", "grasp_study.md"}
    assert names <= {p.name for p in quick_study.iterdir()}
    assert (quick_study / "grasp_study.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    table = (quick_study / "grasp_study.md").read_text(encoding="utf-8")
    assert "## Recommendation" in table and REFERENCE.name in table


def test_csvs_have_the_documented_columns_and_one_row_per_trial(quick_study: Path) -> None:
    columns, rows = read_csv(quick_study / "grasp_study.csv")
    assert columns == list(TRIAL_COLUMNS)
    seeds = {r["seed"] for r in rows}
    assert len(rows) == len(QUICK_CONFIGS) * len(seeds) and seeds
    summary_columns, summary = read_csv(quick_study / "grasp_study_summary.csv")
    assert summary_columns == list(SUMMARY_COLUMNS)
    assert [s["config"] for s in summary if s["hand"] == "all"] == [c.name for c in QUICK_CONFIGS]


def test_reference_has_zero_error_against_itself(quick_study: Path) -> None:
    _, rows = read_csv(quick_study / "grasp_study.csv")
    reference = [r for r in rows if r["config"] == REFERENCE.name]
    assert reference and any(r["accepted"] == "1" for r in reference)
    for r in reference:
        assert float(r["label_agrees"]) == 1.0
        if r["accepted"] == "1":
            assert float(r["pos_err_mm"]) == 0.0 and float(r["rot_err_deg"]) == 0.0
            assert float(r["taxel_iou"]) == 1.0


def test_coarser_timesteps_cost_less_and_do_not_beat_the_reference(quick_study: Path) -> None:
    _, summary = read_csv(quick_study / "grasp_study_summary.csv")
    by_name = {s["config"]: s for s in summary if s["hand"] == "all"}
    reference, coarsest = by_name[REFERENCE.name], by_name[COARSEST.name]
    # A 32× coarser timestep must take fewer physics steps per trial, whatever the acceptance (the
    # time it saves is measured, not asserted: the study's wall_s and cpu_s columns).
    _, rows = read_csv(quick_study / "grasp_study.csv")

    def mean_steps(config: str) -> float:
        steps = [int(r["steps"]) for r in rows if r["config"] == config]
        assert steps and min(steps) > 0, config
        return sum(steps) / len(steps)

    assert mean_steps(coarsest["config"]) < mean_steps(reference["config"]) / 3
    # A coarse step that reproduced the reference exactly would mean the timestep never applied.
    assert float(coarsest["pos_err_mm_median"] or "inf") > 0.0
    assert float(by_name[DEFAULT.name]["label_agreement_pct"]) >= 50.0
