"""Grasp types and readiness (`grasp_type`): what each type keeps, judged from the output files
with geometry of the tests' own, and the rejection reasons the result counts."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from vint_engines.grasp.engine import GraspEngine
from vint_engines.grasp.hands import TRX3
from vint_engines.grasp.touch import LinkContact, Skin, TouchParams
from vint_engines.grasp.trial import POWER_CENTRE_RATIO, TrialRejected, check_dorsal
from vint_engines.poses import quat_to_matrix
from vint_engines.protocol import TaskRequest

CAN = {
    "name": "tomato_soup_can",
    "ycb_id": "005",
    "mass_kg": 0.349,
    "material": "metal",
    "symmetries_continuous": [{"axis": [0.0, 0.0, 1.0], "offset": [0.0, 0.0, 0.0]}],
    "description": "",
    "shape": {"type": "cylinder", "radius_m": 0.0338, "height_m": 0.1019},
}
PHYSICS = {"timestep": 0.002, "lift_height": 0.10, "hold_s": 0.5, "max_drop_m": 0.02}
SEEDS = [1234567890123 + 7919 * i for i in range(10)]
ACTIVATION_N = TouchParams.parse({}).activation_force_n


def run(
    engine: GraspEngine, hand: str, grasp_type: str, out: Path
) -> tuple[dict[str, Any], dict[str, Any], Any]:
    params = {
        "object": CAN,
        "hand": {"name": hand},
        "trials": [{"grasp_index": i, "seed": seed} for i, seed in enumerate(SEEDS)],
        "physics": {**PHYSICS, "grasp_type": grasp_type},
    }
    result = engine.run(TaskRequest("t", params, (), out))
    grasps = json.loads((out / "grasps.json").read_text())
    touch = {t["grasp_index"]: t for t in json.loads((out / "touch.json").read_text())["trials"]}
    return grasps, touch, result.result


@pytest.fixture(scope="module")
def engine() -> GraspEngine:
    return GraspEngine()


@pytest.fixture(scope="module")
def runs(engine: GraspEngine, tmp_path_factory: pytest.TempPathFactory) -> dict[tuple[str, str], tuple]:
    return {
        (hand, kind): run(engine, hand, kind, tmp_path_factory.mktemp(f"{hand}_{kind}"))
        for hand in ("trx3", "allegro")
        for kind in ("power", "any")
    }


def on_back(link: dict[str, Any], p: np.ndarray) -> bool:
    """A link-frame point on the link's dorsal side, from the link's geometry in grasps.json: the
    palm's back half (palm -z), or a finger link's side away from the palm (link -x) more than 30°
    past its side (x < -r/2), short of the fingertip's end cap (sensorised all round)."""
    if link["name"] == "palm":
        return bool(p[2] < 0.0)
    capsule = next(g for g in link["geoms"] if g["type"] == "capsule")
    radius, end = capsule["size"][0], capsule["p"][2] + capsule["size"][1]
    return bool(p[2] <= end and p[0] < -0.5 * radius)


def back_forces(links: dict[str, dict[str, Any]], samples: list[list[dict[str, Any]]]) -> dict[str, float]:
    forces: dict[str, float] = {}
    for contacts in samples:
        for c in contacts:
            if on_back(links[c["link"]], np.array(c["p_link"])):
                forces[c["link"]] = forces.get(c["link"], 0.0) + c["force_n"] / len(samples)
    return forces


def centre_height(vertices: np.ndarray, trial: dict[str, Any], palm_half_z: float) -> tuple[float, float]:
    """The object's bounding-box centre's height over the palmar face and its bounding radius."""
    centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    radius = float(np.linalg.norm(vertices - centre, axis=1).max())
    obj, palm = trial["object_pose"], trial["hand_pose"]
    world = quat_to_matrix(obj["q"]) @ centre + np.array(obj["p"])
    local = quat_to_matrix(palm["q"]).T @ (world - np.array(palm["p"]))
    return float(local[2]) - palm_half_z, radius


def test_power_grasps_touch_with_the_palm_and_hold_the_object_near_it(
    engine: GraspEngine, runs: dict
) -> None:
    kept = 0
    for hand in ("trx3", "allegro"):
        grasps, touch, _ = runs[(hand, "power")]
        assert grasps["physics"]["grasp_type"] == "power"
        scene = next(s for (key, _), (s, _) in engine._scenes.items() if key == hand)
        for trial in (t for t in grasps["trials"] if t["accepted"]):
            kept += 1
            regions = [t["region"] for t in touch[trial["grasp_index"]]["active"]]
            assert "palm" in regions, f"{hand} grasp {trial['grasp_index']}: no palm taxel active"
            height, radius = centre_height(scene.obj.surface.vertices, trial, scene.hand.palm_half[2])
            assert height <= POWER_CENTRE_RATIO * radius + 1e-9, (hand, trial["grasp_index"], height, radius)
            assert trial["grasp"]["type"] == "power"
    assert kept >= 4, f"only {kept} power grasps of {2 * len(SEEDS)} kept"


def test_no_kept_grasp_presses_with_the_back_of_a_link(runs: dict) -> None:
    checked = 0
    for grasps, touch, _ in runs.values():
        links = {link["name"]: link for link in grasps["hand"]["links"]}
        for trial in (t for t in grasps["trials"] if t["accepted"]):
            forces = back_forces(links, touch[trial["grasp_index"]]["contact_samples"])
            assert max(forces.values(), default=0.0) <= ACTIVATION_N, (trial["grasp_index"], forces)
            checked += 1
    assert checked >= 10


def test_the_geometric_back_check_sees_a_pressing_back() -> None:
    link = {"name": "f0_mid", "geoms": [{"type": "capsule", "size": [0.009, 0.0175], "p": [0, 0, 0.0175]}]}
    samples = [[{"link": "f0_mid", "p_link": [-0.009, 0.0, 0.01], "force_n": 3.0}]]
    assert back_forces({"f0_mid": link}, samples) == {"f0_mid": 3.0}
    samples = [[{"link": "f0_mid", "p_link": [0.009, 0.0, 0.01], "force_n": 3.0}]]
    assert back_forces({"f0_mid": link}, samples) == {}


def test_the_skin_faces_a_palmar_contact_and_not_a_dorsal_one(engine: GraspEngine, runs: dict) -> None:
    scene = next(s for (key, _), (s, _) in engine._scenes.items() if key == "trx3")
    skin = Skin(scene, engine._layout("trx3", TRX3, {"name": "trx3"}, {})[0], TouchParams.parse({}))
    x = np.array([1.0, 0.0, 0.0])
    palmar = LinkContact("f0_mid", np.array([0.009, 0.0, 0.015]), 2.0, x)
    dorsal = LinkContact("f0_mid", np.array([-0.009, 0.0, 0.015]), 2.0, -x)
    side = LinkContact("f0_mid", np.array([0.0, 0.009, 0.015]), 2.0, np.array([0.0, 1.0, 0.0]))
    palm_edge = LinkContact("palm", np.array([0.055, 0.0, 0.0]), 2.0, x)
    assert skin.faces_skin(palmar) and skin.faces_skin(side)
    assert not skin.faces_skin(dorsal) and not skin.faces_skin(palm_edge)
    assert skin.dorsal_forces([[palmar, dorsal], [dorsal]]) == {"f0_mid": 2.0}
    with pytest.raises(TrialRejected, match=r"^dorsal_contact: f0_mid 2 N"):
        check_dorsal({"f0_mid": 2.0, "palm": 0.1}, ACTIVATION_N)
    check_dorsal({"f0_mid": 0.1}, ACTIVATION_N)


def test_every_rejection_has_a_reason_and_the_result_counts_them_by_class(runs: dict) -> None:
    classes: set[str] = set()
    for grasps, _, result in runs.values():
        trials = grasps["trials"]
        rejected = [t for t in trials if not t["accepted"]]
        assert all(isinstance(t["reason"], str) and t["reason"] for t in rejected)
        assert sum(result["rejected"].values()) == len(rejected)
        assert len(result["accepted"]) + len(rejected) == len(trials)
        for t in rejected:
            kind = t["reason"].split(":", 1)[0]
            assert result["rejected"].get(kind, 0) >= 1, (t["reason"], result["rejected"])
            classes.add(kind)
    # The power runs reject for the type's own reasons; `any` keeps grasps power would not.
    assert classes & {"no_palm_contact", "far_from_palm"}, classes
    power = sum(len(runs[(h, "power")][2]["accepted"]) for h in ("trx3", "allegro"))
    any_kind = sum(len(runs[(h, "any")][2]["accepted"]) for h in ("trx3", "allegro"))
    assert power < any_kind


def test_precision_grasps_touch_with_fingertips_only(engine: GraspEngine, tmp_path: Path) -> None:
    grasps, touch, _ = run(engine, "trx3", "precision", tmp_path)
    for trial in (t for t in grasps["trials"] if t["accepted"]):
        active = touch[trial["grasp_index"]]["active"]
        assert {t["region"] for t in active} == {"tip"}
        assert len({t["link"] for t in active}) >= 2
    reasons = {t["reason"].split(":", 1)[0] for t in grasps["trials"] if not t["accepted"]}
    assert "not_fingertips" in reasons
    assert "no_palm_contact" not in reasons and "far_from_palm" not in reasons
