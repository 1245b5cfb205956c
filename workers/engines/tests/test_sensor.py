"""The colour sensor model against its equations, computed here: on flat patches the linear-light
mean is the exposure and white-balance gains times the input and the variance is shot · x + read;
it is seeded by the view, leaves the camera's draws alone, saturates after the exposure, and off
means the image as rendered. The 8-bit encoding is the sRGB curve, recomputed here."""

from __future__ import annotations

import numpy as np

from vint_engines.render.sensor import SensorModel, capture, encode_srgb8


def flat(x: float) -> np.ndarray:
    return np.full((400, 400, 3), x, np.float32)


def test_off_is_the_rendered_image() -> None:
    image = np.random.default_rng(0).random((32, 32, 3), dtype=np.float32)
    out, record = capture(image, SensorModel(enabled=False), 7)
    assert out is image and record == {"enabled": False}


def test_gains_and_noise_follow_the_poissonian_gaussian_model() -> None:
    model = SensorModel(exposure_ev_sigma=0.3, white_balance_sigma=0.05, shot_noise=0.004, read_noise=2e-5)
    for x in (0.05, 0.2, 0.5):
        out, record = capture(flat(x), model, 11)
        red, green, blue = record["white_balance_gains_rgb"]
        assert green == 1.0
        for channel, wb in ((0, red), (1, green), (2, blue)):
            signal = x * record["exposure_gain"] * wb
            measured = out[..., channel]
            assert abs(measured.mean() - signal) < 0.01 * signal + 0.001, (x, channel)
            expected_var = 0.004 * signal + 2e-5
            assert 0.9 * expected_var < measured.var() < 1.1 * expected_var, (x, channel)


def test_saturates_after_the_exposure() -> None:
    """A highlight above full scale that a short exposure brings under it keeps its level."""
    model = SensorModel(exposure_ev_sigma=0.0, white_balance_sigma=0.0, shot_noise=0.0, read_noise=0.0)
    bright = np.array([[[1.6, 0.5, 2.0]]], np.float32)
    out, _ = capture(bright, model, 3)
    assert np.allclose(out, [[[1.0, 0.5, 1.0]]])
    short = SensorModel(exposure_ev_sigma=1.0, white_balance_sigma=0.0, shot_noise=0.0, read_noise=0.0)
    seed = next(s for s in range(100) if capture(bright, short, s)[1]["exposure_gain"] < 0.45)
    out, record = capture(bright, short, seed)
    assert np.allclose(out, bright * record["exposure_gain"], atol=1e-6)


def test_seeded_by_the_view_and_different_between_views() -> None:
    image = flat(0.2)
    a, ra = capture(image, SensorModel(), 5)
    b, rb = capture(image, SensorModel(), 5)
    c, rc = capture(image, SensorModel(), 6)
    assert np.array_equal(a, b) and ra == rb
    assert not np.array_equal(a, c) and ra != rc


def test_exposure_spread_matches_its_sigma() -> None:
    gains = [
        capture(flat(0.2)[:4, :4], SensorModel(exposure_ev_sigma=0.2), seed)[1]["exposure_gain"]
        for seed in range(400)
    ]
    ev = np.log2(gains)
    assert abs(ev.mean()) < 0.03 and abs(ev.std() - 0.2) < 0.03


def test_srgb_encoding_is_the_iec_curve() -> None:
    """Every 8-bit level decodes (IEC 61966-2-1's inverse) to a linear value that encodes back to
    it; out-of-range light clips to 0 and 255."""
    levels = np.arange(256) / 255.0
    linear = np.where(levels <= 0.04045, levels / 12.92, ((levels + 0.055) / 1.055) ** 2.4)
    assert np.array_equal(encode_srgb8(linear), np.arange(256, dtype=np.uint8))
    assert encode_srgb8(np.array([-0.5, 0.0, 1.0, 7.0])).tolist() == [0, 0, 255, 255]
