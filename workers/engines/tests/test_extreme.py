"""Stiff and extreme grasp trials: each ends in a valid accepted grasp or a clean rejection with a
reason — never a crash, a NaN or silently wrong data.

Every case runs both hands for a couple of short trials through the engine, then holds its output
to `assert_valid_or_rejected`: accepted grasps have finite unit-quaternion poses, held the object,
touch points within the sensing depth of the object's model mesh and a penetration below the
bound; rejected ones carry a reason; every trial records what the stability monitor saw.
"""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pytest
from conftest import ENGINES_DIR, new_dir, read_grasps_with_touch
from geometry import distance_to_mesh

from vint_engines.grasp.engine import GraspEngine
from vint_engines.grasp.hands import hand_dims
from vint_engines.grasp.hands.catalog import read_hand_catalog
from vint_engines.grasp.scene import build_scene
from vint_engines.grasp.taxels import TaxelLayout, parse_layout
from vint_engines.grasp.touch import Skin, TouchParams
from vint_engines.grasp.trial import Approach, Physics, run_trial
from vint_engines.objects import ObjectSpec, build_model
from vint_engines.poses import quat_to_matrix
from vint_engines.protocol import BadInput, TaskRequest

CATALOG = {
    entry["name"]: entry
    for entry in tomllib.loads((ENGINES_DIR.parents[1] / "catalog" / "objects.toml").read_text())["object"]
}
HANDS = ("trx3", "allegro")
SEEDS = [1234567890123 + 7919 * i for i in range(2)]
SHORT = {"hold_s": 0.3}


def run(
    engine: GraspEngine,
    tmp_path: Path,
    obj: str,
    hand: str,
    physics: dict[str, Any],
    seeds: list[int] = SEEDS,
    touch: dict[str, Any] | None = None,
) -> dict[str, Any]:
    params = {
        "object": CATALOG[obj],
        "hand": {"name": hand},
        "trials": [{"grasp_index": i, "seed": seed} for i, seed in enumerate(seeds)],
        # Extreme cases of the physics, any grasp type (test_grasp_types.py checks the types).
        "physics": {"grasp_type": "any", **physics},
        "touch": touch or {},
    }
    result = engine.run(TaskRequest("t", params, (), new_dir(tmp_path, f"{obj}-{hand}")))
    doc = read_grasps_with_touch(result.outputs[0].path.parent)
    assert_valid_or_rejected(doc, Physics.parse(physics))
    return doc


def assert_valid_or_rejected(doc: dict[str, Any], physics: Physics) -> None:
    mesh = build_model(ObjectSpec.parse({k: v for k, v in doc["object"].items() if k != "model"}))
    layout = hand_layout(doc["hand"]["name"])
    for trial in doc["trials"]:
        stability = trial["stability"]
        assert stability["retries"] <= physics.max_retries
        assert physics.min_timestep * (1 - 1e-9) <= stability["timestep_used"] <= physics.timestep
        for key in ("timestep_used", "max_penetration_m", "max_object_speed_mps", "max_kinetic_energy_j"):
            assert math.isfinite(stability[key]), (key, stability)
        if not trial["accepted"]:
            assert isinstance(trial["reason"], str) and trial["reason"], trial
            continue
        assert trial["reason"] is None and not stability["warnings"]
        assert stability["max_penetration_m"] <= physics.max_penetration_m
        assert stability["max_object_speed_mps"] <= physics.max_object_speed_mps
        assert trial["hold"]["drop_m"] < physics.max_drop_m
        for pose in [trial["object_pose"], trial["hand_pose"], *trial["link_poses"].values()]:
            assert all(math.isfinite(v) for v in pose["p"] + pose["q"])
            assert math.isclose(math.hypot(*pose["q"]), 1.0, rel_tol=1e-6)
        assert all(math.isfinite(v) for v in trial["joints"].values())
        touch = trial["touch"]
        margin = touch["contact_margin_m"]
        assert touch["active_count"] == len(touch["active"]) >= doc["touch"]["min_active_taxels"]
        assert (
            math.isfinite(touch["contact_force_n"])
            and 0 <= touch["unsensed_force_n"] <= touch["contact_force_n"]
        )
        world = taxel_points(layout, trial, [t["taxel"] for t in touch["active"]])
        pose = trial["object_pose"]
        local = (world - np.array(pose["p"])) @ quat_to_matrix(pose["q"])
        gap = distance_to_mesh(local, mesh.mesh.vertices, mesh.mesh.faces)
        gains = np.random.default_rng(doc["touch"]["gain_seed"]).lognormal(
            0.0, doc["touch"]["gain_sigma"], len(layout)
        )
        readings = np.array(touch["readings"])
        assert np.isfinite(readings).all() and (readings >= 0).all() and (readings <= gains).all()
        deepest = max(margin, stability["max_penetration_m"])
        for taxel, distance in zip(touch["active"], gap, strict=True):
            assert taxel["distance_m"] < margin and math.isfinite(taxel["force_n"]) and taxel["force_n"] > 0
            assert 0 < taxel["reading"] <= gains[taxel["taxel"]]
            # The mesh is the union of the collision pieces' surfaces only up to tessellation.
            assert distance < deepest + 1e-3, (taxel, distance)


def hand_layout(hand: str) -> TaxelLayout:
    path = read_hand_catalog()[hand].taxels_path()
    return parse_layout(path.read_text(), hand_dims(hand).link_names(), str(path))


def taxel_points(layout: TaxelLayout, trial: dict[str, Any], indices: list[int]) -> np.ndarray:
    """The hand instance's taxels `indices` (layout position plus recorded offset) in the world."""
    offsets = np.array(trial["touch"]["position_offsets_um"]) * 1e-6
    points = []
    for i in indices:
        pose = trial["link_poses"][layout.links[i]]
        points.append(quat_to_matrix(pose["q"]) @ (layout.positions[i] + offsets[i]) + pose["p"])
    return np.array(points).reshape(-1, 3)


@pytest.fixture(scope="module")
def engine() -> GraspEngine:
    return GraspEngine()


@pytest.mark.parametrize("hand", HANDS)
def test_a_stirring_stick_is_pinched_or_cleanly_rejected(
    engine: GraspEngine, tmp_path: Path, hand: str
) -> None:
    """1.5 mm thick and 0.8 g: held between the fingers with a gentle grip, or rejected."""
    doc = run(engine, tmp_path, "stirring_stick", hand, SHORT, [SEEDS[0] + 7919 * i for i in range(3)])
    for trial in (t for t in doc["trials"] if t["accepted"]):
        assert {c["link"] for c in trial["contacts"]} - {"palm"}, "held by the fingers"


def test_a_16_g_marker_is_held_with_a_gentle_grip(engine: GraspEngine, tmp_path: Path) -> None:
    """The full squeeze sank the fingers 13-21 mm into it; the weight-scaled grip does not."""
    doc = run(engine, tmp_path, "large_marker", "trx3", SHORT, [SEEDS[0] + 7919 * i for i in range(6)])
    held = [t for t in doc["trials"] if t["accepted"]]
    assert held, [t["reason"] for t in doc["trials"]]
    for trial in held:
        assert trial["hold"]["object_rise_m"] > 0.5 * doc["physics"]["lift_height"]


def posed_trials(
    obj: str, hand: str, approaches: list[tuple[np.ndarray, np.ndarray, float]], physics: dict[str, Any]
) -> dict[str, Any]:
    """Trials with the hand posed exactly: the object in its catalog orientation, the palm
    tangent to the object's extreme point along each `direction` (palm normal = -direction, the
    support plane of the object's surface there), turned by `angle` about it. Every record is
    JSON without NaN and valid or cleanly rejected."""
    entry = CATALOG[obj]
    scene = build_scene(hand_dims(hand), ObjectSpec.parse(entry))
    data = mujoco.MjData(scene.model)
    parsed = Physics.parse(physics)
    touch = TouchParams.parse({})
    skin = Skin(scene, hand_layout(hand), touch)
    vertices = scene.obj.surface.vertices
    records = []
    for index, (quat, direction, angle) in enumerate(approaches):
        unit = direction / np.linalg.norm(direction)
        point = vertices[int(np.argmax(vertices @ unit))]
        approach = Approach.facing(quat, point, unit, angle, 0.05 * hand_dims(hand).reach(), 0.5, scene)
        record = run_trial(scene, data, parsed, skin, index, index, approach)
        json.dumps(record, allow_nan=False)  # no NaN or infinity anywhere
        records.append(record)
    doc = {"object": entry, "hand": {"name": hand}, "trials": records, "touch": touch.to_json()}
    assert_valid_or_rejected(doc, parsed)
    return doc


UPRIGHT = np.array([1.0, 0.0, 0.0, 0.0])


@pytest.mark.parametrize("hand", HANDS)
@pytest.mark.parametrize(
    ("obj", "physics"), [("power_drill", {"mass_override_kg": 2.0}), ("stirring_stick", {})]
)
def test_top_and_tilted_grasps_of_the_heaviest_and_lightest_objects(
    hand: str, obj: str, physics: dict
) -> None:
    tilted = np.array([0.0, 1.0, 1.0])
    doc = posed_trials(
        obj, hand, [(UPRIGHT, np.array([0.0, 0.0, 1.0]), 0.0), (UPRIGHT, tilted, 1.0)], {**SHORT, **physics}
    )
    for trial, expected in zip(
        doc["trials"], ([0.0, 0.0, -1.0], -tilted / np.linalg.norm(tilted)), strict=True
    ):
        assert np.allclose(trial["approach"]["palm_normal_world"], expected)


@pytest.mark.parametrize("hand", HANDS)
def test_palm_normals_along_the_axes_and_turns_of_0_and_pi_are_handled(hand: str) -> None:
    """The palm frame is built from the normal alone: along a world axis a cross product with
    that axis would vanish."""
    axes = [np.array(v, dtype=float) for v in ([0, 0, 1], [0, 0, -1], [1, 0, 0], [-1, 0, 0])]
    doc = posed_trials(
        "tomato_soup_can", hand, [(UPRIGHT, a, angle) for a in axes for angle in (0.0, math.pi)], SHORT
    )
    for trial in doc["trials"]:
        normal = np.array(trial["approach"]["palm_normal_world"])
        assert np.isclose(np.abs(normal).max(), 1.0) and np.isclose(np.linalg.norm(normal), 1.0)
    assert sum(t["accepted"] for t in doc["trials"]) >= 4, [t["reason"] for t in doc["trials"]]


@pytest.mark.parametrize("hand", HANDS)
def test_a_2_kg_drill_is_held_or_rejected(engine: GraspEngine, tmp_path: Path, hand: str) -> None:
    run(engine, tmp_path, "power_drill", hand, {**SHORT, "mass_override_kg": 2.0})


@pytest.mark.parametrize("hand", HANDS)
def test_a_5_g_brick_is_held_or_rejected(engine: GraspEngine, tmp_path: Path, hand: str) -> None:
    run(engine, tmp_path, "foam_brick", hand, {**SHORT, "mass_override_kg": 0.005})


@pytest.mark.parametrize("ratio", [0.0, -0.1])
def test_zero_and_negative_standoff_start_touching_or_inside(
    engine: GraspEngine, tmp_path: Path, ratio: float
) -> None:
    for hand in HANDS:
        doc = run(engine, tmp_path, "tomato_soup_can", hand, {**SHORT, "standoff_ratio": [ratio, ratio]})
        standoffs = [t["approach"]["standoff"] for t in doc["trials"]]
        assert all(s == 0.0 for s in standoffs) if ratio == 0 else all(s < 0 for s in standoffs)


def test_contact_time_constant_at_the_timestep_reruns_with_a_finer_step(
    engine: GraspEngine, tmp_path: Path
) -> None:
    """MuJoCo would clamp the time constant to two timesteps, softening the skin silently."""
    for hand in HANDS:
        physics = {**SHORT, "timestep": 0.002, "hand_solref_timeconst": 0.002}
        doc = run(engine, tmp_path, "tomato_soup_can", hand, physics)
        for trial in doc["trials"]:
            assert trial["stability"]["timestep_used"] <= 0.001
            assert trial["stability"]["retry_reasons"][0].startswith("timestep:")


def test_an_8_ms_timestep_is_never_accepted_as_is(engine: GraspEngine, tmp_path: Path) -> None:
    """FACTS: a held can dropped silently at 4 ms. Either the trial reruns finer, or it is rejected."""
    for hand in HANDS:
        doc = run(engine, tmp_path, "tomato_soup_can", hand, {**SHORT, "timestep": 0.008})
        for trial in doc["trials"]:
            assert trial["stability"]["timestep_used"] <= 0.0025 or not trial["accepted"]
        rigid = run(
            engine,
            tmp_path / "rigid",
            "tomato_soup_can",
            hand,
            {**SHORT, "timestep": 0.008, "max_retries": 0},
        )
        assert [t["accepted"] for t in rigid["trials"]] == [False, False]
        assert all(t["reason"].startswith("timestep:") for t in rigid["trials"])


def test_a_10_s_hold_keeps_the_can(engine: GraspEngine, tmp_path: Path) -> None:
    """The whole hold is simulated; a can that creeps out of readiness over 10 s (it slid 9.6 mm
    at the default 1 ms step) is rejected for it, after the hold, not dropped."""
    doc = run(engine, tmp_path, "tomato_soup_can", "trx3", {"hold_s": 10.0}, SEEDS[:1])
    trial, hold_steps = doc["trials"][0], round(10.0 / doc["physics"]["timestep"])
    if trial["accepted"]:
        assert trial["hold"]["steps"] == hold_steps
    else:
        assert trial["reason"].startswith("moved_in_hand: slipped"), trial["reason"]
        assert trial["steps"] > hold_steps


@pytest.mark.parametrize("hand", HANDS)
def test_a_tenfold_squeeze_is_held_or_rejected(engine: GraspEngine, tmp_path: Path, hand: str) -> None:
    run(engine, tmp_path, "tomato_soup_can", hand, {**SHORT, "force_scale": 10.0})


@pytest.mark.parametrize("hand", HANDS)
@pytest.mark.parametrize("force_scale", [0.01, 100.0])
def test_the_extreme_squeezes_read_finite_touch_within_the_gains(
    engine: GraspEngine, tmp_path: Path, hand: str, force_scale: float
) -> None:
    """The contract's force_scale bounds: a 100-fold squeeze saturates taxels without overflow, a
    1/100 one barely reaches the activation force (or the grasp is rejected)."""
    run(
        engine,
        tmp_path,
        "tomato_soup_can",
        hand,
        {**SHORT, "force_scale": force_scale},
        touch={"min_active_taxels": 1},
    )


@pytest.mark.parametrize("hand", HANDS)
def test_a_sensor_at_its_most_aged_feels_only_hard_contacts(
    engine: GraspEngine, tmp_path: Path, hand: str
) -> None:
    """Aging 0.01: a taxel needs 100 times the activation force to fire, and reads less than new."""
    new = run(engine, tmp_path / "new", "tomato_soup_can", hand, SHORT, touch={"min_active_taxels": 0})
    aged = run(
        engine,
        tmp_path / "aged",
        "tomato_soup_can",
        hand,
        SHORT,
        touch={"aging": [0.01, 0.01], "min_active_taxels": 0},
    )
    assert [t["accepted"] for t in new["trials"]] == [t["accepted"] for t in aged["trials"]] == [True, True]
    for fresh, old in zip(new["trials"], aged["trials"], strict=True):
        readings = {a["taxel"]: a["reading"] for a in fresh["touch"]["active"]}
        assert readings and len(old["touch"]["active"]) < len(readings)
        for taxel in old["touch"]["active"]:
            assert taxel["force_n"] >= 100 * aged["touch"]["activation_force_n"]
            assert taxel["reading"] < readings[taxel["taxel"]]


@pytest.mark.parametrize("hand", HANDS)
def test_pyramidal_cones_with_high_impratio_hold_or_are_rejected(
    engine: GraspEngine, tmp_path: Path, hand: str
) -> None:
    run(engine, tmp_path, "tomato_soup_can", hand, {**SHORT, "cone": "pyramidal", "impratio": 100.0})


def test_a_shake_is_recorded_and_judged(engine: GraspEngine, tmp_path: Path) -> None:
    shake = {"enabled": True, "accel_mps2": 20.0, "directions": 4, "duration_s": 0.4}
    doc = run(engine, tmp_path, "tomato_soup_can", "trx3", {**SHORT, "shake": shake})
    for trial in doc["trials"]:
        if trial["accepted"]:
            assert 0.0 <= trial["hold"]["shake_slip_m"] < doc["physics"]["max_drop_m"]
        else:
            assert trial["reason"] in {"dropped: shake", "dropped", "no_contact", "no_touch"}


@pytest.mark.parametrize(
    "bad",
    [
        {"cone": "square"},
        {"standoff_ratio": [0.1, 0.0]},
        {"standoff_ratio": [-1.0, 0.0]},
        {"shake": {"enabled": "yes"}},
        {"shake": {"enabled": True, "directions": 0}},
        {"impratio": 0.5},
        {"force_scale": 0.0},
        {"mass_override_kg": -1.0},
        {"timestep": 0.02},
        {"max_retries": 9},
    ],
)
def test_impossible_physics_parameters_are_bad_input(bad: dict[str, Any]) -> None:
    with pytest.raises(BadInput):
        Physics.parse(bad)


def test_reruns_and_shakes_are_deterministic(tmp_path: Path) -> None:
    """Same seed, same bytes — also when trials rerun at a finer step and the hand shakes."""
    shake = {"enabled": True, "accel_mps2": 10.0, "directions": 3, "duration_s": 0.3}
    physics = {**SHORT, "timestep": 0.004, "shake": shake}
    params = {
        "object": CATALOG["mustard_bottle"],
        "hand": {"name": "allegro"},
        "trials": [{"grasp_index": i, "seed": seed} for i, seed in enumerate(SEEDS)],
        "physics": physics,
    }
    texts = []
    for name in ("first", "second"):
        result = GraspEngine().run(TaskRequest("t", params, (), new_dir(tmp_path, name)))
        texts.append(b"".join(output.path.read_bytes() for output in result.outputs))
    assert texts[0] == texts[1]
    doc = json.loads((tmp_path / "first" / "grasps.json").read_text())
    assert all(t["stability"]["retries"] == 1 for t in doc["trials"])
