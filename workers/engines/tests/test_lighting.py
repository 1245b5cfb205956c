"""The light's per-view randomisation against colour science computed here and the render it
drives: a black body's tint is neutral at 6504 K, warm below and cool above, always of unit
luminance; draws are seeded by the view and off by default; a view under a warm light is warmer
and records what it drew."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import new_dir, started_engine

from vint_engines.grasp.engine import GraspEngine
from vint_engines.objects import load_catalog
from vint_engines.protocol import TaskRequest
from vint_engines.render.lighting import LightJitter, blackbody_tint, draw


def test_a_black_bodys_tint_is_neutral_at_daylight_warm_below_cool_above_and_of_unit_luminance() -> None:
    np.testing.assert_allclose(blackbody_tint(6504.0), (1.0, 1.0, 1.0), atol=1e-9)
    warm, cool = blackbody_tint(3000.0), blackbody_tint(10000.0)
    assert warm[0] > warm[1] > warm[2], warm  # a tungsten lamp: red over blue
    assert cool[2] > cool[1] > cool[0], cool  # overcast sky: blue over red
    for kelvin in (1700.0, 2700.0, 4000.0, 5000.0, 6504.0, 8000.0, 20000.0):
        r, g, b = blackbody_tint(kelvin)
        assert abs(0.2126 * r + 0.7152 * g + 0.0722 * b - 1.0) < 1e-9
    # Hotter is bluer, monotonically.
    ratios = [blackbody_tint(k)[2] / blackbody_tint(k)[0] for k in range(2000, 12000, 500)]
    assert all(a < b for a, b in itertools.pairwise(ratios))


def test_draws_are_seeded_by_the_view_and_off_by_default() -> None:
    off = draw(LightJitter(), 5, 30.0, 1.2)
    assert (off.strength, off.rotation_deg, off.tint) == (1.2, 30.0, (1.0, 1.0, 1.0))
    jitter = LightJitter(strength_ev_sigma=0.5, rotation_jitter_deg=45.0, temperature_k=(3000.0, 9000.0))
    assert draw(jitter, 5, 30.0, 1.2) == draw(jitter, 5, 30.0, 1.2)
    draws = [draw(jitter, seed, 30.0, 1.0) for seed in range(300)]
    assert all(abs(d.rotation_deg - 30.0) <= 45.0 for d in draws)
    assert all(3000.0 <= d.temperature_k <= 9000.0 for d in draws)
    ev = np.log2([d.strength for d in draws])
    assert abs(ev.std() - 0.5) < 0.07 and abs(ev.mean()) < 0.1


@pytest.fixture(scope="module")
def grasp(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = new_dir(tmp_path_factory.mktemp("lighting"), "grasp")
    params = {
        "object": load_catalog()["mug"].to_json(),
        "hand": {"name": "trx3"},
        "trials": [{"grasp_index": i, "seed": 42 + i} for i in range(3)],
    }
    GraspEngine().run(TaskRequest("grasp", params, (), out))
    return out


def test_a_warm_light_warms_the_image_and_the_record_says_what_it_drew(grasp: Path, tmp_path: Path) -> None:
    doc = json.loads((grasp / "grasps.json").read_text())
    index = next(t["grasp_index"] for t in doc["trials"] if t["accepted"])
    with started_engine("render", tmp_path) as engine:
        base = {"width": 48, "height": 48, "samples": 4, "sensor": {"enabled": False}}
        images = {}
        for name, light in (
            ("neutral", {}),
            ("warm", {"temperature_k": [2500.0, 2500.0]}),
        ):
            out = new_dir(tmp_path, name)
            params = {
                "grasp_index": index,
                "render": {**base, "light": light},
                "views": [{"view_index": 0, "seed": 9}],
                "outputs": ["rgb"],
            }
            reply = engine.task(name, params, out, [grasp / "grasps.json", grasp / "object.ply"])
            assert reply["ok"] is True, reply
            images[name] = cv2.imread(str(out / "v00_rgb.png")).astype(np.float64)
            record = json.loads((out / "v00_camera.json").read_text())["light"]
            expected_tint = [1.0, 1.0, 1.0] if name == "neutral" else list(blackbody_tint(2500.0))
            np.testing.assert_allclose(record["tint_rgb"], expected_tint, atol=1e-6)
    neutral, warm = images["neutral"], images["warm"]  # BGR
    red_over_blue = lambda img: img[..., 2].mean() / max(img[..., 0].mean(), 1.0)  # noqa: E731
    assert red_over_blue(warm) > 1.3 * red_over_blue(neutral)
