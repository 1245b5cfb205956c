"""The dataset statistics (`python -m vint_engines stats`) on a small synthetic dataset built here,
written once in the native layout and once in the BOP layout, whose every count is known by
construction: the expected numbers below are written out by hand, not computed by the module."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import ENGINES_DIR
from geometry import quat_multiply

from vint_engines.stats import dataset, numbers
from vint_engines.stats import hand as palm_frame

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
FIGURES = (
    "occlusion.png",
    "orientation.png",
    "distance.png",
    "taxels.png",
    "acceptance.png",
    "in_hand.png",
    "camera_palm.png",
    "counts.png",
)


def rotation(axis: str, degrees: float) -> np.ndarray:
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    return {
        "x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
        "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
        "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]),
    }[axis]


def pose(
    azimuth_deg: float, elevation_deg: float, distance_m: float, roll_deg: float
) -> tuple[np.ndarray, np.ndarray]:
    """(R_m2c, t_m2c) of a camera at `distance_m` from the object's origin in the direction
    (azimuth, elevation) of the object frame; the camera's own orientation is arbitrary (it must
    not change the viewing direction), here a fixed turn."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    centre = distance_m * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    R = rotation("z", roll_deg) @ rotation("x", 110.0) @ rotation("y", 25.0)
    return R, -R @ centre


# (object, hand, grasp index, active taxel regions, [views: (occlusion, azimuth, elevation, distance)])
GRASPS: list[tuple[str, str, int, list[str], list[tuple[float, float, float, float]]]] = [
    ("mug", "trx3", 0, ["tip", "tip", "pulp", "palm"], [(0.0, 10.0, 5.0, 0.363), (0.3, 100.0, 50.0, 0.412)]),
    ("mug", "trx3", 3, ["tip", "palm", "palm"], [(0.05, -170.0, -80.0, 0.444), (1.0, 10.0, 5.0, 0.487)]),
    ("mug", "allegro", 1, [], [(0.55, 10.0, 5.0, 0.352)]),
    ("can", "allegro", 2, ["pulp"] * 5 + ["tip"], [(0.999, 170.0, 80.0, 0.471), (0.1, 45.0, 20.0, 0.405)]),
]
OCCLUSION_COUNTS = [2, 1, 0, 1, 0, 1, 0, 0, 0, 2]  # 0, 0.05 | 0.1 | 0.3 | 0.55 | 0.999, 1.0
PAIRS = [
    {
        "object": "mug",
        "hand": "trx3",
        "trials": 5,
        "accepted": 2,
        "rejected": {"dropped": 2, "no_contact": 1},
    },
    {"object": "mug", "hand": "allegro", "trials": 3, "accepted": 1, "rejected": {"dropped": 2}},
    {"object": "can", "hand": "allegro", "trials": 1, "accepted": 1, "rejected": {}},
]
# As an export writes them: a built-in object's own id (never ycbv's), a user's object from 1001.
OBJECTS = [
    {
        "name": "mug",
        "obj_id": 114,
        "model_source": "procedural",
        "stand_in_for": {"dataset": "ycbv", "obj_id": 14, "ycb_id": "025"},
    },
    {"name": "can", "obj_id": 1001, "model_source": "user", "stand_in_for": None},
]


# Per grasp (by index): the object's pose in the palm frame as built — origin in mm, rotation as an
# axis and angle — the grasp type (None: a record from before types) and the palm's world pose
# (axis, angle, position m), all chosen by hand. With the views above, the camera centre's palm-z
# is (R c)_z + t_z, c the camera centre in the object frame: grasp 0 (R = Rz 30°) sees the front
# twice; grasp 3 (Rx -90°: (R c)_z = -c_y) the front from (-170°, -80°) (+0.0134 + 0.060 m) and the
# back from (10°, 5°) (-0.0842 + 0.060 m); grasp 1 (R = I) the front; grasp 2 (Ry 180°: -c_z) the
# back twice.
IN_PALM: dict[int, tuple[tuple[float, float, float], tuple[float, float, float], float]] = {
    0: ((10.0, -5.0, 45.0), (0.0, 0.0, 1.0), 30.0),
    3: ((-20.0, 15.0, 60.0), (1.0, 0.0, 0.0), -90.0),
    1: ((0.0, 0.0, 50.0), (0.0, 0.0, 1.0), 0.0),
    2: ((5.0, -10.0, 40.0), (0.0, 1.0, 0.0), 180.0),
}
GRASP_TYPES = {0: "power", 3: "precision", 1: None, 2: "power"}
PALM_IN_WORLD = {i: ((1.0, 2.0, 3.0), 0.7 + i, (0.1 * i, -0.05, 0.2 + 0.01 * i)) for i in range(4)}
ENVIRONMENTS = ("studio", "forest")  # view v of grasp index i: ENVIRONMENTS[(i + v) % 2]


def axis_angle_quat(axis: tuple[float, float, float], degrees: float) -> np.ndarray:
    """The test's own unit quaternion (w, x, y, z) of a turn about `axis`."""
    half = math.radians(degrees) / 2.0
    u = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    return np.array([math.cos(half), *(math.sin(half) * u)])


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """v turned by q, as q ⊗ (0, v) ⊗ q* — no rotation matrix involved."""
    conjugate = q * np.array([1.0, -1.0, -1.0, -1.0])
    return quat_multiply(quat_multiply(q, np.array([0.0, *v])), conjugate)[1:]


def rodrigues(axis: tuple[float, float, float], degrees: float) -> np.ndarray:
    """Rotation matrix of a turn about `axis` (Rodrigues' formula)."""
    u = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    k = np.array([[0, -u[2], u[1]], [u[2], 0, -u[0]], [-u[1], u[0], 0]])
    a = math.radians(degrees)
    return np.eye(3) + math.sin(a) * k + (1 - math.cos(a)) * k @ k


def world_poses(index: int) -> dict[str, Any]:
    """The palm's and the object's world poses (p, q) and rotations for grasp `index`: the palm
    where PALM_IN_WORLD puts it, the object at IN_PALM's pose in the palm frame."""
    t_op, axis_op, angle_op = IN_PALM[index]
    axis_p, angle_p, p_palm = PALM_IN_WORLD[index]
    q_palm = axis_angle_quat(axis_p, math.degrees(angle_p))
    q_object = quat_multiply(q_palm, axis_angle_quat(axis_op, angle_op))
    p_object = np.asarray(p_palm) + quat_rotate(q_palm, 1e-3 * np.asarray(t_op))
    return {
        "palm": {"p": list(p_palm), "q": q_palm.tolist()},
        "object": {"p": p_object.tolist(), "q": q_object.tolist()},
        "R_palm": rodrigues(axis_p, math.degrees(angle_p)),
        "R_object": rodrigues(axis_p, math.degrees(angle_p)) @ rodrigues(axis_op, angle_op),
        "p_palm": np.asarray(p_palm),
        "p_object": p_object,
    }


def camera_of(index: int, R_m2c: np.ndarray, t_m2c: np.ndarray) -> dict[str, np.ndarray]:
    """The world-to-camera transform implied by the object's pose in the camera and in the world,
    and the palm's pose in the camera."""
    poses = world_poses(index)
    R_w2c = R_m2c @ poses["R_object"].T
    t_w2c = t_m2c - R_w2c @ poses["p_object"]
    return {
        "R_w2c": R_w2c,
        "t_w2c": t_w2c,
        "R_palm_c": R_w2c @ poses["R_palm"],
        "t_palm_c": R_w2c @ poses["p_palm"] + t_w2c,
    }


def environment(index: int, view: int) -> dict[str, Any]:
    return {"name": ENVIRONMENTS[(index + view) % 2], "rotation_deg": 0.0, "strength": 1.0}


def grasp_id(obj: str, hand: str, index: int) -> str:
    return f"{obj}.{hand}.g{index:06d}"


def touch_entries(regions: list[str]) -> list[dict[str, Any]]:
    return [
        {
            "taxel": i,
            "link": "l",
            "region": r,
            "p_palm": [0, 0, 0],
            "n_palm": [0, 0, 1],
            "reading": 0.5,
            "force_n": 1,
        }
        for i, r in enumerate(regions)
    ]


def write_json(path: Path, doc: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc), encoding="utf-8")


def write_native(root: Path) -> Path:
    write_json(
        root / "dataset.json", {"format": "vint-native", "version": 1, "objects": OBJECTS, "pairs": PAIRS}
    )
    for obj, hand, index, regions, views in GRASPS:
        gid = grasp_id(obj, hand, index)
        poses = world_poses(index)
        trial: dict[str, Any] = {"hand_pose": poses["palm"], "object_pose": poses["object"]}
        if GRASP_TYPES[index] is not None:
            trial["grasp"] = {"type": GRASP_TYPES[index]}
        record = {
            "grasp_id": gid,
            "object": {"name": obj},
            "hand": {"name": hand},
            "touch": {"active": touch_entries(regions)},
            "trial": trial,
        }
        write_json(root / gid / "grasp.json", record)
        for v, (occ, az, el, dist) in enumerate(views):
            R, t = pose(az, el, dist, roll_deg=37.0 * v)
            camera = camera_of(index, R, t)
            meta = {
                "sample_id": f"{gid}.v{v:02d}",
                "grasp_id": gid,
                "object": {"name": obj},
                "hand": hand,
                "camera": {
                    "R_m2c": R.tolist(),
                    "t_m2c": t.tolist(),
                    "R_w2c": camera["R_w2c"].tolist(),
                    "t_w2c": camera["t_w2c"].tolist(),
                    "environment": environment(index, v),
                },
                "poses": {"hand": poses["palm"], "object": poses["object"]},
                "visibility": {"occlusion": occ},
            }
            write_json(root / f"{gid}.v{v:02d}" / "meta.json", meta)
    return root


def write_bop(root: Path) -> Path:
    """The same grasps as BOP scenes: one scene per grasp (split by position), mm translations,
    9-number rotations, touch and hand beside them."""
    write_json(
        root / "dataset.json", {"format": "vint-bop", "version": 1, "objects": OBJECTS, "pairs": PAIRS}
    )
    obj_ids = {o["name"]: o["obj_id"] for o in OBJECTS}
    for scene_id, (obj, hand, index, regions, views) in enumerate(
        sorted(GRASPS, key=lambda g: grasp_id(*g[:3]))
    ):
        gid = grasp_id(obj, hand, index)
        scene = root / ("train", "val", "test", "train")[scene_id] / f"{scene_id:06d}"
        gt, meta, touch, hands = {}, {}, {}, {}
        for v, (occ, az, el, dist) in enumerate(views):
            R, t = pose(az, el, dist, roll_deg=37.0 * v)
            gt[str(v)] = [
                {"cam_R_m2c": R.reshape(9).tolist(), "cam_t_m2c": (1000 * t).tolist(), "obj_id": obj_ids[obj]}
            ]
            meta[str(v)] = {
                "sample_id": f"{gid}.v{v:02d}",
                "grasp_id": gid,
                "occlusion": occ,
                "environment": environment(index, v),
            }
            if scene_id % 2 == 0:  # the hand in scene_meta, or only in scene_hand
                meta[str(v)]["hand"] = hand
            touch[str(v)] = {"active": touch_entries(regions), "readings": []}
            camera = camera_of(index, R, t)
            palm = {"R": camera["R_palm_c"].reshape(9).tolist(), "t_mm": (1000 * camera["t_palm_c"]).tolist()}
            hands[str(v)] = {"hand": hand, "joints": {}, "link_poses_cam": {"palm": palm}}
        for name, doc in (("gt", gt), ("meta", meta), ("touch", touch), ("hand", hands)):
            write_json(scene / f"scene_{name}.json", doc)
    return root


@pytest.fixture(scope="module")
def native(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_native(tmp_path_factory.mktemp("native"))


@pytest.fixture(scope="module")
def bop(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_bop(tmp_path_factory.mktemp("bop"))


def run_stats(dataset_dir: Path, out: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ENGINES_DIR)}
    command = [
        sys.executable,
        "-m",
        "vint_engines",
        "stats",
        "--dataset",
        str(dataset_dir),
        "--out",
        str(out),
        *extra,
    ]
    return subprocess.run(command, env=env, capture_output=True, text=True, timeout=120)


def test_occlusion_bins_are_tenths_closed_on_the_left_with_one_in_the_last() -> None:
    cases = {0.0: 0, 0.099999: 0, 0.1: 1, 0.3: 3, 0.7: 7, 0.9: 9, 0.95: 9, 1.0: 9}
    assert {x: numbers.occlusion_bin(x) for x in cases} == cases


def test_both_layouts_are_detected(native: Path, bop: Path) -> None:
    assert dataset.read(native).layout == "native"
    assert dataset.read(bop).layout == "bop"


def test_counts_equal_the_dataset_as_constructed(native: Path) -> None:
    stats = numbers.compute(dataset.read(native))
    assert stats["counts"] == {"samples": 7, "grasps": 4, "objects": 2, "hands": 2}
    assert stats["objects"] == ["can", "mug"] and stats["hands"] == ["allegro", "trx3"]

    occ = stats["occlusion"]
    assert occ["counts"] == OCCLUSION_COUNTS
    assert occ["by_hand"]["trx3"] == [2, 0, 0, 1, 0, 0, 0, 0, 0, 1]
    assert occ["by_hand"]["allegro"] == [0, 1, 0, 0, 0, 1, 0, 0, 0, 1]
    assert occ["summary"]["mean"] == pytest.approx((0 + 0.3 + 0.05 + 1 + 0.55 + 0.999 + 0.1) / 7, abs=1e-6)
    assert occ["summary"]["max"] == 1.0 and occ["summary"]["min"] == 0.0

    dist = stats["distance_m"]
    # 0.352-0.487 m: 1 cm bins from 0.35 (14 of them, within the 20 allowed).
    assert dist["edges"] == pytest.approx([0.35 + 0.01 * k for k in range(15)])
    by_bin = {k: n for k, n in enumerate(dist["counts"]) if n}
    assert by_bin == {0: 1, 1: 1, 5: 1, 6: 1, 9: 1, 12: 1, 13: 1}
    assert dist["summary"]["p50"] == pytest.approx(0.412, abs=1e-9)

    orient = stats["orientation"]
    # Cells (band by sin(elevation) in sixths from -1, sector by 30° of azimuth from -180°):
    # (10°, 5°) ×3 → band 3, sector 6; (100°, 50°) → sin 0.766: band 5, sector 9;
    # (-170°, -80°) → band 0, sector 0; (170°, 80°) → band 5, sector 11;
    # (45°, 20°) → sin 0.342: band 4, sector 7.
    seen = {(b, s): n for b, row in enumerate(orient["counts"]) for s, n in enumerate(row) if n}
    assert seen == {(3, 6): 3, (5, 9): 1, (0, 0): 1, (5, 11): 1, (4, 7): 1}
    assert orient["cells"] == 72 and orient["cells_seen"] == 5
    assert orient["by_object"]["mug"] == {
        "samples": 5,
        "cells_seen": 3,
        "coverage": pytest.approx(3 / 72, abs=1e-6),
    }
    assert orient["elevation_deg"]["max"] == pytest.approx(80.0, abs=1e-6)

    tax = stats["taxels"]
    assert tax["regions"] == ["tip", "pulp", "palm"]
    trx3, allegro = tax["by_hand"]["trx3"], tax["by_hand"]["allegro"]
    assert trx3["grasps"] == 2 and allegro["grasps"] == 2
    assert (trx3["active"]["min"], trx3["active"]["max"], trx3["active"]["mean"]) == (3, 4, 3.5)
    assert (allegro["active"]["min"], allegro["active"]["max"], allegro["active"]["mean"]) == (0, 6, 3.0)
    assert {r: trx3["regions"][r]["total"] for r in tax["regions"]} == {"tip": 3, "pulp": 1, "palm": 3}
    assert {r: allegro["regions"][r]["total"] for r in tax["regions"]} == {"tip": 1, "pulp": 5, "palm": 0}
    assert (
        trx3["regions"]["pulp"]["grasps_touching"] == 1 and allegro["regions"]["palm"]["grasps_touching"] == 0
    )

    pairs = stats["pairs"]
    assert pairs["reasons"] == ["dropped", "no_contact"]
    mug_trx3 = next(p for p in pairs["pairs"] if (p["object"], p["hand"]) == ("mug", "trx3"))
    assert mug_trx3 == {
        "object": "mug",
        "hand": "trx3",
        "trials": 5,
        "accepted": 2,
        "acceptance": 0.4,
        "rejected": {"dropped": 2, "no_contact": 1},
    }
    assert pairs["total"] == {
        "trials": 9,
        "accepted": 4,
        "acceptance": pytest.approx(4 / 9, abs=1e-6),
        "rejected": {"dropped": 4, "no_contact": 1},
    }


def test_the_camera_roll_does_not_move_the_viewing_direction() -> None:
    views = [
        dataset.View("s", "g", "o", "h", 0.0, *pose(33.0, -21.0, 0.4, roll_deg=roll))
        for roll in (0.0, 90.0, 211.0)
    ]
    for view in views:
        azimuth, elevation = numbers.azimuth_elevation_deg(numbers.viewing_direction(view))
        assert (azimuth, elevation) == pytest.approx((33.0, -21.0), abs=1e-9)


def assert_close(a: Any, b: Any, tolerance: float, at: str) -> None:
    """Equal structures, numbers within `tolerance`."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and list(a) == list(b), at
        for key in a:
            assert_close(a[key], b[key], tolerance, f"{at}.{key}")
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), at
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_close(x, y, tolerance, f"{at}[{i}]")
    elif isinstance(a, float) and not isinstance(b, str):
        assert b == pytest.approx(a, abs=tolerance), at
    else:
        assert a == b, at


def test_the_in_hand_position_is_the_palm_frame_position_recomputed_from_the_record(native: Path) -> None:
    """One grasp's object origin in the palm frame, recomputed from its grasp.json poses with the
    test's own quaternion code (q* ⊗ (p_object - p_palm) ⊗ q), equals the one built in and the
    module's; its z-axis cosine is R[2, 2] of the turn built in."""
    gid = grasp_id("mug", "trx3", 3)
    record = json.loads((native / gid / "grasp.json").read_text(encoding="utf-8"))
    palm, obj = record["trial"]["hand_pose"], record["trial"]["object_pose"]
    q_palm = np.asarray(palm["q"])
    conjugate = q_palm * np.array([1.0, -1.0, -1.0, -1.0])
    in_palm_mm = 1000 * quat_rotate(conjugate, np.asarray(obj["p"]) - np.asarray(palm["p"]))
    assert in_palm_mm == pytest.approx([-20.0, 15.0, 60.0], abs=1e-9)

    (grasp,) = [g for g in dataset.read(native).grasps if g.grasp_id == gid]
    assert palm_frame.object_position_mm(grasp) == pytest.approx(in_palm_mm, abs=1e-9)
    # Rx(-90°) takes the object's z to the palm's +y: at right angles to the palm normal.
    assert palm_frame.object_z_cos(grasp) == pytest.approx(0.0, abs=1e-12)


def test_in_hand_and_camera_statistics_equal_the_dataset_as_constructed(native: Path) -> None:
    stats = numbers.compute(dataset.read(native))
    pose = stats["in_hand"]
    assert pose["grasps_without_pose"] == 0 and pose["all"]["grasps"] == 4
    # z of the object origins: trx3 45 and 60 mm, allegro 50 and 40 mm.
    assert pose["by_hand"]["trx3"]["z_mm"]["mean"] == pytest.approx(52.5, abs=1e-6)
    assert pose["by_hand"]["allegro"]["z_mm"]["mean"] == pytest.approx(45.0, abs=1e-6)
    assert pose["by_object"]["mug"]["x_mm"]["min"] == pytest.approx(-20.0, abs=1e-6)
    assert pose["all"]["distance_mm"]["max"] == pytest.approx(math.sqrt(20**2 + 15**2 + 60**2), abs=1e-6)
    # cos(object z, palm normal): Rz 30° → 1, Rx -90° → 0, I → 1, Ry 180° → -1.
    cosines = pose["all"]["object_z_cos"]
    assert (cosines["min"], cosines["max"], cosines["mean"]) == pytest.approx((-1.0, 1.0, 0.25), abs=1e-9)
    can = next(p for p in pose["by_pair"] if (p["object"], p["hand"]) == ("can", "allegro"))
    assert can["grasps"] == 1 and can["y_mm"]["p50"] == pytest.approx(-10.0, abs=1e-6)

    cam = stats["camera_palm"]
    assert (cam["all"]["front"], cam["all"]["back"]) == (4, 3)
    assert (cam["by_hand"]["trx3"]["front"], cam["by_hand"]["trx3"]["back"]) == (3, 1)
    assert (cam["by_hand"]["allegro"]["front"], cam["by_hand"]["allegro"]["back"]) == (1, 2)
    assert sum(cam["all"]["counts"]) == 7 and sum(cam["all"]["counts"][:5]) == 3


def test_palm_facing_is_the_cosine_of_the_palm_normal_and_the_camera_direction(native: Path) -> None:
    """Every view's palm_facing, recomputed from meta.json's palm pose and camera with quaternion
    rotation: the camera centre in the world, then in the palm frame."""
    for view in dataset.read(native).views:
        meta = json.loads((native / view.sample_id / "meta.json").read_text(encoding="utf-8"))
        R_w2c, t_w2c = np.asarray(meta["camera"]["R_w2c"]), np.asarray(meta["camera"]["t_w2c"])
        centre_world = -R_w2c.T @ t_w2c
        palm = meta["poses"]["hand"]
        conjugate = np.asarray(palm["q"]) * np.array([1.0, -1.0, -1.0, -1.0])
        centre_palm = quat_rotate(conjugate, centre_world - np.asarray(palm["p"]))
        expected = centre_palm[2] / np.linalg.norm(centre_palm)
        assert palm_frame.palm_facing(view) == pytest.approx(expected, abs=1e-9), view.sample_id


def test_grasp_types_and_counts_per_object_and_environment(native: Path) -> None:
    stats = numbers.compute(dataset.read(native))
    assert stats["grasp_types"] == {
        "types": ["power", "precision", "unknown"],
        "counts": {"power": 2, "precision": 1, "unknown": 1},
        "by_hand": {
            "allegro": {"power": 1, "precision": 0, "unknown": 1},
            "trx3": {"power": 1, "precision": 1, "unknown": 0},
        },
    }
    assert stats["per_object"] == {
        "can": {
            "grasps": 1,
            "samples": 2,
            "by_hand": {"allegro": {"grasps": 1, "samples": 2}, "trx3": {"grasps": 0, "samples": 0}},
        },
        "mug": {
            "grasps": 3,
            "samples": 5,
            "by_hand": {"allegro": {"grasps": 1, "samples": 1}, "trx3": {"grasps": 2, "samples": 4}},
        },
    }
    # (grasp index + view) even → studio: mug/trx3 0 (v0), mug/trx3 3 (v1), can/allegro 2 (v0).
    assert stats["per_environment"] == {
        "forest": {"samples": 4, "by_hand": {"allegro": 2, "trx3": 2}},
        "studio": {"samples": 3, "by_hand": {"allegro": 1, "trx3": 2}},
    }


def test_a_record_without_poses_or_types_marks_them_unavailable_or_unknown(tmp_path: Path) -> None:
    """An export from before palm poses and grasp types: the pose statistics are None, the type
    "unknown", the environment "unknown" — nothing invented."""
    gid = "mug.trx3.g000000"
    write_json(
        tmp_path / gid / "grasp.json",
        {"grasp_id": gid, "object": {"name": "mug"}, "hand": {"name": "trx3"}, "touch": {"active": []}},
    )
    R, t = pose(10.0, 5.0, 0.4, 0.0)
    meta = {
        "sample_id": f"{gid}.v00",
        "grasp_id": gid,
        "object": {"name": "mug"},
        "hand": "trx3",
        "camera": {"R_m2c": R.tolist(), "t_m2c": t.tolist()},
        "visibility": {"occlusion": 0.2},
    }
    write_json(tmp_path / f"{gid}.v00" / "meta.json", meta)
    stats = numbers.compute(dataset.read(tmp_path))
    assert stats["in_hand"] is None and stats["camera_palm"] is None
    assert stats["grasp_types"]["counts"] == {"unknown": 1}
    assert stats["per_environment"] == {"unknown": {"samples": 1, "by_hand": {"trx3": 1}}}


def test_native_and_bop_layouts_give_the_same_stats(native: Path, bop: Path) -> None:
    from_native = numbers.compute(dataset.read(native))
    from_bop = numbers.compute(dataset.read(bop))
    assert from_native.pop("layout") == "native" and from_bop.pop("layout") == "bop"
    # BOP stores millimetres: distances agree to float rounding, not bit for bit.
    dist_native, dist_bop = from_native.pop("distance_m"), from_bop.pop("distance_m")
    assert dist_native["counts"] == dist_bop["counts"]
    assert dist_native["summary"]["mean"] == pytest.approx(dist_bop["summary"]["mean"], abs=1e-9)
    # The palm's pose comes from grasp.json and meta.json in one, scene_hand.json in the other.
    for key in ("in_hand", "camera_palm"):
        assert_close(from_native.pop(key), from_bop.pop(key), 1e-6, key)
    # BOP's files carry no grasp type: unavailable there, not invented.
    assert from_bop.pop("grasp_types") is None and from_native.pop("grasp_types") is not None
    assert from_native == from_bop


def test_the_command_writes_figures_table_and_numbers_deterministically(native: Path, tmp_path: Path) -> None:
    first, second = tmp_path / "a", tmp_path / "b"
    done = run_stats(native, first, "--json")
    assert done.returncode == 0, done.stderr[-4000:]
    assert run_stats(native, second).returncode == 0
    for name in FIGURES:
        png = (first / name).read_bytes()
        assert png[:8] == PNG_SIGNATURE, name
        assert b"matplotlib" not in png, f"{name} carries a software stamp"
        assert png == (second / name).read_bytes(), f"{name} differs between two runs"
    written = json.loads((first / "stats.json").read_text(encoding="utf-8"))
    assert json.loads(done.stdout) == written
    assert written["occlusion"]["counts"] == OCCLUSION_COUNTS
    table = (first / "stats.md").read_text(encoding="utf-8")
    assert "| [90, 100] | 2 | 28.6 % | 1 | 1 |" in table  # 2 of 7 samples; allegro 1, trx3 1
    assert "| mug | trx3 | 5 | 2 | 40.0 % | 2 | 1 |" in table
    assert (first / "stats.md").read_bytes() == (second / "stats.md").read_bytes()


def test_a_directory_that_is_no_dataset_exits_2_saying_why(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    done = run_stats(tmp_path / "empty", tmp_path / "out")
    assert done.returncode == 2
    assert "neither a native dataset" in done.stderr
