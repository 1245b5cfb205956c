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

from vint_engines.stats import dataset, numbers

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
FIGURES = ("occlusion.png", "orientation.png", "distance.png", "taxels.png", "acceptance.png")


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
        record = {
            "grasp_id": gid,
            "object": {"name": obj},
            "hand": {"name": hand},
            "touch": {"active": touch_entries(regions)},
        }
        write_json(root / gid / "grasp.json", record)
        for v, (occ, az, el, dist) in enumerate(views):
            R, t = pose(az, el, dist, roll_deg=37.0 * v)
            meta = {
                "sample_id": f"{gid}.v{v:02d}",
                "grasp_id": gid,
                "object": {"name": obj},
                "hand": hand,
                "camera": {"R_m2c": R.tolist(), "t_m2c": t.tolist()},
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
            meta[str(v)] = {"sample_id": f"{gid}.v{v:02d}", "grasp_id": gid, "occlusion": occ}
            if scene_id % 2 == 0:  # the hand in scene_meta, or only in scene_hand
                meta[str(v)]["hand"] = hand
            touch[str(v)] = {"active": touch_entries(regions), "readings": []}
            hands[str(v)] = {"hand": hand, "joints": {}, "link_poses_cam": {}}
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


def test_native_and_bop_layouts_give_the_same_stats(native: Path, bop: Path) -> None:
    from_native = numbers.compute(dataset.read(native))
    from_bop = numbers.compute(dataset.read(bop))
    assert from_native.pop("layout") == "native" and from_bop.pop("layout") == "bop"
    # BOP stores millimetres: distances agree to float rounding, not bit for bit.
    dist_native, dist_bop = from_native.pop("distance_m"), from_bop.pop("distance_m")
    assert dist_native["counts"] == dist_bop["counts"]
    assert dist_native["summary"]["mean"] == pytest.approx(dist_bop["summary"]["mean"], abs=1e-9)
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
