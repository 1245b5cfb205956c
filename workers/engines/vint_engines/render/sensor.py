"""The colour camera's sensor, applied to the path-traced image: an exposure error, a white-balance
error and the sensor's noise. Plain numpy, seeded by the view.

A rendered image is what a perfect camera would record; a robot's colour camera misjudges exposure
and white balance a little from frame to frame, and its pixels carry photon shot noise and read
noise. The model works in linear light, on the rendered (or denoised) float image x: an exposure
gain 2^e (e ~ N(0, exposure_ev_sigma)) and per-channel white-balance gains (red and blue exp(w),
w ~ N(0, white_balance_sigma), green 1: a camera's balance is set against green), then
heteroscedastic Gaussian noise of variance `shot_noise` · x + `read_noise` — the
Poissonian–Gaussian model of Foi et al. ("Practical Poissonian-Gaussian noise modeling and fitting
for single-image raw-data", IEEE TIP 2008), per channel after demosaicking (the demosaic's spatial
correlation is left out) — then a clip to [0, 1]: the sensor saturates after the exposure, so a
highlight that a short exposure brings under full scale keeps its gradation. The defaults are the
middle of the ranges Brooks et al. fitted to real cameras ("Unprocessing Images for Learned Raw
Denoising", CVPR 2019: shot noise log-uniform over [1e-4, 1.2e-2], log read = 2.18 · log shot +
1.2): shot 0.002 and read 4.3e-6, a well-lit indoor scene. `encode_srgb8` then makes the 8-bit
image, with or without the sensor: the sRGB transfer curve (IEC 61966-2-1), rounded, no dither.

Its random stream is the view's seed with `SENSOR_STREAM` appended, so it never shifts the
camera's draws, and the same view gets the same noise whatever renders it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

SENSOR_STREAM = 0x5E  # appended to the view's seed: the sensor's own random stream


@dataclass(frozen=True)
class SensorModel:
    """`render.sensor` of a render task: fields, bounds and defaults are `RenderSensor` in the stage
    contract."""

    enabled: bool = True
    exposure_ev_sigma: float = 0.2
    white_balance_sigma: float = 0.03
    shot_noise: float = 0.002
    read_noise: float = 4.3e-6

    @staticmethod
    def from_fields(fields: Mapping[str, Any]) -> SensorModel:
        return SensorModel(
            enabled=bool(fields["enabled"]),
            exposure_ev_sigma=float(fields["exposure_ev_sigma"]),
            white_balance_sigma=float(fields["white_balance_sigma"]),
            shot_noise=float(fields["shot_noise"]),
            read_noise=float(fields["read_noise"]),
        )


def linear_to_srgb(x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.maximum(x, 0.0031308), 1 / 2.4) - 0.055)


def encode_srgb8(linear: npt.NDArray[np.floating]) -> npt.NDArray[np.uint8]:
    """Linear light (clipped to [0, 1]) as 8-bit sRGB, rounded to the nearest level."""
    clipped = np.clip(linear.astype(np.float64), 0.0, 1.0)
    return np.rint(linear_to_srgb(clipped) * 255.0).astype(np.uint8)


def capture(
    linear_rgb: npt.NDArray[np.floating], model: SensorModel, seed: int
) -> tuple[npt.NDArray[np.floating], dict[str, Any]]:
    """The image (H×W×3 linear light, R, G, B) as the sensor records it, still linear, and what
    it drew (for the camera record)."""
    if not model.enabled:
        return linear_rgb, {"enabled": False}
    rng = np.random.default_rng([seed, SENSOR_STREAM])
    exposure = float(2.0 ** rng.normal(0.0, model.exposure_ev_sigma))
    red, blue = np.exp(rng.normal(0.0, model.white_balance_sigma, size=2))
    gains = np.array([red, 1.0, blue]) * exposure
    linear = np.maximum(linear_rgb.astype(np.float64), 0.0) * gains  # a denoiser's undershoot is no light
    sigma = np.sqrt(model.shot_noise * linear + model.read_noise)
    out = np.clip(linear + sigma * rng.standard_normal(linear.shape), 0.0, 1.0)
    record = {
        "enabled": True,
        "exposure_gain": round(exposure, 6),
        "white_balance_gains_rgb": [round(float(red), 6), 1.0, round(float(blue), 6)],
        "shot_noise": model.shot_noise,
        "read_noise": model.read_noise,
    }
    return out, record
