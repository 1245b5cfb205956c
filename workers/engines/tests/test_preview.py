"""The contact sheet (`python -m vint_engines preview`) on a small native dataset written here: a
camera and a palm pose chosen by hand, and one active taxel whose pixel is computed below with
its own rotation formula (Rodrigues), not the module's quaternion code."""

from __future__ import annotations

import hashlib
import json
import math
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from conftest import ENGINES_DIR

from vint_engines import depth_file
from vint_engines.preview import dataset, sheet, taxels, tiles

WIDTH, HEIGHT = 320, 240  # one image pixel per tile pixel (tiles are 320 wide)
FOCAL = 300.0
RGB_BGR = (40, 60, 80)  # a flat image, so whatever is drawn on it stands out
SEGMENT_NAMES = {"0": "background", "1": "object", "2": "hand/palm", "3": "hand/f0_link1", "4": "scene/table"}
P_PALM = np.array([0.01, -0.02, 0.03])  # the active taxel, palm frame (m)
READING = 0.8
FAR_ROWS = 20


def rodrigues(axis: list[float], degrees: float) -> np.ndarray:
    k = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    cross = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    theta = math.radians(degrees)
    return np.eye(3) + math.sin(theta) * cross + (1 - math.cos(theta)) * cross @ cross


def quaternion(axis: list[float], degrees: float) -> list[float]:
    k = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    half = math.radians(degrees) / 2
    return [math.cos(half), *(math.sin(half) * k).tolist()]


PALM_AXIS, PALM_DEG, PALM_P = [1.0, 2.0, -0.5], 35.0, np.array([0.02, 0.01, 0.05])
R_W2C = rodrigues([0.3, -1.0, 0.2], 25.0)
T_W2C = np.array([0.01, -0.02, 0.5])
K = np.array([[FOCAL, 0, (WIDTH - 1) / 2], [0, FOCAL, (HEIGHT - 1) / 2], [0, 0, 1]])


def expected_pixel(t_w2c: np.ndarray = T_W2C) -> tuple[float, float, float]:
    """(u, v, z) of the active taxel, by hand: palm → world → camera → pixel."""
    world = rodrigues(PALM_AXIS, PALM_DEG) @ P_PALM + PALM_P
    x, y, z = R_W2C @ world + t_w2c
    return FOCAL * x / z + (WIDTH - 1) / 2, FOCAL * y / z + (HEIGHT - 1) / 2, z


def segmentation_image() -> np.ndarray:
    """Five vertical bands, one per label 0..4."""
    labels = np.zeros((HEIGHT, WIDTH), dtype=np.uint8)
    for label in range(5):
        labels[:, label * WIDTH // 5 : (label + 1) * WIDTH // 5] = label
    return labels


def write_sample(
    root: Path,
    obj: str,
    hand: str,
    surface_z: float,
    noisy: bool = False,
    dist: list[float] | None = None,
    t_w2c: np.ndarray = T_W2C,
    depth_format: str = "png",
) -> str:
    """A grasp record and one view of it: rgb, depth (`surface_z` everywhere but a background
    corner and a strip 10 cm farther along the bottom), segmentation, and depth_noisy (the depth
    20 cm farther) only when `noisy`, both in `depth_format`; the camera at `t_w2c`, with the lens
    distortion `dist` when given."""
    grasp_id = f"{obj}.{hand}.g000001"
    sample_id = f"{grasp_id}.v00"
    (root / grasp_id).mkdir(parents=True)
    grasp = {
        "grasp_id": grasp_id,
        "object": {"name": obj},
        "hand": {"name": hand, "taxels": {"layout": "hands/none/taxels.csv", "count": 2, "sha256": "0" * 64}},
        "trial": {
            "hand_pose": {"p": PALM_P.tolist(), "q": quaternion(PALM_AXIS, PALM_DEG)},
            "link_poses": {"palm": {"p": PALM_P.tolist(), "q": quaternion(PALM_AXIS, PALM_DEG)}},
        },
        "touch": {
            "active": [
                {"taxel": 1, "link": "palm", "region": "palm", "p_palm": P_PALM.tolist(), "reading": READING}
            ],
            "readings": [0.0, READING],
        },
    }
    (root / grasp_id / "grasp.json").write_text(json.dumps(grasp))
    directory = root / sample_id
    directory.mkdir()
    meta: dict[str, Any] = {
        "sample_id": sample_id,
        "grasp_id": grasp_id,
        "object": {"name": obj},
        "hand": hand,
        "camera": {
            "K": K.tolist(),
            "width": WIDTH,
            "height": HEIGHT,
            "R_w2c": R_W2C.tolist(),
            "t_w2c": t_w2c.tolist(),
            "segmentation": SEGMENT_NAMES,
        },
        "visibility": {"visible_px": 75, "full_px": 100, "occlusion": 0.25},
        "grasp": {"record": f"../{grasp_id}/grasp.json"},
    }
    if dist is not None:
        meta["camera"]["dist"] = dist
    (directory / "meta.json").write_text(json.dumps(meta))
    cv2.imwrite(str(directory / "rgb.png"), np.full((HEIGHT, WIDTH, 3), RGB_BGR, dtype=np.uint8))
    depth = np.full((HEIGHT, WIDTH), surface_z, dtype=np.float32)
    depth[:20, :20] = 0.0  # no return
    depth[-FAR_ROWS:] = surface_z + 0.1
    depth_file.write(directory / "depth", depth, depth_format)
    if noisy:
        noisy_depth = np.where(depth > 0, depth + 0.2, 0.0).astype(np.float32)
        depth_file.write(directory / "depth_noisy", noisy_depth, depth_format)
    cv2.imwrite(str(directory / "segmentation.png"), segmentation_image())
    return sample_id


def one_sheet(root: Path) -> np.ndarray:
    chosen = [dataset.load(ref) for ref in dataset.list_samples(root)]
    return sheet.compose(chosen, root / "no-catalog").image


def tile(image: np.ndarray, row: int, column: str) -> np.ndarray:
    top = sheet.HEADER_PX + row * (sheet.CAPTION_PX + HEIGHT) + sheet.CAPTION_PX
    left = sheet.COLUMNS.index(column) * WIDTH
    return image[top : top + HEIGHT, left : left + WIDTH]


def test_the_active_taxel_projects_to_the_independently_computed_pixel(tmp_path: Path) -> None:
    u, v, z = expected_pixel()
    assert 20 < u < WIDTH - 20 and 20 < v < HEIGHT - FAR_ROWS - 10, (
        "the test's taxel is well inside the image"
    )
    write_sample(tmp_path, "mug", "trx3", surface_z=z + 0.001)
    sample = dataset.load(dataset.list_samples(tmp_path)[0])
    projected = taxels.active_taxels(sample.grasp, sample.camera)
    np.testing.assert_allclose(projected.uv[0], [u, v], atol=1e-9)
    np.testing.assert_allclose(projected.z[0], z, atol=1e-12)

    drawn = tile(one_sheet(tmp_path), 0, "taxels").astype(int)
    changed = np.argwhere(np.any(drawn != RGB_BGR, axis=2))
    assert len(changed) > 0, "a dot is drawn"
    centre_v, centre_u = changed.mean(axis=0)
    assert abs(centre_u - u) < 0.5 and abs(centre_v - v) < 0.5, (centre_u, centre_v, u, v)
    assert changed[:, 1].max() - changed[:, 1].min() <= 2 * sheet.DOT_RADIUS_PX + 3, "a small dot"
    centre = drawn[round(v), round(u)]
    assert not np.array_equal(centre, RGB_BGR), "seen by the camera: a filled dot"
    np.testing.assert_array_equal(centre, sheet.reading_colours(np.array([READING]))[0])


def test_a_distorted_views_taxel_projects_through_its_lens(tmp_path: Path) -> None:
    """With `dist` in the camera record the taxel lands where OpenCV's lens model (written out
    here by hand) puts it, pixels from the pinhole's pixel, and the dot is drawn there. The camera
    is moved so that the taxel lies well off its axis, where the lens moves it most."""
    k1, k2, p1, p2, k3 = dist = [-0.3, 0.08, 0.004, -0.003, 0.01]
    t_w2c = T_W2C + np.array([0.17, 0.06, 0.0])
    pinhole_u, pinhole_v, z = expected_pixel(t_w2c)
    x, y = (pinhole_u - (WIDTH - 1) / 2) / FOCAL, (pinhole_v - (HEIGHT - 1) / 2) / FOCAL
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    u = FOCAL * (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)) + (WIDTH - 1) / 2
    v = FOCAL * (y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y) + (HEIGHT - 1) / 2
    assert math.hypot(u - pinhole_u, v - pinhole_v) > 2, "the lens moves the taxel"
    write_sample(tmp_path, "mug", "trx3", surface_z=z + 0.001, dist=dist, t_w2c=t_w2c)
    sample = dataset.load(dataset.list_samples(tmp_path)[0])
    projected = taxels.active_taxels(sample.grasp, sample.camera)
    np.testing.assert_allclose(projected.uv[0], [u, v], atol=1e-6)
    np.testing.assert_allclose(projected.z[0], z, atol=1e-12)
    drawn = tile(one_sheet(tmp_path), 0, "taxels").astype(int)
    centre_v, centre_u = np.argwhere(np.any(drawn != RGB_BGR, axis=2)).mean(axis=0)
    assert abs(centre_u - u) < 0.5 and abs(centre_v - v) < 0.5, (centre_u, centre_v, u, v)


def test_a_taxel_behind_a_nearer_surface_is_a_ring(tmp_path: Path) -> None:
    u, v, z = expected_pixel()
    write_sample(tmp_path, "mug", "trx3", surface_z=z - 0.02)  # something 2 cm in front of it
    drawn = tile(one_sheet(tmp_path), 0, "taxels")
    np.testing.assert_array_equal(drawn[round(v), round(u)], RGB_BGR)
    assert np.any(drawn[round(v) - 6 : round(v) + 7, round(u) - 6 : round(u) + 7] != RGB_BGR)


def test_the_inactive_skin_is_drawn_faintly_only_from_the_layout_the_record_cites(tmp_path: Path) -> None:
    u, v, z = expected_pixel()
    p_inactive = P_PALM + np.array([0.03, 0.03, 0.0])
    x, y, zi = R_W2C @ (rodrigues(PALM_AXIS, PALM_DEG) @ p_inactive + PALM_P) + T_W2C
    ui, vi = round(FOCAL * x / zi + (WIDTH - 1) / 2), round(FOCAL * y / zi + (HEIGHT - 1) / 2)
    assert (ui - u) ** 2 + (vi - v) ** 2 > 8**2, "apart from the active dot"
    assert 0 <= ui < WIDTH and 0 <= vi < HEIGHT - FAR_ROWS
    sample_dir = tmp_path / "ds" / write_sample(tmp_path / "ds", "mug", "trx3", surface_z=max(z, zi) + 0.001)
    layout = "taxel,link,x,y,z,nx,ny,nz,region\n" + "".join(
        f"{i},palm,{p[0]:.6f},{p[1]:.6f},{p[2]:.6f},0,0,1,palm\n" for i, p in enumerate((p_inactive, P_PALM))
    )
    catalog = tmp_path / "catalog"
    (catalog / "hands" / "fake").mkdir(parents=True)
    (catalog / "hands" / "fake" / "taxels.csv").write_text(layout)
    record_path = tmp_path / "ds" / "mug.trx3.g000001" / "grasp.json"
    record = json.loads(record_path.read_text())

    def faint_pixel(sha256: str) -> np.ndarray:
        record["hand"]["taxels"] = {"layout": "hands/fake/taxels.csv", "count": 2, "sha256": sha256}
        record_path.write_text(json.dumps(record))
        chosen = [dataset.load(ref) for ref in dataset.list_samples(sample_dir.parent)]
        return tile(sheet.compose(chosen, catalog).image, 0, "taxels")[vi, ui]

    assert np.all(faint_pixel(hashlib.sha256(layout.encode()).hexdigest()) > RGB_BGR), "a faint light dot"
    np.testing.assert_array_equal(faint_pixel("0" * 64), RGB_BGR)


def test_segmentation_has_a_distinct_colour_per_label_and_black_background(tmp_path: Path) -> None:
    write_sample(tmp_path, "mug", "trx3", surface_z=0.5)
    seg = tile(one_sheet(tmp_path), 0, "segmentation")
    colours = [
        tuple(int(c) for c in seg[HEIGHT // 2, label * WIDTH // 5 + WIDTH // 10]) for label in range(5)
    ]
    assert colours[0] == (0, 0, 0), "background"
    assert len(set(colours)) == 5, colours
    for label, colour in enumerate(colours):  # each band is one flat colour
        band = seg[:, label * WIDTH // 5 + 1 : (label + 1) * WIDTH // 5 - 1]
        assert np.all(band == colour), label
    by_name = tiles.segment_colours({int(k): v for k, v in SEGMENT_NAMES.items()})
    assert colours[1] == by_name[1] == tiles.bgr(tiles.OBJECT_RGB)
    assert colours[2:4] == [tiles.bgr(c) for c in tiles.HAND_RGB[:2]], "hand links in id order"
    assert colours[4] == tiles.bgr(tiles.OTHER_RGB[0]), "the table from the other labels' palette"


def test_every_hand_link_and_other_label_has_its_own_colour() -> None:
    allegro = {0: "background", 1: "object"} | {2 + k: f"hand/link{k}" for k in range(17)}
    allegro |= {19: "arm/flange", 20: "arm/link", 21: "scene/table"}
    colours = tiles.segment_colours(allegro)
    assert len(set(colours.values())) == len(allegro)
    trx3 = {0: "background", 1: "object", 2: "hand/palm", 3: "arm/flange", 4: "arm/link", 5: "scene/table"}
    assert tiles.segment_colours(trx3)[5] == colours[21], "a table is the same colour beside any hand"


@pytest.mark.parametrize("depth_format", ["png", "npy"])
def test_a_missing_modality_is_a_grey_tile_and_depth_shares_one_range(
    tmp_path: Path, depth_format: str
) -> None:
    write_sample(tmp_path / "clean", "mug", "trx3", surface_z=0.5, depth_format=depth_format)
    image = one_sheet(tmp_path / "clean")
    missing = tile(image, 0, "depth_noisy")
    grey = np.all(missing == tiles.MISSING_GREY, axis=2)
    assert grey.mean() > 0.95, "grey but for its label"
    assert not grey.all(), "labelled"
    depth = tile(image, 0, "depth")
    assert np.all(depth[:20, :20] == 0), "no return is black"
    assert not np.all(depth[100:, 100:] == tiles.MISSING_GREY)

    write_sample(tmp_path / "noisy", "mug", "trx3", surface_z=0.5, noisy=True, depth_format=depth_format)
    image = one_sheet(tmp_path / "noisy")
    clean, noisy = tile(image, 0, "depth"), tile(image, 0, "depth_noisy")
    assert np.all(noisy[:20, :20] == 0), "holes are black"
    # Beyond the clean range's far end: the clean depth's far colour, dimmed (its own range would
    # make it the near colour).
    far = clean[-5, 100]
    assert not np.array_equal(far, clean[100, 100])
    np.testing.assert_array_equal(noisy[100, 100], far // tiles.OUT_OF_RANGE_DIM)
    np.testing.assert_array_equal(noisy[-5, 100], far // tiles.OUT_OF_RANGE_DIM)


def test_samples_are_spread_over_objects_and_hands() -> None:
    refs = [
        dataset.SampleRef(f"{o}.{h}.g{g:06d}.v{v:02d}", o, h, Path("."))
        for o in ("can", "mug", "box")
        for h in ("allegro", "trx3")
        for g in (1, 2)
        for v in (0, 1)
    ]
    picked = dataset.choose(refs, 3)
    assert {r.object for r in picked} == {"box", "can", "mug"}
    assert {r.hand for r in picked} == {"allegro", "trx3"}
    six = dataset.choose(refs, 6)
    assert len({(r.object, r.hand) for r in six}) == 6, "every pair before any second sample"
    assert all(r.sample_id.endswith("g000001.v00") for r in six), "each pair's first sample"
    rest = sorted((r for r in refs if r not in six), key=lambda r: r.sample_id)
    assert dataset.choose(refs, 8)[6:] == rest[:2], "then by id"
    assert dataset.choose(list(reversed(refs)), 8) == dataset.choose(refs, 8), "whatever order they come in"


def run_preview(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ENGINES_DIR)}
    return subprocess.run(
        [sys.executable, "-m", "vint_engines", "preview", *args], capture_output=True, text=True, env=env
    )


def test_the_command_writes_a_png_of_rows_by_columns_tiles_and_summarises_it(tmp_path: Path) -> None:
    ids = [write_sample(tmp_path / "ds", o, h, 0.5) for o, h in (("mug", "trx3"), ("can", "allegro"))]
    out = tmp_path / "sheets" / "sheet.png"
    done = run_preview("--dataset", str(tmp_path / "ds"), "--out", str(out), "--json")
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    width, height = len(sheet.COLUMNS) * WIDTH, sheet.HEADER_PX + 2 * (sheet.CAPTION_PX + HEIGHT)
    assert summary["size"] == [width, height]
    assert summary["tile"] == [WIDTH, HEIGHT]
    assert sorted(summary["samples"]) == sorted(ids)
    assert summary["path"] == str(out)
    image = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
    assert image.shape == (height, width, 3)


@pytest.mark.parametrize("case", ["missing", "empty", "not-json", "no-camera", "no-grasp-record"])
def test_bad_input_exits_2_naming_the_path(tmp_path: Path, case: str) -> None:
    root = tmp_path / "ds"
    if case != "missing":
        root.mkdir()
    if case == "not-json":
        (root / "mug.trx3.g000001.v00").mkdir()
        (root / "mug.trx3.g000001.v00" / "meta.json").write_text("{")
    if case in ("no-camera", "no-grasp-record"):
        sample = root / write_sample(root, "mug", "trx3", 0.5)
        if case == "no-camera":
            meta = json.loads((sample / "meta.json").read_text())
            del meta["camera"]["K"]
            (sample / "meta.json").write_text(json.dumps(meta))
        else:
            (root / "mug.trx3.g000001" / "grasp.json").unlink()
    done = run_preview("--dataset", str(root), "--out", str(tmp_path / "sheet.png"))
    assert done.returncode == 2, done.stderr
    assert done.stderr.startswith("preview: ") and str(root) in done.stderr, done.stderr
    assert not (tmp_path / "sheet.png").exists()
