"""Viewpoint control: a sampled view's camera is redrawn, seeded and bounded, until its occlusion
lies within `render.occlusion` (and, optionally, it stands in front of the palm). The search on its
own (no Blender), then the engine: every view's occlusion recomputed from its written mask files,
the palm side from the grasp record's palm pose, and the same seed giving the same camera."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from conftest import EngineProcess, new_dir, started_engine, trx3_grasps

from vint_engines.objects import load_catalog
from vint_engines.poses import quat_to_matrix
from vint_engines.render.camera import CameraPose, look_at
from vint_engines.render.viewpoint import MAX_CAMERA_ATTEMPTS, Palm, ViewpointRule, attempt_rng, search

# -- the search alone ------------------------------------------------------------------------------


def camera_at(x: float) -> CameraPose:
    return look_at(np.array([x, -1.0, 0.5]), np.zeros(3))


def scripted(occlusions: list[float]) -> tuple[Any, Any, list[int]]:
    """A draw that puts attempt k at x = k and a measure that reads attempt k's occlusion from
    `occlusions`; `measured` lists the attempts measured."""
    measured: list[int] = []

    def draw(attempt: int) -> CameraPose:
        return camera_at(float(attempt))

    def measure(camera: CameraPose) -> tuple[int, float]:
        attempt = round(float(camera.position[0]))
        measured.append(attempt)
        return attempt, occlusions[attempt]

    return draw, measure, measured


def test_the_first_attempt_in_range_is_kept_and_none_after_it_is_drawn() -> None:
    draw, measure, measured = scripted([0.02, 0.95, 0.5, 0.4])
    chosen = search(draw, measure, ViewpointRule((0.1, 0.9)), None, max_attempts=4)
    assert (chosen.geometry, chosen.occlusion, chosen.attempts, chosen.renders) == (2, 0.5, 3, 3)
    assert chosen.occlusion_in_range and measured == [0, 1, 2]


def test_the_range_includes_its_ends() -> None:
    draw, measure, _ = scripted([0.1])
    assert search(draw, measure, ViewpointRule((0.1, 0.9)), None, max_attempts=1).occlusion_in_range


def test_without_an_attempt_in_range_the_nearest_is_kept_and_flagged() -> None:
    draw, measure, measured = scripted([0.0, 0.97, 0.93, 1.0])
    chosen = search(draw, measure, ViewpointRule((0.1, 0.9)), None, max_attempts=4)
    assert (chosen.geometry, chosen.attempts, chosen.renders) == (2, 4, 4)
    assert not chosen.occlusion_in_range
    record = chosen.record(ViewpointRule((0.1, 0.9)))
    assert record["occlusion_in_range"] is False and record["attempts"] == 4
    assert measured == [0, 1, 2, 3], "the nearest miss is kept, not rendered again"


def test_cameras_behind_the_palm_are_rejected_before_any_render() -> None:
    # The palm at the origin faces +x: attempts 0-2 stand at x <= 0 (behind or on its plane's back).
    palm = Palm(point=np.array([0.5, 0.0, 0.0]), normal=np.array([1.0, 0.0, 0.0]))
    draw, measure, measured = scripted([0.5] * 6)
    chosen = search(draw, measure, ViewpointRule((0.1, 0.9), "front"), palm, max_attempts=6)
    assert chosen.geometry == 1 and measured == [1]
    assert chosen.palm_facing is not None and chosen.palm_facing > 0.0
    assert chosen.record(ViewpointRule((0.1, 0.9), "front"))["palm_side"] == "front"


def test_when_every_attempt_stands_behind_the_palm_the_nearest_is_rendered() -> None:
    palm = Palm(point=np.array([10.0, 0.0, 0.0]), normal=np.array([1.0, 0.0, 0.0]))
    draw, measure, measured = scripted([0.5] * 3)
    chosen = search(draw, measure, ViewpointRule((0.1, 0.9), "front"), palm, max_attempts=3)
    assert measured == [2], "attempt 2 is the least far behind the palm"
    assert chosen.record(ViewpointRule((0.1, 0.9), "front"))["palm_side"] == "back"


def test_attempt_zero_is_the_views_own_stream_and_redraws_are_functions_of_seed_and_attempt() -> None:
    assert attempt_rng(77, 0).random() == np.random.default_rng(77).random()
    firsts = [attempt_rng(77, k).random() for k in range(MAX_CAMERA_ATTEMPTS)]
    assert len(set(firsts)) == MAX_CAMERA_ATTEMPTS
    assert [attempt_rng(77, k).random() for k in (5, 3)] == [firsts[5], firsts[3]]
    assert attempt_rng(78, 3).random() != firsts[3]


# -- the engine -----------------------------------------------------------------------------------

RENDER = {
    "width": 64,
    "height": 64,
    "samples": 1,
    "fov_deg": 60.0,
    "environment": "studio",
    "radius_m": [0.2, 0.25],
    "elevation_deg": [15.0, 75.0],
}
VIEWS = [{"view_index": v, "seed": 1000 + v} for v in range(8)]
NARROW = [0.3, 0.6]  # far narrower than the default, so many views need redraws


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("viewpoint")


@pytest.fixture(scope="module")
def grasp(workdir: Path) -> dict[str, Any]:
    """An accepted grasp of the tomato soup can by trx3, from the real grasp engine."""
    out = new_dir(workdir, "grasp")
    doc = trx3_grasps(out, load_catalog()["tomato_soup_can"].to_json())
    trial = next(t for t in doc["trials"] if t["accepted"])
    return {"dir": out, "trial": trial}


@pytest.fixture(scope="module")
def engine(workdir: Path) -> Iterator[EngineProcess]:
    with started_engine("render", workdir) as process:
        yield process


def render(engine: EngineProcess, grasp: dict[str, Any], out: Path, **settings: Any) -> dict[str, Any]:
    params = {
        "grasp_index": grasp["trial"]["grasp_index"],
        "render": {**RENDER, **settings},
        "views": VIEWS,
        "outputs": ["mask"],
    }
    reply = engine.task(out.name, params, out, [grasp["dir"] / "grasps.json", grasp["dir"] / "object.ply"])
    assert reply["ok"] is True, reply
    return reply


def mask_occlusion(out: Path, view: int) -> float:
    """1 - visible / full from the written masks alone."""
    visible = cv2.imread(str(out / f"v{view:02d}_mask.png"), cv2.IMREAD_UNCHANGED) > 0
    full = cv2.imread(str(out / f"v{view:02d}_mask_full.png"), cv2.IMREAD_UNCHANGED) > 0
    full_px = int(np.count_nonzero(full | visible))
    return 1.0 if full_px == 0 else 1.0 - int(np.count_nonzero(visible)) / full_px


def cameras(out: Path) -> list[dict[str, Any]]:
    return [json.loads((out / f"v{v:02d}_camera.json").read_text()) for v in range(len(VIEWS))]


def test_every_view_is_redrawn_into_the_occlusion_range_and_the_same_seed_gives_the_same_camera(
    engine: EngineProcess, grasp: dict[str, Any], workdir: Path
) -> None:
    first, again = new_dir(workdir, "narrow"), new_dir(workdir, "narrow_again")
    reply = render(engine, grasp, first, occlusion=NARROW)
    render(engine, grasp, again, occlusion=NARROW)
    records = cameras(first)
    for v, record in enumerate(records):
        found = mask_occlusion(first, v)
        assert NARROW[0] <= found <= NARROW[1], f"v{v:02d}: {found} ({record['viewpoint']})"
        assert record["occlusion"] == pytest.approx(found, abs=1e-6)
        assert record["viewpoint"]["occlusion_in_range"] is True
        assert record["viewpoint"]["source"] == "sampled"
    attempts = [record["viewpoint"]["attempts"] for record in records]
    assert max(attempts) > 1, f"a range this narrow needs redraws: {attempts}"
    assert reply["metrics"]["camera_attempts_per_view"] == pytest.approx(sum(attempts) / len(VIEWS), abs=1e-3)
    assert reply["metrics"]["views_out_of_occlusion_range"] == 0
    for record, repeat in zip(records, cameras(again), strict=True):
        assert (repeat["R_w2c"], repeat["t_w2c"]) == (record["R_w2c"], record["t_w2c"])
        assert repeat["viewpoint"] == record["viewpoint"]


def test_a_full_range_keeps_every_first_draw(
    engine: EngineProcess, grasp: dict[str, Any], workdir: Path
) -> None:
    """[0, 1] accepts every camera: each view keeps attempt 0, the camera drawn from its seed alone
    (so the narrow range's views that needed no redraw have exactly these cameras)."""
    narrow, full = new_dir(workdir, "narrow_ref"), new_dir(workdir, "full")
    render(engine, grasp, narrow, occlusion=NARROW)
    render(engine, grasp, full, occlusion=[0.0, 1.0])
    for kept, drawn in zip(cameras(narrow), cameras(full), strict=True):
        assert drawn["viewpoint"]["attempts"] == 1
        if kept["viewpoint"]["attempts"] == 1:
            assert kept["R_w2c"] == drawn["R_w2c"]


def test_palm_front_keeps_every_camera_in_front_of_the_palm(
    engine: EngineProcess, grasp: dict[str, Any], workdir: Path
) -> None:
    out = new_dir(workdir, "front")
    render(engine, grasp, out, palm_side="front", occlusion=[0.0, 1.0])
    palm = grasp["trial"]["link_poses"]["palm"]
    p_palm, n_palm = np.array(palm["p"]), quat_to_matrix(np.array(palm["q"]))[:, 2]
    for v, record in enumerate(cameras(out)):
        R, t = np.array(record["R_w2c"]), np.array(record["t_w2c"])
        position = -R.T @ t
        assert float(np.dot(position - p_palm, n_palm)) > 0.0, f"v{v:02d} stands behind the palm"
        assert record["viewpoint"]["palm_side"] == "front"
