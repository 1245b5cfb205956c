"""The scene around the grasp, held to geometry computed here from grasps.json alone: the table top
lies `table_gap_m` below the lowest point of the hand's primitives, the object and the arm pieces
(lowest points worked out analytically per primitive), its pixels back-project onto that plane;
the arm's flange and last link sit at the hand's mount; the segmentation labels them after the
links; a camera below the table top sees no table; and the default RGB has no fireflies on the
hand or the object."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from conftest import EngineProcess, new_dir, started_engine
from geometry import distance_to_mesh, signed_distance_to_primitive

from vint_engines import depth_file
from vint_engines.grasp.engine import GraspEngine
from vint_engines.objects import build_model, load_catalog
from vint_engines.objects.meshio import read_ply_m
from vint_engines.poses import quat_to_matrix
from vint_engines.protocol import TaskRequest
from vint_engines.render.camera import look_at

SIZE = 96
RENDER = {
    "width": SIZE,
    "height": SIZE,
    "samples": 8,
    "fov_deg": 60.0,
    "environment": "studio",
    "radius_m": [0.35, 0.45],
    "elevation_deg": [20.0, 70.0],
}
OUTPUTS = ["rgb", "depth", "segmentation"]
GAP_M = 0.04
# The arm pieces as docs/rendering.md states them: (radius, length) stacked from the mount.
FLANGE = (0.0315, 0.010)
ARM_LINK = (0.0375, 0.100)


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("scene_dressing")


@pytest.fixture(scope="module", params=["trx3", "allegro"])
def grasp(request: pytest.FixtureRequest, workdir: Path) -> dict[str, Any]:
    hand = request.param
    out = new_dir(workdir, f"grasp_{hand}")
    params = {
        "object": load_catalog()["tomato_soup_can"].to_json(),
        "hand": {"name": hand},
        "trials": [{"grasp_index": i, "seed": 42 + i} for i in range(3)],
    }
    GraspEngine().run(TaskRequest("grasp", params, (), out))
    doc = json.loads((out / "grasps.json").read_text())
    trial = next(t for t in doc["trials"] if t["accepted"])
    return {"dir": out, "doc": doc, "trial": trial, "hand": hand}


@pytest.fixture(scope="module")
def engine(workdir: Path) -> Iterator[EngineProcess]:
    with started_engine("render", workdir) as process:
        yield process


def render(
    engine: EngineProcess,
    grasp: dict[str, Any],
    out: Path,
    views: list[dict],
    dataset_objects: list[str] | None = None,
    **settings: Any,
) -> None:
    params = {
        "grasp_index": grasp["trial"]["grasp_index"],
        "render": {**RENDER, **settings},
        "views": views,
        "outputs": OUTPUTS,
        **({"dataset_objects": dataset_objects} if dataset_objects else {}),
    }
    reply = engine.task(out.name, params, out, [grasp["dir"] / "grasps.json", grasp["dir"] / "object.ply"])
    assert reply["ok"] is True, reply


def load(out: Path, view: int) -> dict[str, Any]:
    prefix = out / f"v{view:02d}"
    return {
        "rgb": cv2.imread(f"{prefix}_rgb.png", cv2.IMREAD_COLOR),
        "depth": depth_file.read(Path(f"{prefix}_depth.png")),
        "segmentation": cv2.imread(f"{prefix}_segmentation.png", cv2.IMREAD_UNCHANGED),
        "camera": json.loads(Path(f"{prefix}_camera.json").read_text()),
    }


def pose(record: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    return quat_to_matrix(np.array(record["q"])), np.array(record["p"])


def lowest_z(kind: str, size: list[float], R: np.ndarray, c: np.ndarray) -> float:
    """The lowest world z of a MuJoCo primitive with world rotation R and centre c."""
    if kind == "sphere":
        return c[2] - size[0]
    if kind == "box":
        return c[2] - float(np.abs(R[2]) @ np.asarray(size))
    radius, half = size
    a_z = R[2, 2]  # the z component of the primitive's axis
    if kind == "capsule":
        return c[2] - abs(a_z) * half - radius
    return c[2] - abs(a_z) * half - radius * float(np.sqrt(max(0.0, 1.0 - a_z**2)))


def arm_cylinders(grasp: dict[str, Any]) -> list[tuple[np.ndarray, np.ndarray, float, float]]:
    """(centre, axis, radius, half length) of the flange and the arm link, in the world."""
    mount = grasp["doc"]["hand"]["mount"]
    R, t = pose(grasp["trial"]["link_poses"][mount["link"]])
    point = R @ np.array(mount["p"]) + t
    axis = R @ np.array(mount["axis"])
    flange_c = point + axis * FLANGE[1] / 2
    link_c = point + axis * (FLANGE[1] + ARM_LINK[1] / 2)
    return [(flange_c, axis, FLANGE[0], FLANGE[1] / 2), (link_c, axis, ARM_LINK[0], ARM_LINK[1] / 2)]


def expected_table_top(grasp: dict[str, Any]) -> float:
    lows = []
    poses = grasp["trial"]["link_poses"]
    for link in grasp["doc"]["hand"]["links"]:
        R_l, t_l = pose(poses[link["name"]])
        for geom in link["geoms"]:
            R_g = R_l @ quat_to_matrix(np.array(geom["q"]))
            lows.append(lowest_z(geom["type"], geom["size"], R_g, R_l @ np.array(geom["p"]) + t_l))
    for centre, axis, radius, half in arm_cylinders(grasp):
        lows.append(centre[2] - abs(axis[2]) * half - radius * float(np.sqrt(max(0.0, 1.0 - axis[2] ** 2))))
    vertices, _ = read_ply_m(grasp["dir"] / "object.ply")
    R_o, t_o = pose(grasp["trial"]["object_pose"])
    lows.append(float(((R_o @ vertices.T).T + t_o)[:, 2].min()))
    return min(lows) - GAP_M


def back_project(view: dict[str, Any], pixels: np.ndarray) -> np.ndarray:
    """World points of the given pixel mask, from depth and the camera record."""
    camera = view["camera"]
    rows, cols = np.nonzero(pixels)
    K = np.array(camera["K"])
    rays = np.linalg.inv(K) @ np.stack([cols, rows, np.ones_like(cols)]).astype(float)
    R_w2c, t_w2c = np.array(camera["R_w2c"]), np.array(camera["t_w2c"])
    return (R_w2c.T @ (rays * view["depth"][rows, cols] - t_w2c[:, None])).T


def label_ids(camera: dict[str, Any]) -> dict[str, int]:
    return {name: int(k) for k, name in camera["segmentation"].items()}


def spikes(rgb: np.ndarray) -> np.ndarray:
    """Pixels brighter by more than 0.3 (of full scale) than all 8 neighbours."""
    g = rgb.astype(np.float64).max(axis=2) / 255.0
    p = np.pad(g, 1, mode="edge")
    h, w = g.shape
    shifts = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dy or dx]
    around = [p[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w] for dy, dx in shifts]
    return (g - np.max(around, axis=0)) > 0.3


def test_table_flange_and_labels_follow_the_grasp(
    engine: EngineProcess, grasp: dict[str, Any], workdir: Path
) -> None:
    out = new_dir(workdir, f"dressed_{grasp['hand']}")
    views = [{"view_index": v, "seed": 300 + v} for v in range(3)]
    render(engine, grasp, out, views, scene={"table": True, "table_gap_m": GAP_M, "flange": True})
    links = grasp["doc"]["hand"]["links"]
    n = len(links)
    top = expected_table_top(grasp)
    seen_table = seen_arm = 0
    for v in range(3):
        view = load(out, v)
        camera = view["camera"]
        ids = label_ids(camera)
        assert (ids["arm/flange"], ids["arm/link"], ids["scene/table"]) == (2 + n, 3 + n, 4 + n)
        assert camera["scene"]["table"] is True and camera["scene"]["flange"] is True
        assert abs(camera["scene"]["table_top_z"] - top) < 0.002, (camera["scene"]["table_top_z"], top)
        seg = view["segmentation"]
        assert set(np.unique(seg)) <= set(ids.values()) | {0}
        table = seg == ids["scene/table"]
        if np.count_nonzero(table) > 20:
            seen_table += 1
            z = back_project(view, table)[:, 2]
            assert np.median(np.abs(z - top)) < 0.001 and np.percentile(np.abs(z - top), 90) < 0.002
        arm = (seg == ids["arm/flange"]) | (seg == ids["arm/link"])
        if np.count_nonzero(arm) > 10:
            seen_arm += 1
            points = back_project(view, arm)
            distance = np.min(
                [
                    np.abs(signed_distance_to_primitive(to_axis_frame(points, c, a), "cylinder", [r, h]))
                    for c, a, r, h in arm_cylinders(grasp)
                ],
                axis=0,
            )
            assert np.median(distance) < 0.001 and np.percentile(distance, 90) < 0.002
        foreground = (seg > 0) & (seg != ids["scene/table"])
        assert not np.any(spikes(view["rgb"]) & foreground), "a firefly on the hand or the object"
    assert seen_table >= 2, "the table is seen from above"
    assert seen_arm >= 1, "the arm is seen in some view"


def to_axis_frame(points: np.ndarray, centre: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Points in a frame at `centre` whose z is `axis` (x, y any perpendicular pair)."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(axis, helper)
    x /= np.linalg.norm(x)
    y = np.cross(axis, x)
    return (points - centre) @ np.stack([x, y, axis]).T


def test_without_the_scene_only_the_hand_and_object_are_labelled(
    engine: EngineProcess, grasp: dict[str, Any], workdir: Path
) -> None:
    out = new_dir(workdir, f"bare_{grasp['hand']}")
    render(engine, grasp, out, [{"view_index": 0, "seed": 300}], scene={"table": False, "flange": False})
    view = load(out, 0)
    names = set(view["camera"]["segmentation"].values())
    assert not any(name.startswith(("arm/", "scene/")) for name in names)
    assert view["camera"]["scene"] == {
        "table": False,
        "table_top_z": None,
        "flange": False,
        "distractors": [],
    }
    assert int(view["segmentation"].max()) <= 1 + len(grasp["doc"]["hand"]["links"])


def test_a_camera_below_the_table_top_sees_no_table(
    engine: EngineProcess, grasp: dict[str, Any], workdir: Path
) -> None:
    out = new_dir(workdir, f"below_{grasp['hand']}")
    _, t_o = pose(grasp["trial"]["object_pose"])
    camera = look_at(t_o + np.array([0.3, 0.1, -0.5]), t_o)
    explicit = {"R_w2c": camera.R_w2c.tolist(), "t_w2c": camera.t_w2c.tolist()}
    views = [{"view_index": 0, "seed": 5, "camera": explicit}]
    render(engine, grasp, out, views)
    view = load(out, 0)
    assert view["camera"]["scene"]["table"] is False
    table_id = label_ids(view["camera"])["scene/table"]
    assert not np.any(view["segmentation"] == table_id)


def test_distractors_stand_on_the_table_clear_of_the_grasp_where_they_are_drawn(
    engine: EngineProcess, grasp: dict[str, Any], workdir: Path
) -> None:
    """Each distractor the record lists, rebuilt from the catalog at its recorded pose: its lowest
    point on the table top, at least 2 cm from the object's mesh, every hand primitive and the arm
    pieces; the pixels labelled with it back-project onto its surface."""
    out = new_dir(workdir, f"bench_{grasp['hand']}")
    views = [{"view_index": v, "seed": 400 + v} for v in range(3)]
    scene = {"table": True, "table_gap_m": GAP_M, "flange": True, "distractors": 4}
    render(engine, grasp, out, views, scene=scene)
    catalog = load_catalog()
    first = load(out, 0)["camera"]["scene"]
    assert len(first["distractors"]) == 4, first
    assert "tomato_soup_can" not in {d["name"] for d in first["distractors"]}, "never the grasped object"
    top = first["table_top_z"]
    vertices, _ = read_ply_m(grasp["dir"] / "object.ply")
    R_o, t_o = pose(grasp["trial"]["object_pose"])
    object_points = vertices @ R_o.T + t_o
    seen = 0
    for v in range(3):
        view = load(out, v)
        camera = view["camera"]
        assert camera["scene"]["distractors"] == first["distractors"], "one bench for every view of a grasp"
        ids = label_ids(camera)
        n = len(grasp["doc"]["hand"]["links"])
        for i, stand in enumerate(camera["scene"]["distractors"]):
            assert ids[f"distractor/{stand['name']}"] == 5 + n + i
            model = build_model(catalog[stand["name"]]).mesh
            R, t = pose(stand)
            points = model.vertices @ R.T + t
            assert abs(points[:, 2].min() - top) < 1e-6, (stand["name"], points[:, 2].min(), top)
            gaps = [np.min(np.linalg.norm(points[:, None] - object_points[None], axis=2))]
            for link in grasp["doc"]["hand"]["links"]:
                R_l, t_l = pose(grasp["trial"]["link_poses"][link["name"]])
                for geom in link["geoms"]:
                    R_g = R_l @ quat_to_matrix(np.array(geom["q"]))
                    local = (points - (R_l @ np.array(geom["p"]) + t_l)) @ R_g
                    gaps.append(float(signed_distance_to_primitive(local, geom["type"], geom["size"]).min()))
            for c, a, r, h in arm_cylinders(grasp):
                gaps.append(
                    float(signed_distance_to_primitive(to_axis_frame(points, c, a), "cylinder", [r, h]).min())
                )
            assert min(gaps) > 0.0199, (stand["name"], min(gaps))
            pixels = view["segmentation"] == ids[f"distractor/{stand['name']}"]
            if np.count_nonzero(pixels) > 20:
                seen += 1
                off = distance_to_mesh(back_project(view, pixels), points, model.faces)
                assert np.median(off) < 0.001 and np.percentile(off, 90) < 0.002, (
                    stand["name"],
                    np.median(off),
                )
    assert seen >= 2, "distractors are seen"


def test_no_distractor_is_one_of_the_jobs_objects(
    engine: EngineProcess, grasp: dict[str, Any], workdir: Path
) -> None:
    """The dataset annotates its objects; one standing unannotated on the table would be a label's
    error. With every catalog object but three in the job, the bench holds only those three."""
    out = new_dir(workdir, f"excluded_{grasp['hand']}")
    free = ["banana", "foam_brick", "wood_block"]
    job = sorted(name for name in load_catalog() if name not in free)
    scene = {"table": True, "table_gap_m": GAP_M, "flange": True, "distractors": 5}
    render(engine, grasp, out, [{"view_index": 0, "seed": 500}], dataset_objects=job, scene=scene)
    standing = {stand["name"] for stand in load(out, 0)["camera"]["scene"]["distractors"]}
    assert standing == set(free), standing
