"""What the noise model knows about the sensor and the surfaces it sees: the Azure Kinect depth
modes (from the stage contract, which takes them from Microsoft's hardware specification), the
axial-noise calibration, and the IR reflectivity of each material tag.

Sources and assumptions are listed in docs/depth_noise.md; every figure that is ours, not a cited
one, says so here too.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from vint_engines import contract
from vint_engines.protocol import BadInput

# Microsoft, Azure Kinect DK hardware specification ("Depth camera" / "Depth accuracy"): random
# error σ ≤ 17 mm within the operating range, for surfaces of 15 % to 95 % reflectivity at 850 nm;
# Tölgyessy et al. (Sensors 21(2):413, 2021) confirm σ ≤ 17 mm in all four modes.
SPEC_SIGMA_MAX_M = 0.017
SPEC_REFLECTIVITY_MIN = 0.15
# Our assumption: the noise floor at close range, on a bright surface (BlenderProc's Kinect model
# uses 0.5 mm at 0.5 m; FACTS.md, "Depth sensor").
SIGMA_FLOOR_M = 0.0005
# Our assumption: beyond this incidence the return is too weak and the pixel reads invalid.
MAX_INCIDENCE_DEG = 85.0

DIFFUSE, GLASS, METAL = 0, 1, 2

# IR (850 nm) reflectivity per catalog material tag, and how the surface behaves. The numbers are
# our assumptions (typical diffuse NIR reflectances; Tölgyessy et al. measured 18 materials and
# found dark and specular ones noisier or invalid, but we do not have their per-material figures).
MATERIALS: dict[str, tuple[float, int]] = {
    "plastic": (0.5, DIFFUSE),
    "metal": (0.2, METAL),  # weak diffuse return; saturates near the mirror direction
    "glass": (0.05, GLASS),  # mostly transmits: the sensor sees what lies behind, or nothing
    "paper": (0.8, DIFFUSE),
    "cardboard": (0.6, DIFFUSE),
    "wood": (0.5, DIFFUSE),
    "ceramic": (0.7, DIFFUSE),
    "rubber": (0.1, DIFFUSE),  # dark: the hand's tag (render/scene.py: HAND_MATERIAL_TAG)
}
# The reflectivity every surface gets when materials are switched off: a mid-grey reference.
REFERENCE_REFLECTIVITY = 0.5


@dataclass(frozen=True)
class Mode:
    """An Azure Kinect depth mode (contract.schema.json `depth_modes`)."""

    name: str
    width_px: int
    height_px: int
    fov_h_deg: float
    fov_v_deg: float
    min_range_m: float
    max_range_m: float

    @staticmethod
    def named(name: str) -> Mode:
        modes: Mapping[str, Mapping[str, float]] = contract.schema()["depth_modes"]
        if name not in modes:
            raise BadInput(f"unknown depth mode {name!r} (modes: {sorted(modes)})")
        f = modes[name]
        return Mode(
            name,
            int(f["width_px"]),
            int(f["height_px"]),
            float(f["fov_h_deg"]),
            float(f["fov_v_deg"]),
            float(f["min_range_m"]),
            float(f["max_range_m"]),
        )

    @property
    def pixel_angle_rad(self) -> float:
        """The angle one native pixel spans (horizontal FOV / width; the modes' pixels are square
        to within 1 %)."""
        return math.radians(self.fov_h_deg) / self.width_px

    @property
    def sigma_gain(self) -> float:
        """k in σ² = σ_floor² + k² d² / (rho cos θ): the shot-noise term of an AMCW ToF pixel, whose
        signal falls as rho cos θ / d². Calibrated so that σ reaches the specified 17 mm at the
        mode's maximum range on the darkest specified surface (rho = 0.15, normal incidence): the
        operating range ends where the random error reaches its bound (our reading of the spec)."""
        excess = SPEC_SIGMA_MAX_M**2 - SIGMA_FLOOR_M**2
        return math.sqrt(excess * SPEC_REFLECTIVITY_MIN) / self.max_range_m


def material(tag: str) -> tuple[float, int]:
    """(IR reflectivity, kind) of a material tag."""
    if tag not in MATERIALS:
        raise BadInput(f"unknown material tag {tag!r} (known: {sorted(MATERIALS)})")
    return MATERIALS[tag]
