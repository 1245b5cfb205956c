"""Users' own hands (MJCF + taxel layout) and mesh objects, as a spec names them: the conventions of
docs/hands.md are checked with clean errors, and the example assets of examples/custom.toml grasp
with touch through the same engine as the built-in hands and objects."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import pytest

from vint_engines.grasp.engine import GraspEngine
from vint_engines.grasp.hands import TRX3, load_mjcf_hand
from vint_engines.grasp.skin import generate_layout
from vint_engines.grasp.taxels import layout_differences, parse_layout, read_layout
from vint_engines.objects import ObjectSpec, build_model
from vint_engines.protocol import BadInput, InputRef, TaskRequest

ASSETS = Path(__file__).resolve().parents[3] / "examples" / "assets"
GRIPPER = (ASSETS / "gripper.xml").read_text(encoding="utf-8")


def load(xml: str) -> Any:
    return load_mjcf_hand("mine", xml, "params.hand.mjcf")


def test_the_example_gripper_follows_the_conventions() -> None:
    hand = load(GRIPPER)
    assert hand.link_names() == ["palm", "left_prox", "left_tip", "right_prox", "right_tip"]
    assert hand.joint_names() == ["left_j0", "left_j1", "right_j0", "right_j1"]
    assert (hand.dof, hand.finger_count) == (4, 2)
    assert hand.palm_half == pytest.approx((0.05, 0.03, 0.012))
    assert hand.open_pose() == [-0.25, 0.1, -0.25, 0.1]
    assert hand.close_phases() == [0.0, 1.0, 0.0, 1.0]
    assert hand.reach() == pytest.approx(0.05 + 0.04 + 0.01)
    assert hand.fingertips() == ["left_tip", "right_tip"]


def test_open_and_closed_poses_default_to_the_actuators_control_ranges() -> None:
    xml = GRIPPER.replace('<numeric name="vint_open" data="-0.25 0.1 -0.25 0.1"/>', "")
    assert load(xml).open_pose() == [-0.5, 0.0, -0.5, 0.0]


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (('<body name="palm">', '<body name="hand">'), "no body named 'palm'"),
        (
            ('<position joint="left_j1" ctrlrange="0 1.9" forcerange="-0.8 0.8"/>', ""),
            "'left_j1' must be driven",
        ),
        (
            ("<worldbody>", '<asset><mesh name="m" file="finger.stl"/></asset><worldbody>'),
            "mesh 'm' names 'finger.stl', which the task did not stage",
        ),
        (
            ('<joint name="left_j0" range="-0.5 1.6"/>', '<joint name="left_j0" type="slide" range="0 1"/>'),
            "not a hinge",
        ),
        (
            (
                'joint="left_j0" ctrlrange="-0.5 1.6" forcerange="-1.2 1.2"',
                'joint="left_j0" forcelimited="false"',
            ),
            "needs a force limit",
        ),
        (
            ("</worldbody>", '<body name="table"><geom size=".1 .1 .1" type="box"/></body></worldbody>'),
            "exactly one",
        ),
        (('<numeric name="vint_open"', '<numeric name="vint_opne"'), "unknown custom numeric 'vint_opne'"),
        (('data="1.5 1.7 1.5 1.7"', 'data="1.5 1.7 1.5 2.7"'), "outside its range"),
        (("<mujoco", "<mujoc"), "not a valid MJCF model"),
    ],
)
def test_a_convention_violation_is_bad_input_naming_it(change: tuple[str, str], message: str) -> None:
    old, new = change
    assert old in GRIPPER
    with pytest.raises(BadInput, match=r"params\.hand\.mjcf") as error:
        load(GRIPPER.replace(old, new, 1))
    assert message in str(error.value)


def test_a_general_actuator_written_as_a_position_servo_is_one() -> None:
    """As some Menagerie hands write them: gain kp, affine bias 0 -kp -kv, with a force limit."""
    old = '<position joint="left_j0" ctrlrange="-0.5 1.6" forcerange="-1.2 1.2"/>'
    general = (
        '<general joint="left_j0" ctrlrange="-0.5 1.6" ctrllimited="true" forcerange="-1.2 1.2" '
        'forcelimited="true" biastype="affine" gainprm="6" biasprm="0 -6 -0.1"/>'
    )
    assert old in GRIPPER
    assert load(GRIPPER.replace(old, general)).dof == 4
    with pytest.raises(BadInput, match="must be a position actuator"):
        load(GRIPPER.replace(old, general.replace('biasprm="0 -6 -0.1"', 'biasprm="0 -3 -0.1"')))


def test_the_taxel_layout_is_checked_against_the_models_bodies() -> None:
    hand = load(GRIPPER)
    text = (ASSETS / "gripper_taxels.csv").read_text(encoding="utf-8")
    assert len(parse_layout(text, hand.link_names(), "gripper_taxels.csv")) == 240
    lines = text.splitlines()
    lines[5] = lines[5].replace("palm", "thumb", 1)
    with pytest.raises(BadInput, match=r"line 6: unknown link 'thumb'"):
        parse_layout("\n".join(lines), hand.link_names(), "gripper_taxels.csv")


def test_the_committed_example_layout_is_what_the_generator_makes() -> None:
    """By the rule the built-in layouts follow (`layout_differences`: same taxels, last digit)."""
    hand = load_mjcf_hand("gripper", GRIPPER, "gripper.xml")
    committed = read_layout(ASSETS / "gripper_taxels.csv", hand.link_names())
    assert layout_differences(committed, generate_layout(hand, 240)) == []


def test_built_in_hands_answer_the_same_questions() -> None:
    assert TRX3.reach() == pytest.approx(0.045 + 0.035 + 0.025 + 0.010)
    assert TRX3.close_phases()[:3] == [0.0, 0.5, 1.0]
    assert TRX3.fingertips() == ["f0_tip", "f1_tip", "f2_tip"]


def cup_entry(sha: str) -> dict[str, Any]:
    return {
        "name": "cup",
        "ycb_id": "",
        "mass_kg": 0.15,
        "material": "ceramic",
        "texture": {"kind": "plain"},
        "symmetries_continuous": [{"axis": [0.0, 0.0, 1.0], "offset": [0.0, 0.0, 0.0]}],
        "symmetries_discrete": [],
        "description": "user mesh assets/cup.obj",
        "shape": {"type": "mesh", "asset": sha, "scale": 0.001},
    }


def test_a_mesh_asset_builds_a_model_in_metres_and_round_trips() -> None:
    path = ASSETS / "cup.obj"
    sha = hashlib.sha256(path.read_bytes()).hexdigest()
    spec = ObjectSpec.parse(cup_entry(sha))
    assert spec.to_json() == cup_entry(sha)
    model = build_model(spec, assets={sha: path})
    assert model.extent == pytest.approx([0.068, 0.068, 0.08])
    assert len(model.pieces) > 1, "a hollow cup needs several convex pieces"
    with pytest.raises(BadInput, match="was not staged"):
        build_model(spec)
    with pytest.raises(BadInput, match="not a SHA-256"):
        ObjectSpec.parse(cup_entry("abc"))


def test_a_user_hand_grasps_a_user_mesh_with_touch(tmp_path: Path) -> None:
    files = {name: ASSETS / name for name in ("gripper.xml", "gripper_taxels.csv", "cup.obj")}
    sha = {name: hashlib.sha256(path.read_bytes()).hexdigest() for name, path in files.items()}
    params = {
        "assets": [{"path": f"assets/{n}", "sha256": sha[n], "size": files[n].stat().st_size} for n in files],
        "hand": {"name": "gripper", "mjcf": sha["gripper.xml"], "taxels": sha["gripper_taxels.csv"]},
        "object": cup_entry(sha["cup.obj"]),
        # Approaches come from any side of the cup; a two-finger gripper holds it from some.
        "trials": [{"grasp_index": i, "seed": 1000 + i} for i in range(4)],
        "physics": {"hold_s": 0.3},
    }
    inputs = tuple(InputRef(sha[n], "asset", path) for n, path in files.items())
    GraspEngine().run(TaskRequest("t", params, inputs, tmp_path))
    document = json.loads((tmp_path / "grasps.json").read_text())
    assert document["hand"]["taxels"]["layout"] == "assets/gripper_taxels.csv"
    assert [link["name"] for link in document["hand"]["links"]][:2] == ["palm", "left_prox"]
    accepted = [t for t in document["trials"] if t["accepted"]]
    assert accepted, [t["reason"] for t in document["trials"]]
    assert (tmp_path / "object.ply").read_bytes().startswith(b"ply\n")

    bad = {**params, "hand": {**params["hand"], "taxels": sha["cup.obj"]}}
    with pytest.raises(BadInput, match=r"params\.hand\.taxels"):
        GraspEngine().run(TaskRequest("t", bad, inputs, tmp_path))


@pytest.mark.parametrize("obj", ["stirring_stick", "large_marker"])
def test_a_user_hand_meets_thin_objects_cleanly(tmp_path: Path, obj: str) -> None:
    """A user hand on a thin, light object ends in a recorded outcome (accepted or a rejection
    reason), never an exception."""
    from vint_engines.study.grasped import catalog_entry

    files = {name: ASSETS / name for name in ("gripper.xml", "gripper_taxels.csv")}
    sha = {name: hashlib.sha256(path.read_bytes()).hexdigest() for name, path in files.items()}
    params = {
        "assets": [{"path": f"assets/{n}", "sha256": sha[n], "size": files[n].stat().st_size} for n in files],
        "hand": {"name": "gripper", "mjcf": sha["gripper.xml"], "taxels": sha["gripper_taxels.csv"]},
        "object": catalog_entry(obj),
        "trials": [{"grasp_index": i, "seed": 2000 + i} for i in range(2)],
        "physics": {"hold_s": 0.3},
    }
    inputs = tuple(InputRef(sha[n], "asset", path) for n, path in files.items())
    GraspEngine().run(TaskRequest("t", params, inputs, tmp_path))
    trials = json.loads((tmp_path / "grasps.json").read_text())["trials"]
    assert len(trials) == 2
    for trial in trials:
        assert trial["accepted"] or trial["reason"], trial
