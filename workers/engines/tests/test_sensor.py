"""The colour sensor model against its equations, computed here: on flat patches the linear-light
mean is the exposure and white-balance gains times the input and the variance is shot · x + read;
it is seeded by the view, leaves the camera's draws alone, and off means the image as rendered."""

from __future__ import annotations

import numpy as np

from vint_engines.render.sensor import SensorModel, capture


def to_linear(v: np.ndarray) -> np.ndarray:
    v = v / 255.0
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def flat(level: int) -> np.ndarray:
    return np.full((400, 400, 3), level, np.uint8)


def test_off_is_the_rendered_image() -> None:
    image = np.random.default_rng(0).integers(0, 256, (32, 32, 3), dtype=np.uint8)
    out, record = capture(image, SensorModel(enabled=False), 7)
    assert out is image and record == {"enabled": False}


def test_gains_and_noise_follow_the_poissonian_gaussian_model() -> None:
    model = SensorModel(exposure_ev_sigma=0.3, white_balance_sigma=0.05, shot_noise=0.004, read_noise=2e-5)
    for level in (60, 128, 190):
        out, record = capture(flat(level), model, 11)
        x = to_linear(np.array(float(level)))
        red, green, blue = record["white_balance_gains_rgb"]
        assert green == 1.0
        for channel, wb in ((2, red), (1, green), (0, blue)):  # BGR
            signal = x * record["exposure_gain"] * wb
            measured = to_linear(out[..., channel].astype(np.float64))
            assert abs(measured.mean() - signal) < 0.01 * signal + 0.002, (level, channel)
            expected_var = 0.004 * signal + 2e-5
            # 8-bit quantisation adds at most ~1/12 of a step squared (in linear units) to the variance.
            assert 0.8 * expected_var < measured.var() < 1.25 * expected_var + 1e-5, (level, channel)


def test_seeded_by_the_view_and_different_between_views() -> None:
    image = flat(120)
    a, ra = capture(image, SensorModel(), 5)
    b, rb = capture(image, SensorModel(), 5)
    c, rc = capture(image, SensorModel(), 6)
    assert np.array_equal(a, b) and ra == rb
    assert not np.array_equal(a, c) and ra != rc


def test_exposure_spread_matches_its_sigma() -> None:
    gains = [
        capture(flat(100)[:4, :4], SensorModel(exposure_ev_sigma=0.2), seed)[1]["exposure_gain"]
        for seed in range(400)
    ]
    ev = np.log2(gains)
    assert abs(ev.mean()) < 0.03 and abs(ev.std() - 0.2) < 0.03
