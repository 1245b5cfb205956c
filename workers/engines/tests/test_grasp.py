"""Grasp trials of the trx3 hand on a soup-can-sized cylinder, through the grasp engine."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pytest
from conftest import new_dir

from vint_engines.grasp.engine import GraspEngine, grasp_result
from vint_engines.grasp.hands import ALLEGRO, TRX3
from vint_engines.grasp.scene import ObjectSpec, build_scene
from vint_engines.grasp.trial import SURFACE_DRAWS, Approach, Physics, Rollout, TrialRejected
from vint_engines.objects import load_catalog
from vint_engines.poses import quat_to_matrix
from vint_engines.protocol import BadInput, TaskRequest

CAN = {
    "name": "tomato_soup_can",
    "ycb_id": "005",
    "mass_kg": 0.349,
    "material": "plastic",
    "symmetries_continuous": [{"axis": [0.0, 0.0, 1.0], "offset": [0.0, 0.0, 0.0]}],
    "description": "",
    "shape": {"type": "cylinder", "radius_m": 0.0338, "height_m": 0.1019},
}
# The procedure under test keeps any grasp type (test_grasp_types.py checks the types).
PHYSICS = {"timestep": 0.002, "lift_height": 0.10, "hold_s": 1.0, "max_drop_m": 0.02, "grasp_type": "any"}
SEEDS = [1234567890123 + 7919 * i for i in range(8)]


def grasp_params(seeds: list[int], **physics: float) -> dict[str, Any]:
    return {
        "object": {**CAN, "material": "metal"},
        "hand": {"name": "trx3"},
        "trials": [{"grasp_index": i, "seed": seed} for i, seed in enumerate(seeds)],
        "physics": {**PHYSICS, **physics},
    }


def run_grasp(engine: GraspEngine, params: dict[str, Any], out_dir: Path) -> tuple[str, dict[str, Any]]:
    result = engine.run(TaskRequest("t", params, (), out_dir))
    assert [o.name for o in result.outputs] == ["grasps.json", "touch.json", "object.ply"]
    text = result.outputs[0].path.read_text()
    return text, json.loads(text)


@pytest.fixture(scope="module")
def engine() -> GraspEngine:
    return GraspEngine()


@pytest.fixture(scope="module")
def eight_trials(engine: GraspEngine, tmp_path_factory: pytest.TempPathFactory) -> tuple[str, dict[str, Any]]:
    return run_grasp(engine, grasp_params(SEEDS), tmp_path_factory.mktemp("grasp"))


def test_the_result_counts_each_accepted_trials_active_taxels_per_region() -> None:
    active = [{"region": "tip"}, {"region": "tip"}, {"region": "palm"}]
    records = [
        {"grasp_index": 3, "accepted": True, "touch": {"active": active}},
        {"grasp_index": 4, "accepted": False, "reason": "dropped: lift"},
        {"grasp_index": 5, "accepted": True, "touch": {"active": []}},
    ]
    assert grasp_result(records, ("palm", "tip", "pulp", "tip")) == {
        "accepted": [3, 5],
        "rejected": {"dropped": 1},
        "active_taxels": [
            {"grasp_index": 3, "by_region": {"palm": 1, "pulp": 0, "tip": 2}},
            {"grasp_index": 5, "by_region": {"palm": 0, "pulp": 0, "tip": 0}},
        ],
    }


def test_most_trials_on_the_can_are_accepted(eight_trials: tuple[str, dict[str, Any]]) -> None:
    trials = eight_trials[1]["trials"]
    assert len(trials) == 8
    assert sum(t["accepted"] for t in trials) >= 4, [t["reason"] for t in trials]


def test_accepted_trials_hold_the_object_with_finger_contacts(
    eight_trials: tuple[str, dict[str, Any]],
) -> None:
    doc = eight_trials[1]
    links = {link["name"] for link in doc["hand"]["links"]}
    for trial in (t for t in doc["trials"] if t["accepted"]):
        assert trial["reason"] is None
        assert trial["hold"]["drop_m"] < PHYSICS["max_drop_m"]
        # Lifted with the hand from where it settled after the fixture released it (the origin),
        # having moved less than a finger length in the hand while settling.
        assert trial["hold"]["object_rise_m"] > 0.5 * PHYSICS["lift_height"]
        assert 0.0 <= trial["hold"]["settle_m"] < TRX3.reach()
        assert trial["object_pose"]["p"][2] > trial["hold"]["object_rise_m"] - TRX3.reach()
        assert {c["link"] for c in trial["contacts"]} & (links - {"palm"})
        assert set(trial["link_poses"]) == links
        assert len(trial["joints"]) == doc["hand"]["dof"] == 8
        for contact in trial["contacts"]:
            assert contact["force"] >= 0 and math.isclose(math.hypot(*contact["normal"]), 1.0, rel_tol=1e-6)


def test_poses_are_finite_unit_quaternion_poses(eight_trials: tuple[str, dict[str, Any]]) -> None:
    for trial in (t for t in eight_trials[1]["trials"] if t["accepted"]):
        for pose in [trial["object_pose"], trial["hand_pose"], *trial["link_poses"].values()]:
            assert len(pose["p"]) == 3 and all(math.isfinite(v) for v in pose["p"])
            assert math.isclose(math.hypot(*pose["q"]), 1.0, rel_tol=1e-6)


def test_hand_geometry_is_reported_in_mujoco_convention(eight_trials: tuple[str, dict[str, Any]]) -> None:
    sizes = {"box": 3, "sphere": 1, "capsule": 2, "cylinder": 2}
    hand = eight_trials[1]["hand"]
    assert hand["name"] == "trx3" and hand["links"][0]["name"] == "palm"
    for link in hand["links"]:
        assert link["geoms"]
        for geom in link["geoms"]:
            assert len(geom["size"]) == sizes[geom["type"]] and len(geom["p"]) == 3 and len(geom["q"]) == 4


def test_same_seed_gives_identical_output(
    engine: GraspEngine, eight_trials: tuple[str, dict[str, Any]], tmp_path: Path
) -> None:
    again, _ = run_grasp(engine, grasp_params(SEEDS), new_dir(tmp_path, "again"))
    fresh, _ = run_grasp(GraspEngine(), grasp_params(SEEDS), new_dir(tmp_path, "fresh"))
    assert again == eight_trials[0]
    assert fresh == eight_trials[0]


def test_rejected_trials_carry_a_reason(engine: GraspEngine, tmp_path: Path) -> None:
    # A 20 kg can in fingers at 5 % of their force slips out during the hold.
    _, doc = run_grasp(engine, grasp_params(SEEDS[:2], mass_override_kg=20.0, force_scale=0.05), tmp_path)
    assert [t["reason"] for t in doc["trials"]] == ["dropped", "dropped"]
    assert not any(t["accepted"] for t in doc["trials"])


def test_impossible_parameters_are_bad_input(engine: GraspEngine, tmp_path: Path) -> None:
    for change in ({"hand": {"name": "octopus"}}, {"object": {**CAN, "shape": "torus"}}, {"trials": []}):
        with pytest.raises(BadInput):
            engine.run(TaskRequest("t", {**grasp_params(SEEDS[:1]), **change}, (), tmp_path))


def test_divergence_and_nan_states_reject_the_trial() -> None:
    """Autoreset hides divergence, so a rollout must read MuJoCo's warning counters and the state."""
    scene = build_scene(TRX3, ObjectSpec.parse(CAN))
    data = mujoco.MjData(scene.model)
    rollout = Rollout(scene, data, Physics.parse(PHYSICS))
    rollout.check()  # a fresh state is fine
    data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number = 1
    with pytest.raises(TrialRejected, match="diverged: mjWARN_BADQACC"):
        rollout.check()
    mujoco.mj_resetData(scene.model, data)
    data.qvel[0] = float("nan")
    with pytest.raises(TrialRejected, match="nan_state"):
        rollout.check()


def sphere_bins(directions: np.ndarray, bands: int = 4, sectors: int = 8) -> set[tuple[int, int]]:
    """Equal-area cells of the unit sphere (bands of equal z height times azimuth sectors) that
    the unit `directions` fall in."""
    band = np.minimum(((directions[:, 2] + 1.0) / 2.0 * bands).astype(int), bands - 1)
    azimuth = np.arctan2(directions[:, 1], directions[:, 0]) + math.pi
    sector = np.minimum((azimuth / (2 * math.pi) * sectors).astype(int), sectors - 1)
    return set(zip(band.tolist(), sector.tolist(), strict=True))


@pytest.mark.parametrize("obj", ["tomato_soup_can", "power_drill"])
def test_approaches_come_from_every_direction(obj: str) -> None:
    """Palm normals cover the sphere in the world (the object's orientation is uniform) and in the
    object's frame (surface points from every side: a can's caps as well as its side)."""
    scene = build_scene(TRX3, load_catalog()[obj])
    approaches = [Approach.sample(np.random.default_rng(seed), scene) for seed in range(256)]
    world = np.array([a.palm_rotation()[:, 2] for a in approaches])
    assert len(sphere_bins(world)) >= 30  # of 32; 8 draws per cell expected
    object_axes = np.array([quat_to_matrix(a.object_quat)[:, 2] for a in approaches])
    assert len(sphere_bins(object_axes)) >= 30
    in_object = -np.array([a.normal for a in approaches])
    if obj == "tomato_soup_can":
        # Area-weighted: the caps are r / (r + h) = 25 % of the can's surface, the rest its side.
        caps = np.abs(in_object[:, 2]) > 0.99
        assert 0.15 < caps.mean() < 0.4, caps.mean()
        assert len(sphere_bins(in_object[~caps])) == 8  # the side, from every azimuth
    else:
        assert len(sphere_bins(in_object)) >= 12  # a drill's faces point many ways
    assert all(a.width <= TRX3.reach() or a.redraws == SURFACE_DRAWS for a in approaches)


def test_the_hand_grasps_from_the_sampled_direction(eight_trials: tuple[str, dict[str, Any]]) -> None:
    """The arm keeps the palm's orientation through the lift: the held hand faces as sampled."""
    for trial in (t for t in eight_trials[1]["trials"] if t["accepted"]):
        normal = quat_to_matrix(trial["hand_pose"]["q"])[:, 2]
        assert normal @ np.array(trial["approach"]["palm_normal_world"]) > 0.999


def test_the_allegro_spreads_its_fingers(engine: GraspEngine, tmp_path: Path) -> None:
    params = {**grasp_params(SEEDS[:6], hold_s=0.3), "hand": {"name": "allegro"}}
    _, doc = run_grasp(engine, params, tmp_path)
    accepted = [t for t in doc["trials"] if t["accepted"]]
    assert len(accepted) >= 3, [t["reason"] for t in doc["trials"]]
    ranges = dict(zip(ALLEGRO.joint_names(), ALLEGRO.spread_ranges(), strict=True))
    for joint in ("f0_j0", "f2_j0", "f3_j1"):
        angles = np.array([t["joints"][joint] for t in accepted])
        assert angles.std() > 0.05, (joint, angles)
        low, high = sorted(ranges[joint])
        assert (angles > low - 0.05).all() and (angles < high + 0.05).all(), (joint, angles)


def test_trials_give_the_same_records_in_any_order(engine: GraspEngine, tmp_path: Path) -> None:
    seeds = SEEDS[:3]
    forward = grasp_params(seeds, hold_s=0.3)
    backward = {**forward, "trials": forward["trials"][::-1]}
    _, one = run_grasp(engine, forward, new_dir(tmp_path, "forward"))
    _, other = run_grasp(engine, backward, new_dir(tmp_path, "backward"))
    assert one["trials"] == other["trials"][::-1]
