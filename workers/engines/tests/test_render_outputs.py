"""The render engine's per-view outputs against geometry computed independently: depth and masks
against a z-buffer of the object's model mesh, segmentation against the hand's primitives; extreme
cameras (at the pole, inside the hand, behind the palm, looking away); and the routes that skip
work (bounce pruning, no path tracing without RGB) changing no geometry pixel."""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from conftest import EngineProcess, new_dir, started_engine, trx3_grasps
from geometry import is_convex, rasterise_depth, signed_distance_to_primitive

from vint_engines.noise.engine import NoiseEngine
from vint_engines.objects import load_catalog
from vint_engines.objects.meshio import read_ply_m
from vint_engines.poses import quat_to_matrix
from vint_engines.protocol import BadInput, InputRef, TaskRequest
from vint_engines.render.camera import CameraPose, look_at

RENDER = {
    "width": 64,
    "height": 64,
    "samples": 4,
    "fov_deg": 60.0,
    "environment": "studio",
    "radius_m": [0.2, 0.25],
    "elevation_deg": [15.0, 75.0],
    # These tests hold pixels to geometry at the cameras the seeds draw first; the redraws that keep
    # occlusion in a range have their own tests (test_viewpoint.py).
    "occlusion": [0.0, 1.0],
}
ALL = ["rgb", "depth", "mask", "segmentation"]
# These tests hold depth to geometry at float precision, so they ask for float32 `.npy` depth;
# test_render.py holds the default 16-bit PNG to the float depth (within 0.05 mm).
DEPTH_FORMAT = {"depth_format": "npy"}
GEOMETRY_FILES = ("depth.npy", "mask.png", "mask_full.png", "segmentation.png")
SEEDS = (11, 12, 13)


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("render_outputs")


@pytest.fixture(scope="module")
def grasp(workdir: Path) -> dict[str, Any]:
    """An accepted grasp of the tomato soup can by trx3, from the real grasp engine."""
    out = new_dir(workdir, "grasp")
    # The pixels' geometry, not the grasp type, is under test.
    doc = trx3_grasps(out, load_catalog()["tomato_soup_can"].to_json(), {"grasp_type": "any"})
    # Grasps come from every direction; the views' cameras look from above, so take the grasp
    # whose palm faces most upwards (the hand below the object, the object in sight).
    accepted = [t for t in doc["trials"] if t["accepted"]]
    trial = max(accepted, key=lambda t: t["approach"]["palm_normal_world"][2])
    return {"dir": out, "doc": doc, "trial": trial}


@pytest.fixture(scope="module")
def engine(workdir: Path) -> Iterator[EngineProcess]:
    with started_engine("render", workdir) as process:
        yield process


def render(
    engine: EngineProcess,
    grasp: dict[str, Any],
    out: Path,
    outputs: list[str],
    views: list[dict],
    **settings: Any,
) -> dict[str, Any]:
    params = {
        "grasp_index": grasp["trial"]["grasp_index"],
        "render": {**RENDER, **settings},
        "views": views,
        "outputs": outputs,
        **DEPTH_FORMAT,
    }
    inputs = [grasp["dir"] / "grasps.json", grasp["dir"] / "object.ply"]
    reply = engine.task(out.name, params, out, inputs)
    assert reply["ok"] is True, reply
    return reply


def camera_view(index: int, camera: CameraPose) -> dict[str, Any]:
    pose = {"R_w2c": camera.R_w2c.tolist(), "t_w2c": camera.t_w2c.tolist()}
    return {"view_index": index, "seed": 5, "camera": pose}


def load(out: Path, view: int) -> dict[str, Any]:
    prefix = out / f"v{view:02d}"
    png = lambda name: cv2.imread(f"{prefix}_{name}.png", cv2.IMREAD_UNCHANGED)  # noqa: E731
    return {
        "depth": np.load(f"{prefix}_depth.npy"),
        "mask": png("mask"),
        "mask_full": png("mask_full"),
        "segmentation": png("segmentation"),
        "camera": json.loads(Path(f"{prefix}_camera.json").read_text()),
    }


def to_camera(camera: dict[str, Any], R: np.ndarray, t: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points (n × 3) in a frame placed at (R, t) in the world, into the view's camera frame."""
    R_w2c, t_w2c = np.array(camera["R_w2c"]), np.array(camera["t_w2c"])
    return (R_w2c @ (R @ points.T + t[:, None]) + t_w2c[:, None]).T


def assert_valid_view(view: dict[str, Any], shape: tuple[int, int] = (64, 64)) -> None:
    camera = view["camera"]
    depth = view["depth"]
    assert depth.shape == shape and np.isfinite(depth).all() and (depth >= 0).all()
    assert camera["visible_px"] == np.count_nonzero(view["mask"])
    assert camera["full_px"] == np.count_nonzero(view["mask_full"])
    assert not np.any((view["mask"] > 0) & (view["mask_full"] == 0))  # visible ⊆ full
    assert 0.0 <= camera["occlusion"] <= 1.0
    assert np.array_equal(view["mask"] > 0, view["segmentation"] == 1)


@pytest.fixture(scope="module")
def views(engine: EngineProcess, grasp: dict[str, Any], workdir: Path) -> Path:
    """Views whose intrinsics are jittered as units of a camera model differ (principal point
    off the centre, focal length off nominal): every test on them projects with the recorded K,
    so they hold the renderer's K — Blender's shift and angle — to independent projections."""
    out = new_dir(workdir, "views")
    views = [{"view_index": v, "seed": seed} for v, seed in enumerate(SEEDS)]
    reply = render(engine, grasp, out, ALL, views, intrinsics_jitter=0.04)
    assert reply["metrics"]["device"] == "CPU"
    nominal_f = 32 / np.tan(np.radians(RENDER["fov_deg"]) / 2)
    for v in range(len(SEEDS)):
        K = np.array(json.loads((out / f"v{v:02d}_camera.json").read_text())["K"])
        assert abs(K[0, 2] - 31.5) + abs(K[1, 2] - 31.5) > 0.3 and abs(K[0, 0] / nominal_f - 1) > 1e-4
    return out


def test_object_depth_and_masks_match_a_zbuffer_of_the_model_mesh(views: Path, grasp: dict[str, Any]) -> None:
    """Project the model mesh with the recorded pose (R_m2c, t_m2c) and K, z-buffer it at pixel
    centres: the full mask is its coverage, the rendered depth on visible pixels is its depth
    (median within 1 mm; it is within µm), and every model vertex that the rendered depth shows
    at its pixel lies in the visible mask."""
    vertices, faces = read_ply_m(grasp["dir"] / "object.ply")
    for v in range(len(SEEDS)):
        view = load(views, v)
        assert_valid_view(view)
        camera = view["camera"]
        K = np.array(camera["K"])
        points = (np.array(camera["R_m2c"]) @ vertices.T).T + np.array(camera["t_m2c"])
        zbuffer = rasterise_depth(points, faces, K, 64, 64)
        covered = np.isfinite(zbuffer)
        full = view["mask_full"] > 0
        assert np.count_nonzero(covered != full) <= max(2, 0.02 * np.count_nonzero(full)), v
        visible = view["mask"] > 0
        assert np.count_nonzero(visible) > 20
        both = visible & covered
        error = np.abs(view["depth"][both] - zbuffer[both])
        assert np.median(error) < 0.001 and np.percentile(error, 95) < 0.002, (v, np.median(error))

        uv = (K @ (points / points[:, 2:3]).T).T[:, :2]
        u, w = np.rint(uv[:, 0]).astype(int), np.rint(uv[:, 1]).astype(int)
        inside = (u >= 0) & (u < 64) & (w >= 0) & (w < 64)
        shown = np.zeros(len(points), dtype=bool)
        shown[inside] = np.abs(view["depth"][w[inside], u[inside]] - points[inside, 2]) < 0.001
        assert shown.sum() > 10
        assert np.mean(visible[w[shown], u[shown]]) > 0.95


def test_segmentation_ids_name_the_hand_links_they_show(views: Path, grasp: dict[str, Any]) -> None:
    """camera.json maps ids to names (0 background, 1 object, 2.. links in grasps.json order, then
    the arm's flange and link and the table);
    every pixel labelled with a link back-projects onto that link's primitives, and surface
    points of a link that the depth shows at their pixel carry the link's id (points inside or
    within a millimetre of another link or the object are left out: links overlap at their joints
    and touch the object)."""
    links = grasp["doc"]["hand"]["links"]
    poses = grasp["trial"]["link_poses"]
    rng = np.random.default_rng(0)
    placed = [(link, *link_pose(poses[link["name"]])) for link in links]
    for v in range(len(SEEDS)):
        view = load(views, v)
        camera = view["camera"]
        names = {str(2 + k): f"hand/{link['name']}" for k, link in enumerate(links)}
        n = len(links)
        scene = {str(2 + n): "arm/flange", str(3 + n): "arm/link", str(4 + n): "scene/table"}
        expected = {"0": "background", "1": "object", **names, **scene}
        assert camera["segmentation"] == expected
        seg, depth = view["segmentation"], view["depth"]
        assert seg.dtype == np.uint8 and set(np.unique(seg)) <= {int(k) for k in expected}
        K = np.array(camera["K"])
        R_w2c, t_w2c = np.array(camera["R_w2c"]), np.array(camera["t_w2c"])
        labelled_links = 0
        for k, link in enumerate(links):
            R, t = link_pose(poses[link["name"]])
            # Pixels labelled with this link, back-projected into the link frame.
            rows, cols = np.nonzero(seg == 2 + k)
            if len(rows):
                labelled_links += 1
                rays = np.linalg.inv(K) @ np.stack([cols, rows, np.ones_like(cols)]).astype(float)
                world = R_w2c.T @ (rays * depth[rows, cols] - t_w2c[:, None])
                in_link = (R.T @ (world - t[:, None])).T
                distance = np.abs(link_distance(in_link, link))
                assert np.median(distance) < 0.001 and np.percentile(distance, 95) < 0.002, link["name"]
            # Surface points of the link, projected: where the depth shows them, the id is the link's.
            surface = np.concatenate([sample_geom(rng, g) for g in link["geoms"]])
            world = (R @ surface.T).T + t
            clear = np.all(
                [
                    link_distance((Ro.T @ (world - to).T).T, other) > 0.001
                    for other, Ro, to in placed
                    if other is not link
                ],
                axis=0,
            )
            clear &= object_distance(grasp, world) > 0.001
            points = to_camera(camera, np.eye(3), np.zeros(3), world[clear])
            points = points[points[:, 2] > 0.01]
            uv = (K @ (points / points[:, 2:3]).T).T[:, :2]
            u, w = np.rint(uv[:, 0]).astype(int), np.rint(uv[:, 1]).astype(int)
            inside = (u >= 0) & (u < 64) & (w >= 0) & (w < 64)
            u, w, z = u[inside], w[inside], points[inside, 2]
            shown = np.abs(depth[w, u] - z) < 0.0005
            if shown.sum() >= 10:  # enough points that one pixel-edge case is not 10 %
                assert np.mean(seg[w[shown], u[shown]] == 2 + k) > 0.9, link["name"]
        assert labelled_links >= 2


def link_pose(pose: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    return quat_to_matrix(np.array(pose["q"])), np.array(pose["p"])


def link_distance(points: np.ndarray, link: dict[str, Any]) -> np.ndarray:
    """Signed distance from points in the link frame to the union of the link's primitives."""
    distances = []
    for geom in link["geoms"]:
        R = quat_to_matrix(np.array(geom["q"]))
        local = (R.T @ (points - np.array(geom["p"])).T).T
        distances.append(signed_distance_to_primitive(local, geom["type"], geom["size"]))
    return np.min(distances, axis=0)


def object_distance(grasp: dict[str, Any], world: np.ndarray) -> np.ndarray:
    """Signed distance from world points to the can (a cylinder about its frame's z)."""
    shape = grasp["doc"]["object"]["shape"]
    R, t = link_pose(grasp["trial"]["object_pose"])
    local = (R.T @ (world - t).T).T
    return signed_distance_to_primitive(local, "cylinder", [shape["radius_m"], shape["height_m"] / 2])


def sample_geom(rng: np.random.Generator, geom: dict[str, Any], n: int = 400) -> np.ndarray:
    """Points on a primitive's surface (in the link frame): its point nearest to random points."""
    size = np.array(geom["size"])
    if geom["type"] == "box":
        points = rng.uniform(-size, size, (n, 3))
        axis = rng.integers(0, 3, n)
        points[np.arange(n), axis] = size[axis] * rng.choice([-1.0, 1.0], n)
    else:
        direction = rng.normal(size=(n, 3))
        direction /= np.linalg.norm(direction, axis=1)[:, None]
        radius = size[0]
        if geom["type"] == "sphere":
            points = radius * direction
        else:  # capsule: a point on the axis plus radius in any direction (cylinder sides alike)
            along = rng.uniform(-size[1], size[1], n)
            points = np.outer(along, [0.0, 0.0, 1.0]) + radius * direction
            if geom["type"] == "cylinder":
                points[:, :2] = radius * direction[:, :2] / np.linalg.norm(direction[:, :2], axis=1)[:, None]
                points[:, 2] = along
    R = quat_to_matrix(np.array(geom["q"]))
    return (R @ points.T).T + np.array(geom["p"])


def test_extreme_cameras_give_valid_views(
    engine: EngineProcess, grasp: dict[str, Any], workdir: Path
) -> None:
    """At the pole (straight down), inside the hand's bounding box, just behind the palm (the
    object fully hidden) and looking away from everything: every view writes finite outputs; a
    hidden object has occlusion 1 with visible_px 0, an object out of view full_px 0."""
    trial = grasp["trial"]
    p_obj = np.array(trial["object_pose"]["p"])
    palm = trial["link_poses"]["palm"]
    p_palm, n_palm = np.array(palm["p"]), quat_to_matrix(np.array(palm["q"]))[:, 2]  # +z faces the object
    palm_half_z = grasp["doc"]["hand"]["links"][0]["geoms"][0]["size"][2]
    link_origins = np.array([pose["p"] for pose in trial["link_poses"].values()])
    inside_hand = (link_origins.min(axis=0) + link_origins.max(axis=0)) / 2
    behind_palm = p_palm - (palm_half_z + 0.011) * n_palm
    views = [
        camera_view(0, look_at(p_obj + np.array([0.0, 0.0, 0.3]), p_obj)),
        camera_view(1, look_at(inside_hand, p_palm)),
        camera_view(2, look_at(behind_palm, behind_palm + n_palm)),
        camera_view(3, look_at(p_obj + np.array([0.0, 0.0, 0.3]), p_obj + np.array([0.0, 0.0, 1.0]))),
    ]
    out = new_dir(workdir, "extreme")
    reply = render(engine, grasp, out, ALL, views)
    loaded = [load(out, v) for v in range(4)]
    # The reply's occlusion list (what the dashboard's occlusion view reads) is the camera records'.
    assert reply["result"]["occlusion"] == [view["camera"]["occlusion"] for view in loaded]
    for view in loaded:
        assert_valid_view(view)
        assert cv2.imread(str(out / "v00_rgb.png")).shape == (64, 64, 3)
    pole, _, hidden, away = (view["camera"] for view in loaded)
    assert pole["visible_px"] > 20 and pole["occlusion"] < 1.0
    assert pole["R_w2c"][2] == pytest.approx([0.0, 0.0, -1.0])  # looking straight down
    assert hidden["visible_px"] == 0 and hidden["full_px"] > 0 and hidden["occlusion"] == 1.0
    assert away["visible_px"] == away["full_px"] == 0 and away["occlusion"] == 1.0
    assert not loaded[3]["depth"].any()


def test_pruning_and_skipping_path_tracing_change_no_geometry_pixel(
    engine: EngineProcess, grasp: dict[str, Any], workdir: Path
) -> None:
    """The can's metal and the hand need no transmission or transparent bounces: pruned, they are
    0, and the image is bit-identical to one rendered with every cap; depth, masks and
    segmentation are the same with pruning, without it, and without RGB (no path tracing). A glass
    object keeps its transmission bounces."""
    views = [
        {"view_index": 0, "seed": SEEDS[0]},
        {"view_index": 1, "seed": SEEDS[1], "environment": "forest"},
    ]
    routes = {}
    for name, outputs, extra in (
        ("pruned", ALL, {}),
        ("full", ALL, {"prune_bounces": False}),
        ("geometry_only", ["depth", "mask", "segmentation"], {}),
    ):
        out = new_dir(workdir, name)
        routes[name] = (out, render(engine, grasp, out, outputs, views, **extra)["metrics"])
    assert routes["pruned"][1]["bounces"] == {
        "total": 8,
        "diffuse": 4,
        "glossy": 4,
        "transmission": 0,
        "transparent": 0,
    }
    assert routes["full"][1]["bounces"]["transmission"] == 12
    assert (
        routes["geometry_only"][1]["bounces"] is None and routes["geometry_only"][1]["rgb_ms_per_view"] == 0
    )
    for v in range(2):
        for name in (*GEOMETRY_FILES, "camera.json"):
            pruned = (routes["pruned"][0] / f"v{v:02d}_{name}").read_bytes()
            assert pruned == (routes["full"][0] / f"v{v:02d}_{name}").read_bytes(), name
            if name != "camera.json":
                assert pruned == (routes["geometry_only"][0] / f"v{v:02d}_{name}").read_bytes(), name
        # Without RGB neither the colour sensor nor the light draws; the rest of the record is the same.
        with_rgb = json.loads((routes["pruned"][0] / f"v{v:02d}_camera.json").read_text())
        without = json.loads((routes["geometry_only"][0] / f"v{v:02d}_camera.json").read_text())
        assert with_rgb.pop("sensor")["enabled"] is True and "sensor" not in without
        assert with_rgb.pop("light")["tint_rgb"] == [1.0, 1.0, 1.0] and "light" not in without
        assert with_rgb == without
        rgb = f"v{v:02d}_rgb.png"
        assert (routes["pruned"][0] / rgb).read_bytes() == (routes["full"][0] / rgb).read_bytes()
    assert not list(routes["geometry_only"][0].glob("*_rgb.png"))

    doc = json.loads(json.dumps(grasp["doc"]))
    doc["object"]["material"] = "glass"
    glass_dir = new_dir(workdir, "glass_grasp")
    (glass_dir / "grasps.json").write_text(json.dumps(doc))
    out = new_dir(workdir, "glass")
    params = {
        "grasp_index": grasp["trial"]["grasp_index"],
        "render": RENDER,
        "views": views[:1],
        "outputs": ["rgb"],
    }
    reply = engine.task("glass", params, out, [glass_dir / "grasps.json"])
    assert reply["ok"] is True, reply
    assert reply["metrics"]["bounces"] == {
        "total": 12,
        "diffuse": 4,
        "glossy": 4,
        "transmission": 12,
        "transparent": 0,
    }


def test_environment_rotation_and_strength_change_only_the_light(
    engine: EngineProcess, grasp: dict[str, Any], workdir: Path
) -> None:
    views = [
        {"view_index": 0, "seed": SEEDS[0], "environment": "forest"},
        {"view_index": 1, "seed": SEEDS[0], "environment": "studio"},
    ]
    out = new_dir(workdir, "turned")
    params = {
        "grasp_index": grasp["trial"]["grasp_index"],
        "render": RENDER,
        "environments": [{"name": "forest", "rotation_deg": 120.0, "strength": 2.5}],
        "views": views,
        "outputs": ["rgb", "depth"],
        **DEPTH_FORMAT,
    }
    inputs = [grasp["dir"] / "grasps.json", grasp["dir"] / "object.ply"]
    assert engine.task("turned", params, out, inputs)["ok"] is True
    plain = new_dir(workdir, "plain")
    render(engine, grasp, plain, ["rgb", "depth"], [{**views[0], "environment": "forest"}])
    camera = json.loads((out / "v00_camera.json").read_text())
    assert camera["environment"] == {"name": "forest", "rotation_deg": 120.0, "strength": 2.5}
    assert json.loads((out / "v01_camera.json").read_text())["environment"]["rotation_deg"] == 0.0
    assert np.array_equal(np.load(out / "v00_depth.npy"), np.load(plain / "v00_depth.npy"))
    turned = cv2.imread(str(out / "v00_rgb.png")).astype(float)
    assert turned.mean() > cv2.imread(str(plain / "v00_rgb.png")).astype(float).mean() + 10


def test_a_noise_task_reads_the_rendered_segmentation_and_camera_record(
    engine: EngineProcess, grasp: dict[str, Any], workdir: Path
) -> None:
    """Render depth and segmentation (what the planner asks for with noisy depth alone), then run
    the noise engine on them: camera.json carries each segment's material, the noise depends on
    it (the can as glass reads differently from the can as metal), and a task without the
    segmentation or the camera record is refused, naming the file."""
    out = new_dir(workdir, "for_noise")
    render(
        engine, grasp, out, ["depth", "segmentation"], [{"view_index": 0, "seed": 21}], radius_m=[0.3, 0.35]
    )
    record = json.loads((out / "v00_camera.json").read_text())
    links = grasp["doc"]["hand"]["links"]
    n = len(links)
    scene = {str(2 + n): "metal", str(3 + n): "plastic", str(4 + n): "wood"}  # flange, arm link, table
    assert record["materials"] == {"1": "metal", **{str(2 + k): "rubber" for k in range(n)}, **scene}

    params = {"noise": {"mode": "wfov_unbinned"}, "views": [{"view_index": 0, "seed": 9}], **DEPTH_FORMAT}
    names = ("v00_depth.npy", "v00_segmentation.png", "v00_camera.json")

    def noisy(files: dict[str, Path], name: str) -> np.ndarray:
        inputs = tuple(InputRef(n, "render/x", p) for n, p in files.items())
        NoiseEngine().run(TaskRequest(name, params, inputs, new_dir(workdir, name)))
        return np.load(workdir / name / "v00_depth_noisy.npy")

    files = {n: out / n for n in names}
    as_metal = noisy(files, "noise_metal")
    depth = np.load(out / "v00_depth.npy")
    assert np.isfinite(as_metal).all() and (as_metal > 0).sum() > 0.5 * (depth > 0).sum()
    glass = new_dir(workdir, "glass_camera") / "v00_camera.json"
    glass.write_text(json.dumps({**record, "materials": {**record["materials"], "1": "glass"}}))
    as_glass = noisy({**files, "v00_camera.json": glass}, "noise_glass")
    can = cv2.imread(str(out / "v00_segmentation.png"), cv2.IMREAD_UNCHANGED) == 1
    assert can.sum() > 50
    assert np.abs(as_glass[can] - depth[can]).mean() > 5 * np.abs(as_metal[can] - depth[can]).mean()
    for missing in ("v00_segmentation.png", "v00_camera.json"):
        with pytest.raises(BadInput, match=missing):
            noisy({n: p for n, p in files.items() if n != missing}, f"noise_without_{missing[4:9]}")


# A strong barrel lens with every coefficient in play, in OpenCV's order [k1, k2, p1, p2, k3], on a
# taller than wide image with jittered intrinsics: the pinhole canvas the renderer resamples from
# is taller than wide and its principal point off centre, so these views hold Blender's camera
# shift on such a canvas to OpenCV too.
LENS = [-0.28, -0.02, 0.004, -0.003, 0.02]
LENS_RENDER = {"width": 96, "height": 128, "fov_deg": 40.0, "intrinsics_jitter": 0.04}
UNDISTORT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-9)


@pytest.fixture(scope="module")
def lens_views(engine: EngineProcess, grasp: dict[str, Any], workdir: Path) -> Path:
    """Two views with the can well off the image centre (where the lens moves it most), in
    opposite quadrants."""
    out = new_dir(workdir, "lens")
    p_obj = np.array(grasp["trial"]["object_pose"]["p"])
    views = []
    for v, (azimuth, offset) in enumerate(((30.0, (0.2, 0.28)), (210.0, (-0.2, -0.28)))):
        a, e = np.radians(azimuth), np.radians(60.0)
        eye = p_obj + 0.26 * np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
        centred = look_at(eye, p_obj).R_w2c
        # Look past the can so that it lands `offset` (normalised) off the optical axis.
        aim = p_obj - 0.26 * (offset[0] * centred[0] + offset[1] * centred[1])
        views.append(camera_view(v, look_at(eye, aim)))
    render(engine, grasp, out, ALL, views, **LENS_RENDER, distortion=LENS)
    return out


def test_a_distorted_view_shows_the_object_where_opencv_projects_it_with_k_and_dist(
    lens_views: Path, grasp: dict[str, Any]
) -> None:
    """Checked with OpenCV alone, not with the renderer's lens code: the can's model vertices,
    projected with the recorded K and dist (`cv2.projectPoints`), land on its full mask; the full
    mask is the pixels whose ray (`cv2.undistortPointsIter`) falls inside the can's pinhole
    silhouette (the convex hull of its projected vertices: the can is convex), centroid on
    centroid; the rendered depth along those rays lies on the can's surface. Ignoring dist (K
    alone) fails each check by a wide margin, as would a renderer that skipped or inverted the
    remap."""
    vertices, faces = read_ply_m(grasp["dir"] / "object.ply")
    assert is_convex(vertices, faces)
    for v in range(2):
        view = load(lens_views, v)
        camera = view["camera"]
        assert camera["dist"] == LENS
        assert view["mask_full"].shape == (128, 96) and np.count_nonzero(view["mask"]) > 100
        K = np.array(camera["K"])
        assert abs(K[0, 2] - 47.5) + abs(K[1, 2] - 63.5) > 0.3  # jittered
        lens = lens_fit(view, vertices, grasp, np.array(camera["dist"]))
        pinhole = lens_fit(view, vertices, grasp, None)
        assert lens.on_mask > 0.98, (v, lens)
        assert lens.missed <= 0.25 * lens.outline and lens.shift_px < 0.5, (v, lens)
        assert lens.off_surface_m < 0.001, (v, lens)
        assert pinhole.on_mask < lens.on_mask - 0.1, (v, pinhole)
        assert pinhole.missed > 3 * lens.missed, (v, pinhole)
        assert pinhole.off_surface_m > 2 * lens.off_surface_m, (v, pinhole)


@dataclass(frozen=True)
class LensFit:
    """How well a view's images agree with its camera record read with one distortion."""

    on_mask: float  # share of the in-image projected vertices on the (1 px dilated) full mask
    missed: int  # pixels where the predicted silhouette and the full mask disagree
    outline: int  # pixels just outside the full mask: the scale of `missed`
    shift_px: float  # between the centroids of the predicted silhouette and the full mask
    off_surface_m: float  # median distance of the visible pixels' depth points from the can


def lens_fit(
    view: dict[str, Any], vertices: np.ndarray, grasp: dict[str, Any], dist: np.ndarray | None
) -> LensFit:
    camera = view["camera"]
    K = np.array(camera["K"])
    full, visible = view["mask_full"] > 0, view["mask"] > 0
    height, width = full.shape
    rvec, tvec = cv2.Rodrigues(np.array(camera["R_m2c"]))[0], np.array(camera["t_m2c"])
    near = cv2.dilate(full.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    uv = cv2.projectPoints(vertices, rvec, tvec, K, dist)[0].reshape(-1, 2)
    u, w = np.rint(uv).astype(int).T
    inside = (u >= 0) & (u < width) & (w >= 0) & (w < height)
    # Each pixel's ray, undistorted by OpenCV (with K alone: the pixel's own), in the pinhole image.
    rows, cols = np.indices(full.shape)
    pixels = np.stack([cols.ravel(), rows.ravel()], axis=-1).reshape(-1, 1, 2).astype(np.float64)
    xy = cv2.undistortPointsIter(pixels, K, dist, None, None, UNDISTORT).reshape(-1, 2)
    rays = np.column_stack([xy, np.ones(len(xy))])
    hull = cv2.convexHull(cv2.projectPoints(vertices, rvec, tvec, K, None)[0].astype(np.float32))
    silhouette = np.array(
        [cv2.pointPolygonTest(hull, (float(x), float(y)), False) >= 0 for x, y, _ in rays @ K.T]
    ).reshape(full.shape)
    seen = rays.reshape(height, width, 3)[visible] * view["depth"][visible][:, None]
    R_w2c, t_w2c = np.array(camera["R_w2c"]), np.array(camera["t_w2c"])
    world = (R_w2c.T @ (seen - t_w2c).T).T
    return LensFit(
        on_mask=float(np.mean(near[w[inside], u[inside]])),
        missed=int(np.count_nonzero(silhouette != full)),
        outline=int(np.count_nonzero(near & ~full)),
        shift_px=float(np.linalg.norm(np.argwhere(silhouette).mean(0) - np.argwhere(full).mean(0))),
        off_surface_m=float(np.median(np.abs(object_distance(grasp, world)))),
    )


def test_a_distorted_views_labels_and_depths_come_from_its_canvas_unblended(lens_views: Path) -> None:
    """Nearest-neighbour resampling: every label is one the scene has, the masks agree with the
    segmentation and with the counts recorded, and depth is 0 exactly on the background (a blend
    would smear depth across its edge)."""
    for v in range(2):
        view = load(lens_views, v)
        assert_valid_view(view, (128, 96))
        labels = {int(k) for k in view["camera"]["segmentation"]}
        assert set(np.unique(view["segmentation"])) <= labels
        assert (view["depth"][view["segmentation"] == 0] == 0).all()
        assert (view["depth"][view["segmentation"] > 0] > 0).all()
        assert cv2.imread(str(lens_views / f"v{v:02d}_rgb.png")).shape == (128, 96, 3)


def test_a_lens_of_zeros_changes_no_byte(
    engine: EngineProcess, grasp: dict[str, Any], workdir: Path, views: Path
) -> None:
    """`distortion = [0, 0, 0, 0, 0]` is the pinhole of a task without the field: the same files,
    byte for byte, and no `dist` in the camera record."""
    out = new_dir(workdir, "lens_zero")
    view = [{"view_index": 0, "seed": SEEDS[0]}]
    render(engine, grasp, out, ALL, view, intrinsics_jitter=0.04, distortion=[0.0] * 5)
    for name in ("rgb.png", *GEOMETRY_FILES, "camera.json"):
        assert (out / f"v00_{name}").read_bytes() == (views / f"v00_{name}").read_bytes(), name
    assert "dist" not in json.loads((out / "v00_camera.json").read_text())


def test_a_lens_that_cannot_be_inverted_over_the_image_fails_the_task_before_any_view(
    engine: EngineProcess, grasp: dict[str, Any], workdir: Path
) -> None:
    """At 64×64 and 60° the corners lie at radius 0.80; k1 = -0.6 folds the radial map back well
    inside. Refused (not retryable) before anything renders, naming the parameter and the rule;
    so is a coefficient out of its bound."""
    inputs = [grasp["dir"] / "grasps.json", grasp["dir"] / "object.ply"]
    for name, distortion, expected in (
        (
            "folds",
            [-0.6, 0.0, 0.0, 0.0, 0.0],
            "params.render.distortion: [-0.6, 0.0, 0.0, 0.0, 0.0] must stay",
        ),
        ("bound", [0.0, 0.0, 0.2, 0.0, 0.0], "params.render.distortion[2]: 0.2 is outside [-0.1, 0.1]"),
    ):
        out = new_dir(workdir, f"lens_{name}")
        params = {
            "grasp_index": grasp["trial"]["grasp_index"],
            "render": {**RENDER, "distortion": distortion},
            "views": [{"view_index": 0, "seed": SEEDS[0]}],
            "outputs": ALL,
        }
        reply = engine.task(out.name, params, out, inputs)
        assert reply["ok"] is False and reply["retryable"] is False, reply
        assert expected in reply["error"], reply["error"]
        assert not list(out.iterdir())
