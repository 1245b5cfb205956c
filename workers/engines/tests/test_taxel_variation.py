"""Taxel variation (VinT-6D App. A.1.2: manufacturing deviations and aging): each hand instance's
taxels are moved in their surface's tangent plane by a seeded N(0, σ²) per axis, and each grasp
reads with an aging drawn from a range; both are recorded so a user can rebuild the sensor."""

from __future__ import annotations

import hashlib
import json
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import ENGINES_DIR, read_grasps_with_touch

from vint_engines.grasp.engine import GraspEngine
from vint_engines.grasp.hands import hand_dims
from vint_engines.grasp.hands.catalog import read_hand_catalog
from vint_engines.grasp.taxels import TaxelLayout, read_layout
from vint_engines.grasp.touch import TouchParams, taxel_gains, taxel_offsets, trial_aging
from vint_engines.protocol import TaskRequest

CATALOG = {
    entry["name"]: entry
    for entry in tomllib.loads((ENGINES_DIR.parents[1] / "catalog" / "objects.toml").read_text())["object"]
}
SEEDS = [1234567890123 + 7919 * i for i in range(4)]


def layout_of(hand: str) -> TaxelLayout:
    return read_layout(read_hand_catalog()[hand].taxels_path(), hand_dims(hand).link_names())


def grasp_params(seeds: list[int], **touch: Any) -> dict[str, Any]:
    return {
        "object": CATALOG["tomato_soup_can"],
        "hand": {"name": "trx3"},
        "trials": [{"grasp_index": i, "seed": seed} for i, seed in enumerate(seeds)],
        "physics": {"hold_s": 0.5, "grasp_type": "any"},
        "touch": {"gain_seed": 123, **touch},
    }


def run(engine: GraspEngine, params: dict[str, Any], out_dir: Path) -> dict[str, Any]:
    out_dir.mkdir(parents=True, exist_ok=True)
    engine.run(TaskRequest("t", params, (), out_dir))
    return read_grasps_with_touch(out_dir)


@pytest.fixture(scope="module")
def engine() -> GraspEngine:
    return GraspEngine()


def tangent_parts(offsets_m: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each offset's component along its taxel's normal, and its in-plane part."""
    along = (offsets_m * normals).sum(axis=1)
    return along, offsets_m - along[:, None] * normals


def test_offsets_are_fixed_by_the_hand_seed_and_leave_the_gains_alone() -> None:
    normals = layout_of("trx3").normals
    first, again, other = (taxel_offsets(normals, 3e-4, seed) for seed in (123, 123, 124))
    assert (first == again).all() and (first != other).any()
    assert first.dtype == np.int64 and first.shape == normals.shape
    # The gains draw from the seed's own stream, as before the deviations existed.
    expected = np.random.default_rng(123).lognormal(0.0, 0.1, len(normals))
    assert (taxel_gains(len(normals), 0.1, 123) == expected).all()
    assert (taxel_offsets(normals, 0.0, 123) == 0).all()


@pytest.mark.parametrize(("hand", "sigma"), [("trx3", 3e-4), ("allegro", 3e-4), ("allegro", 1e-3)])
def test_offsets_lie_in_the_tangent_plane_with_the_stated_spread(hand: str, sigma: float) -> None:
    """Per tangent axis the offsets have σ = position_sigma_m (so the in-plane distance has RMS
    σ·√2); none is along the normal beyond the micrometre rounding. With 600+ taxels the sample σ
    lies within 10 % of the true one far beyond 5 standard errors (≈ 2 % each)."""
    normals = layout_of(hand).normals
    offsets = taxel_offsets(normals, sigma, 99) * 1e-6
    along, plane = tangent_parts(offsets, normals)
    assert np.abs(along).max() <= 1.5e-6  # rounding to whole µm only
    per_axis = np.sqrt((plane**2).sum(axis=1).mean() / 2.0)
    assert per_axis == pytest.approx(sigma, rel=0.1)
    assert np.abs(plane.mean(axis=0)).max() < 5 * sigma / np.sqrt(len(normals))
    # Gaussian, not uniform or constant: the in-plane radius is Rayleigh, median σ·√(2 ln 2).
    radius = np.linalg.norm(plane, axis=1)
    assert np.median(radius) == pytest.approx(sigma * np.sqrt(2 * np.log(2)), rel=0.12)


def test_a_grasps_aging_is_drawn_from_its_range_by_the_trial_seed() -> None:
    drawn = [trial_aging((0.6, 0.9), seed) for seed in range(400)]
    assert all(0.6 <= a <= 0.9 for a in drawn)
    assert len(set(drawn)) == len(drawn)
    assert np.mean(drawn) == pytest.approx(0.75, abs=0.02)  # uniform: mean mid-range, ±4 s.e.
    assert trial_aging((0.6, 0.9), 17) == trial_aging((0.6, 0.9), 17)
    assert trial_aging((1.0, 1.0), 17) == 1.0 and trial_aging((0.3, 0.3), 5) == 0.3


def test_the_record_rebuilds_the_sensor_and_each_grasp_its_aging(engine: GraspEngine, tmp_path: Path) -> None:
    params = grasp_params(SEEDS, aging=[0.5, 0.9])
    doc = run(engine, params, tmp_path / "a")
    layout = layout_of("trx3")
    deviation = doc["hand"]["taxels"]["deviation"]
    accepted = [t for t in doc["trials"] if t["accepted"]]
    assert len(accepted) >= 2, [t["reason"] for t in doc["trials"]]
    agings = []
    for trial in accepted:
        touch = trial["touch"]
        offsets = np.array(touch["position_offsets_um"])
        assert (offsets == np.array(accepted[0]["touch"]["position_offsets_um"])).all()  # one sensor
        moved = TaxelLayout(layout.links, layout.positions + offsets * 1e-6, layout.normals, layout.regions)
        assert deviation["sha256"] == hashlib.sha256(moved.to_csv().encode()).hexdigest()
        assert 0.5 <= touch["aging"] <= 0.9 and touch["aging"] == trial_aging((0.5, 0.9), trial["seed"])
        agings.append(touch["aging"])
        # The readings follow the recorded aging: x = aging · f / f_half (exponent 1).
        gains = np.random.default_rng(123).lognormal(0.0, 0.1, len(layout))
        for taxel in touch["active"]:
            x = touch["aging"] * taxel["force_n"] / 10.0
            assert taxel["reading"] == pytest.approx(gains[taxel["taxel"]] * x / (1 + x), rel=1e-9)
    assert len(set(agings)) == len(agings)  # drawn per grasp
    assert deviation["position_sigma_m"] == 3e-4 and deviation["seed"] == 123
    grasps = json.loads((tmp_path / "a" / "grasps.json").read_text())
    assert {t["touch"]["aging"] for t in grasps["trials"] if t["accepted"]} == set(agings)


def test_same_parameters_give_byte_identical_records(engine: GraspEngine, tmp_path: Path) -> None:
    params = grasp_params(SEEDS[:2], aging=[0.5, 0.9])
    run(engine, params, tmp_path / "a")
    run(GraspEngine(), params, tmp_path / "b")
    for name in ("grasps.json", "touch.json"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name


def test_another_hand_instance_moves_the_taxels(engine: GraspEngine, tmp_path: Path) -> None:
    one = run(engine, grasp_params(SEEDS[:2]), tmp_path / "a")
    other = run(engine, grasp_params(SEEDS[:2], gain_seed=124), tmp_path / "b")
    exact = run(engine, grasp_params(SEEDS[:2], position_sigma_m=0.0), tmp_path / "c")
    assert one["hand"]["taxels"]["deviation"]["sha256"] != other["hand"]["taxels"]["deviation"]["sha256"]
    layout = layout_of("trx3")
    nominal = hashlib.sha256(layout.to_csv().encode()).hexdigest()
    assert exact["hand"]["taxels"]["deviation"]["sha256"] == nominal
    for trial in (t for t in exact["trials"] if t["accepted"]):
        assert not np.array(trial["touch"]["position_offsets_um"]).any()
    # The exact layout's recorded positions are the layout's own.
    params = TouchParams.parse({"position_sigma_m": 0.0})
    assert (taxel_offsets(layout.normals, params.position_sigma_m, params.gain_seed) == 0).all()
