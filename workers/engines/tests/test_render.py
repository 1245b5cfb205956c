"""The render engine, served through a real process (so Blender's C-level prints must not reach the
protocol stream), on a grasp produced by the real grasp engine."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from conftest import EngineProcess, new_dir, trx3_grasps
from geometry import distance_to_mesh
from hdri_files import write_opencv_exr

from vint_engines import depth_file
from vint_engines.grasp.engine import GraspEngine
from vint_engines.objects import load_catalog
from vint_engines.objects.meshio import read_ply_m
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
RENDER = {
    "width": 64,
    "height": 64,
    "samples": 8,
    "fov_deg": 60.0,
    "environment": "studio",
    "radius_m": [0.2, 0.25],
    "elevation_deg": [15.0, 75.0],
}
SEED = 987654321


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("render")


@pytest.fixture(scope="module")
def grasps(workdir: Path) -> tuple[Path, int]:
    """grasps.json from the grasp engine and the index of an accepted trial in it."""
    out = new_dir(workdir, "grasp")
    doc = trx3_grasps(out, CAN)
    return out / "grasps.json", next(t["grasp_index"] for t in doc["trials"] if t["accepted"])


@pytest.fixture(scope="module")
def engine(workdir: Path) -> Iterator[EngineProcess]:
    process = EngineProcess("render", workdir)
    hello = process.receive()
    assert hello is not None, process.stderr_tail()
    assert hello["stage"] == "render" and hello["engine"]["libs"]["bpy"].startswith("5.2")
    yield process
    assert process.shutdown(60) == 0
    process.kill()


def render(
    engine: EngineProcess, grasps: tuple[Path, int], out: Path, outputs: list[str], **extra: Any
) -> dict[str, Any]:
    params = {
        "grasp_index": grasps[1],
        "render": RENDER,
        "views": [{"view_index": 0, "seed": SEED}],
        "outputs": outputs,
        **extra,
    }
    return engine.task(out.name, params, out, [grasps[0]])


@pytest.fixture(scope="module")
def view(engine: EngineProcess, grasps: tuple[Path, int], workdir: Path) -> tuple[dict[str, Any], Path]:
    out = new_dir(workdir, "view")
    reply = render(engine, grasps, out, ["rgb", "depth", "mask"])
    assert reply["ok"] is True, reply
    return reply, out


def load_view(out: Path, depth_format: str = "png") -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    depth = depth_file.read(out / f"v00_depth.{depth_format}")
    mask = cv2.imread(str(out / "v00_mask.png"), cv2.IMREAD_UNCHANGED)
    camera = json.loads((out / "v00_camera.json").read_text())
    return depth, mask, camera


def test_view_writes_the_protocol_outputs(view: tuple[dict[str, Any], Path]) -> None:
    reply, out = view
    names = {o["name"] for o in reply["outputs"]}
    assert names == {"v00_rgb.png", "v00_depth.png", "v00_mask.png", "v00_mask_full.png", "v00_camera.json"}
    rgb = cv2.imread(str(out / "v00_rgb.png"), cv2.IMREAD_UNCHANGED)
    depth, mask, camera = load_view(out)
    assert rgb.shape == (64, 64, 3) and rgb.dtype == np.uint8
    assert depth.shape == (64, 64) and depth.dtype == np.float32 and np.isfinite(depth).all()
    assert mask.shape == (64, 64) and mask.dtype == np.uint8 and set(np.unique(mask)) == {0, 255}
    assert camera["visible_px"] == np.count_nonzero(mask) > 20
    assert (depth[mask > 0] > 0).all()  # the object is hit wherever the mask says so
    assert (depth == 0).any()  # and the background reads 0


def test_png_depth_is_the_float_depth_within_half_a_step(
    engine: EngineProcess, grasps: tuple[Path, int], view: tuple[dict[str, Any], Path], workdir: Path
) -> None:
    """The same view with `depth_format = "npy"`: the default 16-bit PNG decodes within 0.05 mm
    (half a 0.1 mm step) of the float32 depth on every pixel in range, with the same holes. The
    decoding here is OpenCV's and numpy's, not the engine's."""
    out = new_dir(workdir, "npy")
    reply = render(engine, grasps, out, ["rgb", "depth", "mask"], depth_format="npy")
    assert reply["ok"] is True, reply
    assert {o["name"] for o in reply["outputs"]} >= {"v00_depth.npy"}
    exact = np.load(out / "v00_depth.npy")
    units = cv2.imread(str(view[1] / "v00_depth.png"), cv2.IMREAD_UNCHANGED)
    assert units.dtype == np.uint16 and units.shape == exact.shape
    in_range = (exact > 0) & (exact <= 6.5535)
    assert in_range.sum() > 20 and np.array_equal(units > 0, in_range)
    error = np.abs(units[in_range].astype(np.float64) * 1e-4 - exact[in_range].astype(np.float64))
    assert error.max() <= 0.5e-4 + 1e-9, error.max()
    # The other files do not depend on how depth is stored.
    for name in ("v00_rgb.png", "v00_mask.png", "v00_camera.json"):
        assert (out / name).read_bytes() == (view[1] / name).read_bytes(), name


def test_camera_is_a_proper_opencv_camera(view: tuple[dict[str, Any], Path]) -> None:
    _, _, camera = load_view(view[1])
    K = np.array(camera["K"])
    assert K[0, 0] == pytest.approx(32 / np.tan(np.radians(30))) and K[0, 0] == K[1, 1]
    assert (K[0, 2], K[1, 2]) == (31.5, 31.5) and list(K[2]) == [0, 0, 1]
    for key in ("R_w2c", "R_m2c"):
        R = np.array(camera[key])
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-9) and np.linalg.det(R) == pytest.approx(1.0)
    assert 0.15 < camera["t_m2c"][2] < 0.3  # the object is in front of the camera, at the sampled radius


def test_depth_on_object_pixels_lies_on_the_object_surface(view: tuple[dict[str, Any], Path]) -> None:
    """Back-project each object pixel with K and its depth, move it into the object frame with
    (R_m2c, t_m2c) and measure its distance to the cylinder's surface."""
    depth, mask, camera = load_view(view[1])
    v, u = np.nonzero(mask)
    rays = np.linalg.inv(np.array(camera["K"])) @ np.stack([u, v, np.ones_like(u)]).astype(float)
    points_c = rays * depth[v, u]
    points_m = np.array(camera["R_m2c"]).T @ (points_c - np.array(camera["t_m2c"])[:, None])
    dx = np.hypot(points_m[0], points_m[1]) - CAN["shape"]["radius_m"]
    dz = np.abs(points_m[2]) - CAN["shape"]["height_m"] / 2
    distance = np.abs(np.minimum(np.maximum(dx, dz), 0) + np.hypot(np.maximum(dx, 0), np.maximum(dz, 0)))
    assert np.percentile(distance, 95) < 0.002 and distance.max() < 0.005


def test_same_seed_renders_identical_images(
    engine: EngineProcess, grasps: tuple[Path, int], view: tuple[dict[str, Any], Path], workdir: Path
) -> None:
    again = new_dir(workdir, "again")
    assert render(engine, grasps, again, ["rgb", "depth", "mask"])["ok"] is True
    depth_a, mask_a, camera_a = load_view(view[1])
    depth_b, mask_b, camera_b = load_view(again)
    assert np.array_equal(depth_a, depth_b) and np.array_equal(mask_a, mask_b) and camera_a == camera_b
    assert (view[1] / "v00_rgb.png").read_bytes() == (again / "v00_rgb.png").read_bytes()


def test_rgb_is_skipped_unless_requested(
    engine: EngineProcess, grasps: tuple[Path, int], workdir: Path
) -> None:
    out = new_dir(workdir, "no_rgb")
    reply = render(engine, grasps, out, ["depth", "mask"])
    assert reply["ok"] is True
    assert sorted(p.name for p in out.iterdir()) == [
        "v00_camera.json",
        "v00_depth.png",
        "v00_mask.png",
        "v00_mask_full.png",
    ]


def test_unknown_grasp_or_environment_fails_without_retry(
    engine: EngineProcess, grasps: tuple[Path, int], workdir: Path
) -> None:
    reply = render(engine, grasps, new_dir(workdir, "bad_index"), ["depth"], grasp_index=999)
    assert reply["ok"] is False and reply["retryable"] is False and "999" in reply["error"]
    reply = render(
        engine, grasps, new_dir(workdir, "bad_env"), ["depth"], render={**RENDER, "environment": "moon"}
    )
    assert reply["ok"] is False and reply["retryable"] is False and "moon" in reply["error"]
    out = new_dir(workdir, "bad_view_env")
    views = [{"view_index": 0, "seed": SEED}, {"view_index": 1, "seed": SEED, "environment": "moon"}]
    reply = render(engine, grasps, out, ["depth"], views=views)
    assert reply["ok"] is False and reply["retryable"] is False
    assert "params.views[1].environment" in reply["error"] and "moon" in reply["error"]
    assert not any(out.iterdir())  # checked before any view renders


def test_each_view_renders_under_its_own_environment(
    engine: EngineProcess, grasps: tuple[Path, int], workdir: Path
) -> None:
    """Two views with one seed (so one camera) under two HDRIs: same geometry, other light, and each
    camera.json names its environment. Switching leaves no trace: the forest view matches the same
    view rendered alone with forest as the task's default environment."""
    small = {**RENDER, "width": 32, "height": 32, "samples": 4}
    views = [
        {"view_index": 0, "seed": SEED, "environment": "studio"},
        {"view_index": 1, "seed": SEED, "environment": "forest"},
    ]
    mixed = new_dir(workdir, "environments")
    reply = render(engine, grasps, mixed, ["rgb", "depth"], render=small, views=views)
    assert reply["ok"] is True, reply
    for index, environment in ((0, "studio"), (1, "forest")):
        camera = json.loads((mixed / f"v{index:02d}_camera.json").read_text())
        assert camera["environment"] == {"name": environment, "rotation_deg": 0.0, "strength": 1.0}
    assert (mixed / "v00_depth.png").read_bytes() == (mixed / "v01_depth.png").read_bytes()
    assert (mixed / "v00_rgb.png").read_bytes() != (mixed / "v01_rgb.png").read_bytes()

    alone = new_dir(workdir, "forest_alone")
    forest = {**small, "environment": "forest"}
    reply = render(engine, grasps, alone, ["rgb"], render=forest, views=[{"view_index": 1, "seed": SEED}])
    assert reply["ok"] is True, reply
    assert (alone / "v01_rgb.png").read_bytes() == (mixed / "v01_rgb.png").read_bytes()
    assert json.loads((alone / "v01_camera.json").read_text())["environment"]["name"] == "forest"


def test_another_engine_process_renders_the_same_bytes(
    spawn_engine: Any, grasps: tuple[Path, int], view: tuple[dict[str, Any], Path], workdir: Path
) -> None:
    """Outputs are content-addressed artifacts: a retry on a fresh engine must reproduce them."""
    fresh = spawn_engine("render")
    assert fresh.receive() is not None, fresh.stderr_tail()
    out = new_dir(workdir, "fresh")
    assert render(fresh, grasps, out, ["rgb", "depth", "mask"])["ok"] is True
    for name in ("v00_rgb.png", "v00_depth.png", "v00_mask.png", "v00_mask_full.png", "v00_camera.json"):
        assert (out / name).read_bytes() == (view[1] / name).read_bytes(), name
    assert fresh.shutdown(60) == 0


@pytest.fixture(scope="module")
def mustard(workdir: Path) -> tuple[Path, Path, int]:
    """grasps.json and object.ply of a grasp on the mustard bottle (a compound, not a cylinder),
    and the index of an accepted trial."""
    out = new_dir(workdir, "grasp_mustard")
    params = {
        "object": load_catalog()["mustard_bottle"].to_json(),
        "hand": {"name": "trx3"},
        "trials": [{"grasp_index": i, "seed": 1000003 * i + 17} for i in range(4)],
    }
    GraspEngine().run(TaskRequest("grasp", params, (), out))
    doc = json.loads((out / "grasps.json").read_text())
    index = next(t["grasp_index"] for t in doc["trials"] if t["accepted"])
    return out / "grasps.json", out / "object.ply", index


def object_points(out: Path) -> np.ndarray:
    """The object pixels of view 0 back-projected into the object frame (3 × n)."""
    depth, mask, camera = load_view(out, "npy")
    v, u = np.nonzero(mask)
    rays = np.linalg.inv(np.array(camera["K"])) @ np.stack([u, v, np.ones_like(u)]).astype(float)
    points_c = rays * depth[v, u]
    return np.array(camera["R_m2c"]).T @ (points_c - np.array(camera["t_m2c"])[:, None])


def test_a_compound_object_renders_from_the_grasp_engines_model_mesh(
    engine: EngineProcess, mustard: tuple[Path, Path, int], workdir: Path
) -> None:
    """A 32×32 view of the mustard bottle, its mesh read from the staged object.ply: every object
    pixel's depth lies on that mesh. Without object.ply the renderer rebuilds the same mesh from
    the catalog entry in grasps.json, and the view's depth is the same."""
    grasps_json, model_ply, index = mustard
    params = {
        "grasp_index": index,
        "render": {**RENDER, "width": 32, "height": 32, "samples": 4},
        "views": [{"view_index": 0, "seed": SEED}],
        "outputs": ["depth", "mask"],
        "depth_format": "npy",
    }
    staged = new_dir(workdir, "mustard_staged")
    reply = engine.task("staged", params, staged, [grasps_json, model_ply])
    assert reply["ok"] is True, reply
    vertices, faces = read_ply_m(model_ply)
    points = object_points(staged)
    assert points.shape[1] > 20
    distance = distance_to_mesh(points.T, vertices, faces)
    assert np.percentile(distance, 95) < 0.002 and distance.max() < 0.005

    rebuilt = new_dir(workdir, "mustard_rebuilt")
    assert engine.task("rebuilt", params, rebuilt, [grasps_json])["ok"] is True
    depth_staged, mask_staged, _ = load_view(staged, "npy")
    depth_rebuilt, mask_rebuilt, _ = load_view(rebuilt, "npy")
    assert np.array_equal(mask_staged, mask_rebuilt)
    assert np.allclose(depth_staged, depth_rebuilt, atol=1e-5)


def write_hdri(path: Path, bgr: tuple[float, float, float]) -> tuple[Path, str]:
    """A 16×8 Radiance HDRI of one linear colour (BGR), written by OpenCV (not by Blender), and
    its SHA-256: the worker stages a job's file as an input named by that hash."""
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), np.full((8, 16, 3), bgr, dtype=np.float32))
    return path, hashlib.sha256(path.read_bytes()).hexdigest()


def user_hdri_params(name: str, path: Path, sha: str, spec_path: str, **entry: float) -> dict[str, Any]:
    return {
        "environments": [{"name": name, "asset": sha, **entry}],
        "assets": [{"path": spec_path, "sha256": sha, "size": path.stat().st_size}],
    }


SMALL = {**RENDER, "width": 32, "height": 32, "samples": 4}
TWO_VIEWS = [
    {"view_index": 0, "seed": SEED, "environment": "studio"},
    {"view_index": 1, "seed": SEED, "environment": "lab"},  # the same camera, the user's light
]


def test_a_user_hdri_lights_the_rgb_image_and_not_the_geometry(
    engine: EngineProcess, grasps: tuple[Path, int], workdir: Path
) -> None:
    """The same view under studio and under the user's red HDRI: identical depth, a different and
    redder image (the background shows the HDRI itself), and camera.json names the file by hash.
    The image is kept by content: the same file staged again elsewhere (the first copy gone) renders
    the same bytes, while another file under the same name lights differently."""
    red, sha = write_hdri(workdir / "staged" / "a" / "lab.hdr", (0.002, 0.002, 0.5))
    out = new_dir(workdir, "user_hdri")
    extra = user_hdri_params("lab", red, sha, "assets/lab.hdr", rotation_deg=90.0, strength=1.5)
    reply = engine.task(
        "user_hdri", {**base(grasps), **extra, "views": TWO_VIEWS}, out, [grasps[0], (sha, red)]
    )
    assert reply["ok"] is True, reply
    assert np.array_equal(depth_file.read(out / "v00_depth.png"), depth_file.read(out / "v01_depth.png"))
    studio = cv2.imread(str(out / "v00_rgb.png")).astype(float)
    lab = cv2.imread(str(out / "v01_rgb.png")).astype(float)
    background = depth_file.read(out / "v01_depth.png") == 0
    assert background.any()
    b, g, r = (lab[..., c][background].mean() for c in range(3))
    assert r > 100 and r > 4 * g and r > 4 * b, (b, g, r)
    assert abs(studio[..., 2] - studio[..., 1])[background].mean() < 10  # studio's backdrop is grey
    camera = json.loads((out / "v01_camera.json").read_text())
    assert camera["environment"] == {"name": "lab", "rotation_deg": 90.0, "strength": 1.5, "asset": sha}

    red.unlink()  # the staged input of the last task is gone: the engine kept its own copy
    again_file = red.parent.parent / "b" / "lab.hdr"
    again_file.parent.mkdir()
    write_hdri(again_file, (0.002, 0.002, 0.5))
    again = new_dir(workdir, "user_hdri_again")
    views = TWO_VIEWS[1:]
    reply = engine.task(
        "again", {**base(grasps), **extra, "views": views}, again, [grasps[0], (sha, again_file)]
    )
    assert reply["ok"] is True, reply
    assert (again / "v01_rgb.png").read_bytes() == (out / "v01_rgb.png").read_bytes()

    blue, blue_sha = write_hdri(workdir / "staged" / "c" / "lab.hdr", (0.5, 0.002, 0.002))
    other = new_dir(workdir, "user_hdri_other")
    extra = user_hdri_params("lab", blue, blue_sha, "assets/lab.hdr", rotation_deg=90.0, strength=1.5)
    reply = engine.task(
        "other", {**base(grasps), **extra, "views": views}, other, [grasps[0], (blue_sha, blue)]
    )
    assert reply["ok"] is True, reply
    bgr = cv2.imread(str(other / "v01_rgb.png")).astype(float)
    assert bgr[..., 0][background].mean() > 4 * bgr[..., 2][background].mean()


def test_a_user_hdri_is_checked_before_any_view_renders(
    engine: EngineProcess, grasps: tuple[Path, int], workdir: Path
) -> None:
    """A file Blender cannot read, a hash the task does not list, a user's file under a bundled
    name: each fails the task, not retryable, naming what is wrong, with nothing written. Without
    `rgb` the file is not needed at all (no HDRI is read)."""
    broken = workdir / "staged" / "broken" / "lab.hdr"
    broken.parent.mkdir(parents=True)
    broken.write_bytes(b"#?RADIANCE\nthis is not a picture\n")
    sha = hashlib.sha256(broken.read_bytes()).hexdigest()
    extra = user_hdri_params("lab", broken, sha, "assets/broken.hdr")
    out = new_dir(workdir, "broken_hdri")
    reply = engine.task(
        "broken", {**base(grasps), **extra, "views": TWO_VIEWS}, out, [grasps[0], (sha, broken)]
    )
    assert reply["ok"] is False and reply["retryable"] is False, reply
    assert "'lab'" in reply["error"] and "assets/broken.hdr" in reply["error"], reply["error"]
    assert not any(out.iterdir())

    unlisted = {**base(grasps), "environments": extra["environments"], "views": TWO_VIEWS}
    reply = engine.task("unlisted", unlisted, new_dir(workdir, "unlisted_hdri"), [grasps[0]])
    assert reply["ok"] is False and reply["retryable"] is False
    assert "params.environments[0].asset" in reply["error"] and "not among params.assets" in reply["error"]

    shadowing = {
        **base(grasps),
        **extra,
        "environments": [{"name": "forest", "asset": sha}],
        "views": TWO_VIEWS,
    }
    reply = engine.task("shadow", shadowing, new_dir(workdir, "shadow_hdri"), [grasps[0], (sha, broken)])
    assert (
        reply["ok"] is False
        and "params.environments[0].name" in reply["error"]
        and "bundled" in reply["error"]
    )

    depth_only = {**unlisted, "outputs": ["depth"]}
    out = new_dir(workdir, "depth_only_hdri")
    reply = engine.task("depth_only", depth_only, out, [grasps[0]])
    assert reply["ok"] is True, reply
    assert json.loads((out / "v01_camera.json").read_text())["environment"]["asset"] == sha


def test_a_user_hdri_declaring_gigapixels_is_refused_before_blender_reads_it(
    engine: EngineProcess, grasps: tuple[Path, int], workdir: Path
) -> None:
    """A 50-byte .hdr that says 200000 × 200000 (Blender would ask for 640 GB) fails the task, not
    retryable, naming the file and the limit; a small OpenEXR file of the user's lights the view."""
    huge = workdir / "staged" / "huge" / "lab.hdr"
    huge.parent.mkdir(parents=True)
    huge.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 200000 +X 200000\n" + bytes(64))
    sha = hashlib.sha256(huge.read_bytes()).hexdigest()
    out = new_dir(workdir, "huge_hdri")
    params = {**base(grasps), **user_hdri_params("lab", huge, sha, "assets/huge.hdr"), "views": TWO_VIEWS}
    reply = engine.task("huge", params, out, [grasps[0], (sha, huge)])
    assert reply["ok"] is False and reply["retryable"] is False, reply
    assert "'lab'" in reply["error"] and "assets/huge.hdr" in reply["error"], reply["error"]
    assert "200000 × 200000" in reply["error"] and "limit of 33554432 (8192 × 4096)" in reply["error"]
    assert not any(out.iterdir())

    exr = write_opencv_exr(workdir / "staged" / "exr" / "lab.exr", (0.002, 0.002, 0.5))
    sha = hashlib.sha256(exr.read_bytes()).hexdigest()
    out = new_dir(workdir, "exr_hdri")
    params = {**base(grasps), **user_hdri_params("lab", exr, sha, "assets/lab.exr"), "views": TWO_VIEWS[1:]}
    reply = engine.task("exr", params, out, [grasps[0], (sha, exr)])
    assert reply["ok"] is True, reply
    background = depth_file.read(out / "v01_depth.png") == 0
    b, g, r = (
        cv2.imread(str(out / "v01_rgb.png")).astype(float)[..., c][background].mean() for c in range(3)
    )
    assert r > 4 * g and r > 4 * b, (b, g, r)


def base(grasps: tuple[Path, int]) -> dict[str, Any]:
    """A render task of the accepted grasp at 32×32, RGB and depth."""
    return {"grasp_index": grasps[1], "render": SMALL, "outputs": ["rgb", "depth"]}
