"""Per-view randomisation of the light: the environment's strength, its turn about world +z and its
colour temperature, drawn from the view's seed on a stream of its own. Plain numpy.

An HDRI is one photograph of one room at one moment; a robot sees the same room brighter or
dimmer, lit from another side as it moves, under warmer or cooler lamps. `render.light` draws, per
view: a strength factor 2^e with e ~ N(0, `strength_ev_sigma`), a turn added to the environment's
own `rotation_deg`, uniform within ±`rotation_jitter_deg`, and a colour temperature uniform in
`temperature_k` whose tint multiplies the environment's colour. The tint is a black body's colour
relative to daylight: the Planckian locus's chromaticity (the cubic fit of Kim et al., "Design of
advanced color temperature control system for HDTV applications", J. Korean Phys. Soc. 2002,
valid 1667–25000 K),
converted to linear sRGB, divided by the same at 6504 K (so 6504 K is neutral) and scaled to unit
luminance (Rec. 709 weights), so a tint changes colour, never brightness. All three are off by
default: the spec's own environments are what a dataset gets unless it asks for more. A turn makes
Cycles' importance map of the HDRI byte-unstable between processes (docs/rendering.md), so a spec
that jitters rotations gives up byte-reproducibility across processes for its RGB.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

LIGHT_STREAM = 0x7A  # appended to the view's seed: the light's own random stream
NEUTRAL_K = 6504.0
# XYZ → linear sRGB (IEC 61966-2-1, D65).
XYZ_TO_SRGB = np.array(
    [
        [3.2404542, -1.5371385, -0.4985314],
        [-0.9692660, 1.8760108, 0.0415560],
        [0.0556434, -0.2040259, 1.0572252],
    ]
)
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


@dataclass(frozen=True)
class LightJitter:
    """`render.light` of a render task: fields, bounds and defaults are `RenderLight` in the stage
    contract."""

    strength_ev_sigma: float = 0.0
    rotation_jitter_deg: float = 0.0
    temperature_k: tuple[float, float] = (NEUTRAL_K, NEUTRAL_K)

    @staticmethod
    def from_fields(fields: Mapping[str, Any]) -> LightJitter:
        low, high = fields["temperature_k"]
        return LightJitter(
            strength_ev_sigma=float(fields["strength_ev_sigma"]),
            rotation_jitter_deg=float(fields["rotation_jitter_deg"]),
            temperature_k=(float(low), float(high)),
        )


@dataclass(frozen=True)
class LightDraw:
    """What one view's light is: the environment's strength and turn, and the colour tint."""

    strength: float
    rotation_deg: float
    temperature_k: float
    tint: tuple[float, float, float]  # linear RGB

    def to_json(self) -> dict[str, Any]:
        return {
            "strength": round(self.strength, 6),
            "rotation_deg": round(self.rotation_deg, 6),
            "temperature_k": round(self.temperature_k, 3),
            "tint_rgb": [round(c, 6) for c in self.tint],
        }


def planckian_xy(kelvin: float) -> tuple[float, float]:
    """CIE 1931 chromaticity of a black body at `kelvin` (Kim et al.'s cubic fit, 1667–25000 K)."""
    t = float(np.clip(kelvin, 1667.0, 25000.0))
    if t <= 4000.0:
        x = -0.2661239e9 / t**3 - 0.2343589e6 / t**2 + 0.8776956e3 / t + 0.179910
    else:
        x = -3.0258469e9 / t**3 + 2.1070379e6 / t**2 + 0.2226347e3 / t + 0.240390
    if t <= 2222.0:
        y = -1.1063814 * x**3 - 1.34811020 * x**2 + 2.18555832 * x - 0.20219683
    elif t <= 4000.0:
        y = -0.9549476 * x**3 - 1.37418593 * x**2 + 2.09137015 * x - 0.16748867
    else:
        y = 3.0817580 * x**3 - 5.87338670 * x**2 + 3.75112997 * x - 0.37001483
    return x, y


def _linear_srgb(kelvin: float) -> np.ndarray:
    x, y = planckian_xy(kelvin)
    xyz = np.array([x / y, 1.0, (1.0 - x - y) / y])
    return XYZ_TO_SRGB @ xyz


def blackbody_tint(kelvin: float) -> tuple[float, float, float]:
    """The linear-RGB tint of light at `kelvin` relative to 6504 K, at unit luminance."""
    rgb = np.clip(_linear_srgb(kelvin) / _linear_srgb(NEUTRAL_K), 0.0, None)
    rgb = rgb / float(LUMINANCE @ rgb)
    return float(rgb[0]), float(rgb[1]), float(rgb[2])


def draw(jitter: LightJitter, seed: int, rotation_deg: float, strength: float) -> LightDraw:
    """One view's light around the environment's own `rotation_deg` and `strength`. Three draws,
    always made; with nothing to jitter the environment is as the spec gives it."""
    rng = np.random.default_rng([seed, LIGHT_STREAM])
    ev, turn, where = rng.normal(), rng.uniform(-1.0, 1.0), rng.uniform()
    low, high = jitter.temperature_k
    kelvin = low + where * (high - low)
    tint = (1.0, 1.0, 1.0) if low == high == NEUTRAL_K else blackbody_tint(kelvin)
    return LightDraw(
        strength=strength * float(2.0 ** (ev * jitter.strength_ev_sigma)),
        rotation_deg=rotation_deg + float(turn) * jitter.rotation_jitter_deg,
        temperature_k=kelvin,
        tint=tint,
    )
