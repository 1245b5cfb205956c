"""Whole-hand touch from contact mechanics: both hands grasp three objects through the grasp engine,
and every active taxel is checked against what is computed here, independently, from the recorded
contacts, link poses and object pose and the object's model mesh; plus the response's behaviour."""

from __future__ import annotations

import hashlib
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pytest
from conftest import ENGINES_DIR, read_grasps_with_touch
from geometry import signed_distance_to_mesh

from vint_engines.grasp.engine import GraspEngine
from vint_engines.grasp.hand import TOUCH_PROBE, add_touch_probe
from vint_engines.grasp.hands import HANDS, hand_dims
from vint_engines.grasp.hands.catalog import read_hand_catalog
from vint_engines.grasp.taxels import TaxelLayout, read_layout
from vint_engines.grasp.touch import (
    TouchParams,
    object_distances,
    response,
    shared_force,
    taxel_gains,
    trial_aging,
    window_steps,
)
from vint_engines.objects import ObjectSpec, build_model
from vint_engines.poses import quat_to_matrix
from vint_engines.protocol import BadInput, TaskRequest

CATALOG = {
    entry["name"]: entry
    for entry in tomllib.loads((ENGINES_DIR.parents[1] / "catalog" / "objects.toml").read_text())["object"]
}
OBJECTS = ("tomato_soup_can", "mustard_bottle", "mug")
SEEDS = [1234567890123 + 7919 * i for i in range(5)]
TOUCH: dict[str, Any] = {"gain_seed": 123}
DEFAULTS = TouchParams.parse({})
# The model mesh's triangles are chords of the collision shapes' curved surfaces (and CoACD's pieces
# approximate non-convex meshes): the independent distance may exceed MuJoCo's by this much.
TESSELLATION_M = 3e-4
MIN_SPEARMAN = 0.8
NEAR_M = 3e-4  # a taxel this close to the mesh (or inside it) touches the object
MIN_RECALL = 0.9


def grasp_params(obj: str, hand: str, seeds: list[int], **touch: Any) -> dict[str, Any]:
    return {
        "object": CATALOG[obj],
        "hand": {"name": hand},
        "trials": [{"grasp_index": i, "seed": seed} for i, seed in enumerate(seeds)],
        # The touch model, not the grasp type, is under test: keep any hold (test_grasp_types.py).
        "physics": {"hold_s": 0.5, "grasp_type": "any"},
        "touch": {**TOUCH, **touch},
    }


@dataclass(frozen=True)
class Run:
    """One (object, hand) task's output."""

    obj: str
    hand: str
    doc: dict[str, Any]
    metrics: dict[str, float]

    @property
    def accepted(self) -> list[dict[str, Any]]:
        return [t for t in self.doc["trials"] if t["accepted"]]


def run(
    engine: GraspEngine, params: dict[str, Any], out_dir: Path
) -> tuple[dict[str, Any], dict[str, float]]:
    out_dir.mkdir(parents=True, exist_ok=True)
    result = engine.run(TaskRequest("t", params, (), out_dir))
    return read_grasps_with_touch(out_dir), result.metrics


def layout_of(hand: str) -> TaxelLayout:
    return read_layout(read_hand_catalog()[hand].taxels_path(), hand_dims(hand).link_names())


@pytest.fixture(scope="module")
def engine() -> GraspEngine:
    return GraspEngine()


@pytest.fixture(scope="module")
def runs(engine: GraspEngine, tmp_path_factory: pytest.TempPathFactory) -> list[Run]:
    """Five trials of each hand on each of three objects, with the default touch model."""
    out = tmp_path_factory.mktemp("touch")
    runs = []
    for hand in HANDS:
        for obj in OBJECTS:
            doc, metrics = run(engine, grasp_params(obj, hand, SEEDS), out / f"{obj}-{hand}")
            runs.append(Run(obj, hand, doc, metrics))
    return runs


def taxels_in_world(layout: TaxelLayout, trial: dict[str, Any]) -> np.ndarray:
    """Every taxel of the hand instance (the layout's position plus the trial's recorded placement
    deviation) moved to the world with its link's recorded pose."""
    positions = layout.positions + np.array(trial["touch"]["position_offsets_um"]) * 1e-6
    world = np.empty_like(positions)
    for link, indices in layout.indices_by_link().items():
        pose = trial["link_poses"][link]
        world[indices] = positions[indices] @ quat_to_matrix(pose["q"]).T + pose["p"]
    return world


def mesh_distance(obj: str, world: np.ndarray, trial: dict[str, Any]) -> np.ndarray:
    """Signed distance (m, negative inside) of world points to the object's model mesh at its
    recorded pose."""
    mesh = build_model(ObjectSpec.parse(CATALOG[obj])).mesh
    pose = trial["object_pose"]
    local = (world - np.array(pose["p"])) @ quat_to_matrix(pose["q"])
    return signed_distance_to_mesh(local, mesh.vertices, mesh.faces)


def link_contact_force(trial: dict[str, Any]) -> dict[str, float]:
    total: dict[str, float] = {}
    for contact in trial["contacts"]:
        total[contact["link"]] = total.get(contact["link"], 0.0) + contact["force"]
    return total


def spearman(x: np.ndarray, y: np.ndarray) -> float:
    """Spearman's rank correlation (average ranks for ties)."""

    def ranks(v: np.ndarray) -> np.ndarray:
        order = np.argsort(v, kind="stable")
        r = np.empty(len(v))
        r[order] = np.arange(len(v), dtype=float)
        for value in np.unique(v):
            tied = v == value
            r[tied] = r[tied].mean()
        return r

    return float(np.corrcoef(ranks(x), ranks(y))[0, 1])


def sampled_forces(layout: TaxelLayout, obj: str, trial: dict[str, Any]) -> dict[int, float]:
    """Each taxel's force recomputed from the trial's recorded contact samples as docs/touch.md
    defines it, written per taxel here, with the mesh's distance standing for MuJoCo's: a link's
    mean contact force shared by its taxels within the margin, in proportion to margin - distance."""
    touch = trial["touch"]
    world = taxels_in_world(layout, trial)
    margin = DEFAULTS.contact_margin_m
    force: dict[int, float] = {}
    for link, members in layout.indices_by_link().items():
        if not any(c["link"] == link for c in touch["contact_samples"][0]):
            continue
        link_force = sum(
            c["force_n"] for contacts in touch["contact_samples"] for c in contacts if c["link"] == link
        ) / len(touch["contact_samples"])
        gap = mesh_distance(obj, world[members], trial)
        interference = {
            i: margin - g for i, g in zip(members.tolist(), gap.tolist(), strict=True) if g < margin
        }
        for i, w in interference.items():
            force[i] = link_force * w / sum(interference.values())
    return force


def test_every_hand_and_object_is_grasped_with_touch(runs: list[Run]) -> None:
    for r in runs:
        reasons = [t["reason"] for t in r.doc["trials"]]
        assert len(r.accepted) >= 3, (r.obj, r.hand, reasons)
        layout = layout_of(r.hand)
        info = read_hand_catalog()[r.hand]
        deviation = r.doc["hand"]["taxels"].pop("deviation")
        assert r.doc["hand"]["taxels"] == {
            "layout": f"hands/{r.hand}/taxels.csv",
            "count": len(layout),
            "sha256": hashlib.sha256(info.taxels_path().read_bytes()).hexdigest(),
        }
        # The hand instance: the layout file plus each trial's recorded offsets, written as a
        # layout file, hashes to what the record names.
        offsets = np.array(r.accepted[0]["touch"]["position_offsets_um"]) * 1e-6
        moved = TaxelLayout(layout.links, layout.positions + offsets, layout.normals, layout.regions)
        assert deviation["sha256"] == hashlib.sha256(moved.to_csv().encode()).hexdigest()
        assert deviation["position_sigma_m"] == DEFAULTS.position_sigma_m
        assert deviation["seed"] == TOUCH["gain_seed"]
        assert r.doc["touch"] == {**DEFAULTS.to_json(), **TOUCH}


def test_active_taxels_touch_the_object_on_links_in_contact(runs: list[Run]) -> None:
    """Independently of the touch code: the link carries MuJoCo contact force, and the taxel lies
    within the contact margin of the object's mesh, and no deeper inside than the deepest
    penetration the trial saw."""
    margin = DEFAULTS.contact_margin_m
    for r in runs:
        layout = layout_of(r.hand)
        for trial in r.accepted:
            touch = trial["touch"]
            assert touch["active_count"] == len(touch["active"]) > 0
            steps = window_steps(DEFAULTS.contact_window_s, trial["stability"]["timestep_used"])
            assert touch["contact_margin_m"] == margin and touch["contact_steps"] == steps
            forces = link_contact_force(trial)
            indices = [a["taxel"] for a in touch["active"]]
            world = taxels_in_world(layout, trial)
            gap = mesh_distance(r.obj, world[indices], trial)
            deepest = trial["stability"]["max_penetration_m"]
            palm = trial["hand_pose"]
            for taxel, g in zip(touch["active"], gap, strict=True):
                i = taxel["taxel"]
                assert forces.get(taxel["link"], 0.0) > 0.0, taxel
                assert -deepest - TESSELLATION_M <= g <= margin + TESSELLATION_M, (r.obj, r.hand, taxel, g)
                assert taxel["distance_m"] < margin and taxel["force_n"] > 0.0
                assert (taxel["link"], taxel["region"]) == (layout.links[i], layout.regions[i])
                p_palm = (world[i] - palm["p"]) @ quat_to_matrix(palm["q"])
                assert taxel["p_palm"] == pytest.approx(p_palm, abs=1e-9)
                assert np.linalg.norm(taxel["n_palm"]) == pytest.approx(1.0)


def test_taxels_touching_the_object_fire(runs: list[Run], record_property: pytest.RecordProperty) -> None:
    """Each taxel is a contact element: of the taxels the object's mesh puts within 0.3 mm of its
    surface (or inside it), at least 90 % are active, on every link that lies against the object
    (an area contact is felt over its area, not at MuJoCo's few contact points)."""
    for hand in HANDS:
        near = touching_active = 0
        layout = layout_of(hand)
        for r in (r for r in runs if r.hand == hand):
            for trial in r.accepted:
                gap = mesh_distance(r.obj, taxels_in_world(layout, trial), trial)
                active = np.zeros(len(layout), dtype=bool)
                active[[a["taxel"] for a in trial["touch"]["active"]]] = True
                near += int((gap <= NEAR_M).sum())
                touching_active += int((active & (gap <= NEAR_M)).sum())
        recall = touching_active / near
        record_property(f"{hand}_touch_recall", recall)
        assert near > 50 and recall >= MIN_RECALL, (hand, touching_active, near)


def test_a_link_without_contact_has_no_active_taxel(runs: list[Run]) -> None:
    for r in runs:
        for trial in r.accepted:
            touching = {link for link, force in link_contact_force(trial).items() if force > 0.0}
            assert {a["link"] for a in trial["touch"]["active"]} <= touching


def test_readings_rise_with_the_force_recomputed_from_the_recorded_contact_samples(
    runs: list[Run], record_property: pytest.RecordProperty
) -> None:
    for hand in HANDS:
        readings, forces = [], []
        for r in (r for r in runs if r.hand == hand):
            layout = layout_of(hand)
            for trial in r.accepted:
                recomputed = sampled_forces(layout, r.obj, trial)
                for taxel in trial["touch"]["active"]:
                    readings.append(taxel["reading"])
                    forces.append(recomputed.get(taxel["taxel"], 0.0))
        rho = spearman(np.array(readings), np.array(forces))
        record_property(f"{hand}_spearman_reading_force", rho)
        assert rho >= MIN_SPEARMAN, (hand, rho, len(readings))


def test_readings_follow_the_response_of_the_recorded_force_and_inactive_taxels_read_zero(
    runs: list[Run],
) -> None:
    for r in runs:
        gains = np.random.default_rng(TOUCH["gain_seed"]).lognormal(
            0.0, DEFAULTS.gain_sigma, len(layout_of(r.hand))
        )
        for trial in r.accepted:
            readings = np.array(trial["touch"]["readings"])
            active = [a["taxel"] for a in trial["touch"]["active"]]
            assert not np.delete(readings, active).any()
            assert trial["touch"]["aging"] == 1.0  # the default range [1, 1]
            for taxel in trial["touch"]["active"]:
                x = taxel["force_n"] / DEFAULTS.half_force_n
                expected = gains[taxel["taxel"]] * x / (1.0 + x)  # exponent 1, aging 1
                assert taxel["reading"] == readings[taxel["taxel"]] == pytest.approx(expected, rel=1e-9)
                assert taxel["force_n"] >= DEFAULTS.activation_force_n


def test_with_one_step_the_taxels_share_exactly_the_recorded_contact_force(
    engine: GraspEngine, tmp_path: Path
) -> None:
    """Force is conserved: what the taxels carry plus what fell between them is what MuJoCo
    reported on the skin's links."""
    unsensed = total = 0.0
    for hand in HANDS:
        params = grasp_params(
            "tomato_soup_can", hand, SEEDS[:3], contact_window_s=0.0, activation_force_n=0.0
        )
        doc, _ = run(engine, params, tmp_path / hand)
        links = set(layout_of(hand).links)
        for trial in (t for t in doc["trials"] if t["accepted"]):
            touch = trial["touch"]
            recorded = sum(c["force"] for c in trial["contacts"] if c["link"] in links)
            [sample] = touch["contact_samples"]
            assert sorted(c["force_n"] for c in sample) == sorted(c["force"] for c in trial["contacts"])
            assert touch["contact_force_n"] == pytest.approx(recorded, rel=1e-9)
            carried = sum(a["force_n"] for a in touch["active"])
            assert carried + touch["unsensed_force_n"] == pytest.approx(recorded, rel=1e-9)
            unsensed, total = unsensed + touch["unsensed_force_n"], total + recorded
    # Grasps from any side also press on skin without taxels (a finger's sides and back), but most
    # of the force lands where the taxels are.
    assert total > 0 and unsensed < 0.5 * total, (unsensed, total)


def test_the_response_is_monotone_saturating_and_weakens_with_age() -> None:
    force = np.geomspace(1e-3, 1e4, 400)
    gains = np.full(len(force), 1.3)
    new = response(force, gains, DEFAULTS, 1.0)
    aged = response(force, gains, DEFAULTS, 0.5)
    fires = force >= DEFAULTS.activation_force_n
    assert not new[~fires].any() and (new[fires] > 0).all()
    assert (np.diff(new[fires]) > 0).all() and (new < 1.3).all() and new[-1] > 0.99 * 1.3
    # The curve is a divider's output: half the gain at the half force, a quarter at a third of it.
    half = DEFAULTS.half_force_n
    assert response(np.array([half, half / 3]), gains[:2], DEFAULTS, 1.0) == pytest.approx([0.65, 0.325])
    # An aged taxel needs more force for the same reading, and to fire at all.
    assert (aged <= new).all() and (aged[fires & (aged > 0)] < new[fires & (aged > 0)]).all()
    assert (
        aged[(force >= DEFAULTS.activation_force_n) & (force < 2 * DEFAULTS.activation_force_n)] == 0
    ).all()
    steeper = response(force, gains, TouchParams.parse({"response_exponent": 2.0}), 1.0)
    assert steeper[force < half].max() < new[force < half].max()


def test_no_force_no_reading() -> None:
    gains = np.ones(4)
    free = TouchParams.parse({"activation_force_n": 0.0})
    assert not response(np.array([0.0, -1.0, 0.0, -1e9]), gains, free, 1.0).any()


def test_gains_are_fixed_by_the_seed() -> None:
    a, b, c = taxel_gains(600, 0.1, 123), taxel_gains(600, 0.1, 123), taxel_gains(600, 0.1, 124)
    assert (a == b).all() and (a != c).any()
    assert np.median(a) == pytest.approx(1.0, abs=0.02) and np.std(np.log(a)) == pytest.approx(0.1, rel=0.1)
    assert (taxel_gains(600, 0.0, 5) == 1.0).all()


@pytest.mark.parametrize("aging", [0.01, 1.0])
@pytest.mark.parametrize("exponent", [0.2, 1.0, 3.0])
def test_extreme_forces_read_within_zero_and_the_gain(aging: float, exponent: float) -> None:
    params = TouchParams.parse({"aging": [aging, aging], "response_exponent": exponent, "half_force_n": 0.01})
    force = np.array([0.0, 1e-300, 1e-12, 0.2, 1.0, 1e3, 1e9, 1e300, np.finfo(float).max])
    gains = np.array([0.5, 1.0, 2.0, 0.7, 1.1, 1.9, 0.9, 1.5, 3.0])
    readings = response(force, gains, params, trial_aging(params.aging, 7))
    assert np.isfinite(readings).all() and (readings >= 0).all() and (readings <= gains).all()
    assert readings[-1] == pytest.approx(gains[-1])


def test_a_links_force_is_shared_by_interference_and_conserved() -> None:
    interference = np.array([1e-4, 3e-4, 0.5e-4, 0.5e-4])
    share = shared_force(interference, 9.0)
    assert share == pytest.approx([1.8, 5.4, 0.9, 0.9]) and share.sum() == pytest.approx(9.0)
    assert share.argmax() == 1  # the taxel pressed deepest carries most
    # One taxel touching carries it all; a taxel barely inside the margin next to a pressed one,
    # almost nothing; forces from ~1e-4 N to ~1e4 N stay finite and conserved.
    assert shared_force(np.array([2e-4]), 3.0) == pytest.approx([3.0])
    assert shared_force(np.array([1e-300, 1e-3]), 1.0)[0] < 1e-290
    rng = np.random.default_rng(3)
    for force in rng.lognormal(0.0, 3.0, size=200):
        share = shared_force(rng.uniform(1e-9, 1e-3, size=64), force)
        assert np.isfinite(share).all() and (share > 0).all()
        assert share.sum() == pytest.approx(force, rel=1e-9)


def test_readings_depend_on_the_gain_seed_alone(engine: GraspEngine, tmp_path: Path) -> None:
    """The hand's seed fixes its sensor: with exact taxel positions (the deviations, drawn from the
    same seed, are test_taxel_variation.py's) another seed changes the gains only."""
    exact = {"position_sigma_m": 0.0}
    first, _ = run(engine, grasp_params("tomato_soup_can", "trx3", SEEDS[:2], **exact), tmp_path / "a")
    again, _ = run(GraspEngine(), grasp_params("tomato_soup_can", "trx3", SEEDS[:2], **exact), tmp_path / "b")
    reseeded, _ = run(
        engine, grasp_params("tomato_soup_can", "trx3", SEEDS[:2], gain_seed=124, **exact), tmp_path / "c"
    )
    for t1, t2, t3 in zip(first["trials"], again["trials"], reseeded["trials"], strict=True):
        assert t1["accepted"] and t1["touch"] == t2["touch"]  # same seed: identical readings
        assert [a["taxel"] for a in t1["touch"]["active"]] == [a["taxel"] for a in t3["touch"]["active"]]
        assert t1["touch"]["readings"] != t3["touch"]["readings"]  # other gains, same contact


def test_averaging_more_steps_changes_only_the_touch(engine: GraspEngine, tmp_path: Path) -> None:
    """The averaged steps run on a copy of the state: poses and contacts stay those of the capture.
    A window spans as many steps as fit in it at the step the trial used."""
    one, _ = run(engine, grasp_params("mug", "allegro", SEEDS[:2], contact_window_s=0.0), tmp_path / "one")
    many, _ = run(
        engine, grasp_params("mug", "allegro", SEEDS[:2], contact_window_s=0.016), tmp_path / "many"
    )
    for t1, t16 in zip(one["trials"], many["trials"], strict=True):
        assert {k: v for k, v in t1.items() if k != "touch"} == {k: v for k, v in t16.items() if k != "touch"}
        if t1["accepted"]:
            timestep = t16["stability"]["timestep_used"]
            assert t1["touch"]["contact_steps"] == 1
            assert t16["touch"]["contact_steps"] == round(0.016 / timestep) >= 16


def test_grasps_activate_several_taxels_in_every_region(
    runs: list[Run], record_property: pytest.RecordProperty
) -> None:
    for hand in HANDS:
        accepted = [t for r in runs if r.hand == hand for t in r.accepted]
        median = float(np.median([t["touch"]["active_count"] for t in accepted]))
        record_property(f"{hand}_median_active_taxels", median)
        assert median >= 6
        assert {a["region"] for t in accepted for a in t["touch"]["active"]} == {"tip", "pulp", "palm"}
    for r in runs:
        counts = [t["touch"]["active_count"] for t in r.accepted]
        assert float(np.median(counts or [0])) == r.metrics["active_taxels_median"]


def test_touch_timing_is_reported(runs: list[Run]) -> None:
    # The read-out's cost is measured by `python -m vint_engines.study.touch`, not asserted here.
    for r in runs:
        assert 0 < r.metrics["touch_ms"] < r.metrics["trials_ms"]


def test_too_few_active_taxels_reject_the_grasp(engine: GraspEngine, tmp_path: Path) -> None:
    doc, _ = run(
        engine, grasp_params("tomato_soup_can", "allegro", SEEDS[:2], min_active_taxels=10_000), tmp_path
    )
    assert [t["reason"] for t in doc["trials"]] == ["no_touch", "no_touch"]


@pytest.mark.parametrize(
    "bad",
    [
        {"contact_margin_m": -0.001},
        {"footprint_radius_m": 0.006},
        {"contact_window_s": -0.001},
        {"activation_force_n": -0.1},
        {"half_force_n": 0.0},
        {"response_exponent": 5.0},
        {"aging": [1.0, 1.5]},
        {"aging": [0.9, 0.5]},
        {"aging": 0.5},
        {"position_sigma_m": -0.0001},
        {"position_sigma_m": 0.003},
        {"gain_sigma": -0.1},
        {"min_active_taxels": -1},
        {"gain_seed": "x"},
        {"sensing_depth_m": 0.003},
    ],
)
def test_impossible_touch_parameters_are_bad_input(engine: GraspEngine, tmp_path: Path, bad: dict) -> None:
    with pytest.raises(BadInput, match=r"params\.touch"):
        engine.run(TaskRequest("t", grasp_params("mug", "trx3", SEEDS[:1], **bad), (), tmp_path))


def test_distances_work_for_every_object_geom_type() -> None:
    """Convex mesh pieces, boxes and capsules (and unions of them) all measure like their shapes."""
    spec = mujoco.MjSpec()
    corners = [[x, y, z] for x in (-0.02, 0.02) for y in (-0.02, 0.02) for z in (-0.02, 0.02)]
    spec.add_mesh(name="cube", uservert=np.array(corners).ravel().tolist())
    body = spec.worldbody.add_body(name="object", pos=[0.1, 0.0, 0.1], quat=[0.9, 0.1, 0.2, 0.3])
    body.add_freejoint()
    body.add_geom(name="mesh", type=mujoco.mjtGeom.mjGEOM_MESH, meshname="cube")
    body.add_geom(name="box", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.02, 0.02, 0.02], pos=[0, 0, 0.1])
    body.add_geom(name="capsule", type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=[0.01, 0.02, 0], pos=[0, 0.1, 0])
    add_touch_probe(spec)
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    rng = np.random.default_rng(7)
    cap = 0.005
    for name in ("mesh", "box", "capsule"):
        geom = model.geom(name).id
        local = rng.uniform(-0.03, 0.03, size=(1500, 3))
        world = local @ data.geom_xmat[geom].reshape(3, 3).T + data.geom_xpos[geom]
        if name == "capsule":
            axis = np.clip(local[:, 2], -0.02, 0.02)
            truth = np.linalg.norm(local - np.outer(axis, [0, 0, 1]), axis=1) - 0.01
        else:
            excess = np.abs(local) - 0.02
            truth = np.linalg.norm(np.maximum(excess, 0), axis=1) + np.minimum(excess.max(axis=1), 0)
        measured = object_distances(model, data, model.geom(TOUCH_PROBE).id, [geom], world, cap)
        near = truth < cap - 1e-6
        assert (truth < 0).any() and near.sum() > 100
        assert measured[near] == pytest.approx(truth[near], abs=2e-6), name
        assert (measured[truth > cap + 1e-6] >= cap).all(), name
