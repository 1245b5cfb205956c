"""An Azure-Kinect-like time-of-flight depth model over float32 depth maps (metres, 0 = invalid),
registered to the rendering camera. Each term, its equation and its source: docs/depth_noise.md.

In order, on one view:
1. invalid input (0, NaN, ±Inf, negative) stays invalid;
2. materials (switch `materials`): glass shows the surface behind it, or nothing; every surface
   gets its tag's IR reflectivity rho (dark → noisier);
   registration (switch `registration`): what the ToF camera beside the colour camera
   (`tof_baseline_m` away, tilted 6°) cannot see reads nothing: occlusion shadows beside the
   fingers and resampling holes along edges (`registration.py`);
3. lateral noise (`lateral`): each pixel samples the scene at a jittered position (σ in the mode's
   native pixels, converted to output pixels with the camera's focal length);
4. incidence angle θ from normals estimated on the depth map with the camera's intrinsics;
5. flying pixels (`flying_pixels`): a pixel whose native footprint straddles a depth step reads
   a signal-weighted mix of both depths, or is invalidated (the sensor's mixed-pixel filter);
6. axial noise, always: σ² = σ_floor² + k² d² / (rho cos θ), k calibrated per mode (`sensor.py`),
   spatially correlated by the depth engine's smoothing (`spatial_sigma_px`: the white field
   blurred by a Gaussian of that σ in native pixels and rescaled to unit variance, so σ per pixel
   stays as stated and neighbours correlate as exp(-r² / 4σ²); 0 leaves it white);
7. multipath (`multipath`): a positive bias in concave corners;
8. specular metal (`materials`): dropouts near the mirror direction;
9. readings outside the mode's range, or beyond 85° incidence, are invalid.

Randomness comes only from the generator passed in: it is split into one stream per piece, each
drawn whole-image whatever the content, so a seed fixes the output and switching one piece off
leaves the others' draws as they were.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from vint_engines import contract
from vint_engines.noise import geometry, registration, sensor
from vint_engines.noise.geometry import Intrinsics
from vint_engines.protocol import BadInput

Depth = npt.NDArray[np.float32]
Mask = npt.NDArray[np.bool_]

# Our assumption: the neighbourhood over which multipath light gathers in a corner (1 cm, the
# scale of a fingertip against an object), and the largest depth span it spans (larger steps are
# silhouettes, not corners).
MULTIPATH_RADIUS_M = 0.01
MULTIPATH_SPAN_M = 0.05
# The multipath bias never exceeds the specified systematic error (Microsoft: < 11 mm + 0.1 % d).
MULTIPATH_MAX_M = 0.011
# Glass shows the surface behind it only if that surface is at least this much farther.
GLASS_BEHIND_MIN_M = 0.005


@dataclass(frozen=True)
class Surfaces:
    """Per-pixel surface properties: IR reflectivity and kind (`sensor.DIFFUSE|GLASS|METAL`)."""

    reflectivity: npt.NDArray[np.float32]
    kind: npt.NDArray[np.uint8]

    @staticmethod
    def uniform(shape: tuple[int, ...]) -> Surfaces:
        return Surfaces(
            np.full(shape, sensor.REFERENCE_REFLECTIVITY, np.float32),
            np.full(shape, sensor.DIFFUSE, np.uint8),
        )

    @staticmethod
    def from_segmentation(segmentation: npt.NDArray[np.integer[Any]], materials: dict[int, str]) -> Surfaces:
        """Each pixel's material, from its segment id and the id → material tag map of the view's
        camera record. Background (no tag) keeps the reference values; it has no depth anyway."""
        top = int(segmentation.max(initial=0))
        known = max(materials, default=0)
        size = max(top, known) + 1
        rho = np.full(size, sensor.REFERENCE_REFLECTIVITY, np.float32)
        kind = np.full(size, sensor.DIFFUSE, np.uint8)
        for segment, tag in materials.items():
            rho[segment], kind[segment] = sensor.material(tag)
        ids = np.unique(segmentation)
        missing = [int(i) for i in ids if i != 0 and int(i) not in materials]
        if missing:
            raise BadInput(f"segment ids {missing} have no material in the camera record")
        return Surfaces(rho[segmentation], kind[segmentation])


@dataclass(frozen=True)
class NoiseModel:
    """Fields, bounds and defaults: `NoiseModel` in the stage contract; `parse({})` gives the
    defaults."""

    mode: sensor.Mode
    sigma_scale: float
    lateral: bool
    lateral_sigma_px: float
    flying_pixels: bool
    flying_jump_m: float
    flying_invalid_share: float
    multipath: bool
    multipath_gain: float
    materials: bool
    specular_cone_deg: float
    registration: bool
    tof_baseline_m: float
    spatial_sigma_px: float

    @staticmethod
    def parse(obj: Any, where: str = "params.noise") -> NoiseModel:
        fields = contract.validated_part("NoiseModel", obj, where)
        fields["mode"] = sensor.Mode.named(fields["mode"])
        return NoiseModel(**fields)

    def without(self, *pieces: str) -> NoiseModel:
        """This model with the named switches off (for studies and tests)."""
        return replace(self, **dict.fromkeys(pieces, False))

    def sigma(self, depth_m: Depth, cos_theta: Depth, reflectivity: Depth) -> Depth:
        """The axial σ (m) at `depth_m`, incidence cos θ and IR reflectivity rho."""
        k = self.mode.sigma_gain
        cos = np.maximum(cos_theta, np.float32(math.cos(math.radians(sensor.MAX_INCIDENCE_DEG))))
        variance = sensor.SIGMA_FLOOR_M**2 + (k * depth_m) ** 2 / (reflectivity * cos)
        return (self.sigma_scale * np.sqrt(variance)).astype(np.float32)

    def apply(
        self, depth: Depth, k: Intrinsics, surfaces: Surfaces | None, rng: np.random.Generator
    ) -> Depth:
        """A noisy copy of `depth` (H×W metres along the optical axis, 0 = invalid) seen by a camera
        with intrinsics `k`; `surfaces` is required when materials are on."""
        if depth.ndim != 2 or depth.size == 0:
            raise BadInput(f"depth map must be a non-empty H×W array, got shape {depth.shape}")
        if self.materials and surfaces is None:
            raise BadInput("the materials piece needs the view's segmentation and material tags")
        if surfaces is None or not self.materials:
            surfaces = Surfaces.uniform(depth.shape)
        elif surfaces.kind.shape != depth.shape:
            raise BadInput(f"segmentation shape {surfaces.kind.shape} differs from depth shape {depth.shape}")
        axial_rng, lateral_rng, flying_rng, specular_rng = rng.spawn(4)

        depth = depth.astype(np.float32, copy=False)
        valid = np.isfinite(depth) & (depth > 0)
        clean = np.where(valid, depth, np.float32(0))
        rho, kind = surfaces.reflectivity, surfaces.kind
        if self.materials:
            clean, valid, rho = _see_through_glass(clean, valid, rho, kind)
        if self.registration:
            valid &= registration.seen_by_tof(clean, valid, k, self.mode, self.tof_baseline_m)
            clean = np.where(valid, clean, np.float32(0))
        # Output pixels per native pixel of the mode, at the image centre.
        scale = self.mode.pixel_angle_rad * float(k.fx)
        if self.lateral and self.lateral_sigma_px > 0:
            clean, valid, rho, kind = _jitter(
                lateral_rng, self.lateral_sigma_px * scale, clean, valid, rho, kind
            )
        cos = geometry.cos_incidence(clean, valid, k)

        noisy = clean.copy()
        keep = valid.copy()
        if self.flying_pixels:
            noisy, keep = self._fly(flying_rng, clean, valid, rho, scale, noisy, keep)
        sigma = self.sigma(np.where(valid, noisy, 1.0).astype(np.float32), cos, rho)
        white = axial_rng.standard_normal(depth.shape, dtype=np.float32)
        noisy = noisy + sigma * correlated(white, self.spatial_sigma_px * scale)
        if self.multipath and self.multipath_gain > 0:
            noisy = noisy + self._multipath_bias(clean, valid, k)
        if self.materials:
            keep &= ~_mirror_dropouts(specular_rng, cos, kind, self.specular_cone_deg)
        keep &= (clean >= self.mode.min_range_m) & (clean <= self.mode.max_range_m)
        keep &= cos >= np.float32(math.cos(math.radians(sensor.MAX_INCIDENCE_DEG)))
        keep &= np.isfinite(noisy) & (noisy > 0)
        return np.where(keep, noisy, np.float32(0)).astype(np.float32)

    def _fly(
        self,
        rng: np.random.Generator,
        clean: Depth,
        valid: Mask,
        rho: npt.NDArray[np.float32],
        scale: float,
        noisy: Depth,
        keep: Mask,
    ) -> tuple[Depth, Mask]:
        """Mixed pixels at depth steps. A pixel within a footprint of a step straddles it with
        probability min(1, footprint) (the step lies anywhere between pixel centres); the other
        surface then covers a share w ~ U(0, ½) of it, and an AMCW pixel reads the phase of the
        summed returns, ≈ the mean depth weighted by each return's amplitude rho(1-w)/d² and rhow/d².
        A share of mixed pixels is invalidated instead; against a no-return background (nothing
        to mix with) a straddling pixel keeps its depth or is invalidated the same way."""
        half = max(1, round(scale / 2))
        low, high = geometry.local_span(clean, valid, 2 * half + 1)
        straddle_p = min(1.0, scale)
        draw_straddle = rng.random(clean.shape, dtype=np.float32)
        draw_share = rng.random(clean.shape, dtype=np.float32) * np.float32(0.5)
        draw_invalid = rng.random(clean.shape, dtype=np.float32)
        edge = valid & ((high - low) > self.flying_jump_m) & (draw_straddle < straddle_p)
        to_background = high >= np.float32(1e5)
        own = clean
        other = np.where(own - low < high - own, high, low)
        w = draw_share
        a_own = (1 - w) / np.maximum(own, 1e-6) ** 2
        a_other = w / np.maximum(other, 1e-6) ** 2
        mixed = (a_own * own + a_other * other) / (a_own + a_other)
        mixes = edge & ~to_background
        noisy = np.where(mixes, mixed, noisy).astype(np.float32)
        keep = keep & ~(edge & (draw_invalid < self.flying_invalid_share))
        del rho  # the two returns share the pixel's reflectivity: rho cancels in the weights
        return noisy, keep

    def _multipath_bias(self, clean: Depth, valid: Mask, k: Intrinsics) -> Depth:
        """gain × concavity, clipped to [0, 11 mm], where the neighbourhood is one continuous
        surface (a span under 5 cm) away from the image border: light reaching a concave
        corner's pixel also by a second bounce off the facing surface travels farther, so the
        phase reads long."""
        if not valid.any():
            return np.zeros_like(clean)
        typical = float(np.median(clean[valid]))
        sigma_px = max(0.5, MULTIPATH_RADIUS_M * float(k.fx) / typical)
        size = 2 * int(np.ceil(3 * sigma_px)) + 1
        low, high = geometry.local_span(clean, valid, size)
        # The window must lie on one continuous, valid surface inside the image: a one-sided
        # window (a silhouette, the image border) would read a plane as curved.
        corner = valid & ((high - low) < MULTIPATH_SPAN_M)
        inside = np.zeros_like(corner)
        half = size // 2
        inside[half : clean.shape[0] - half, half : clean.shape[1] - half] = True
        corner &= inside
        bias = self.multipath_gain * geometry.concavity(clean, valid, sigma_px)
        return np.where(corner, np.clip(bias, 0.0, MULTIPATH_MAX_M), 0.0).astype(np.float32)


def correlated(white: Depth, sigma_px: float) -> Depth:
    """A unit-variance white field blurred by a Gaussian of `sigma_px` (output pixels) and scaled
    back to unit variance: neighbours at distance r correlate as exp(-r² / 4σ²). Below a tenth of a
    pixel the field is returned as it is."""
    if sigma_px < 0.1:
        return white
    size = 2 * math.ceil(4 * sigma_px) + 1
    kernel = cv2.getGaussianKernel(size, sigma_px, cv2.CV_64F)[:, 0]
    gain = float((kernel**2).sum())  # variance of one blurred axis; the 2-D blur's is gain²
    blurred = cv2.sepFilter2D(white, cv2.CV_32F, kernel, kernel, borderType=cv2.BORDER_REFLECT)
    return (blurred / np.float32(gain)).astype(np.float32)


def _see_through_glass(
    clean: Depth, valid: Mask, rho: npt.NDArray[np.float32], kind: npt.NDArray[np.uint8]
) -> tuple[Depth, Mask, npt.NDArray[np.float32]]:
    """Glass transmits the sensor's light: each glass pixel reads the nearest non-glass pixel's
    surface (and reflectivity) when that surface lies behind the glass, else nothing (a
    no-return background, or a nearer surface: the hand holding it)."""
    glass = valid & (kind == sensor.GLASS)
    if not glass.any():
        return clean, valid, rho
    nearest_depth, nearest_rho, nearest_valid = _nearest_outside(glass, clean, valid, rho)
    behind = nearest_valid & (nearest_depth > clean + GLASS_BEHIND_MIN_M)
    through = glass & behind
    clean = np.where(glass, np.where(through, nearest_depth, 0), clean).astype(np.float32)
    valid = (valid & ~glass) | through
    rho = np.where(through, nearest_rho, rho).astype(np.float32)
    return clean, valid, rho


def _nearest_outside(
    glass: Mask, clean: Depth, valid: Mask, rho: npt.NDArray[np.float32]
) -> tuple[Depth, npt.NDArray[np.float32], Mask]:
    """For every pixel, the depth, reflectivity and validity of the nearest non-glass pixel."""
    # The zero pixels of the input are the ones whose labels we get: make them the non-glass ones.
    source = np.where(glass, 255, 0).astype(np.uint8)
    if not (source == 0).any():
        zeros = np.zeros(clean.shape, np.float32)
        return zeros, zeros, np.zeros(clean.shape, bool)
    _, labels = cv2.distanceTransformWithLabels(source, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    rows, cols = np.nonzero(source == 0)
    # Labels number the zero pixels in row-major scan order, starting at 1.
    index = labels - 1
    return clean[rows, cols][index], rho[rows, cols][index], valid[rows, cols][index]


def _jitter(
    rng: np.random.Generator,
    sigma_px: float,
    clean: Depth,
    valid: Mask,
    rho: npt.NDArray[np.float32],
    kind: npt.NDArray[np.uint8],
) -> tuple[Depth, Mask, npt.NDArray[np.float32], npt.NDArray[np.uint8]]:
    """Every pixel samples the scene (nearest neighbour: no invented depths) at its position plus
    N(0, sigma_px²) in u and v."""
    h, w = clean.shape
    du = rng.standard_normal((h, w), dtype=np.float32) * np.float32(sigma_px)
    dv = rng.standard_normal((h, w), dtype=np.float32) * np.float32(sigma_px)
    cols = np.clip(np.rint(np.arange(w, dtype=np.float32)[None, :] + du), 0, w - 1).astype(np.intp)
    rows = np.clip(np.rint(np.arange(h, dtype=np.float32)[:, None] + dv), 0, h - 1).astype(np.intp)
    return clean[rows, cols], valid[rows, cols], rho[rows, cols], kind[rows, cols]


def _mirror_dropouts(
    rng: np.random.Generator, cos: Depth, kind: npt.NDArray[np.uint8], cone_deg: float
) -> Mask:
    """Metal pixels near the mirror direction (the emitter sits beside the lens, so: the normal
    towards the camera) saturate and read invalid, with probability exp(-ln2 (θ/θ_c)²): 1 at
    the mirror direction, ½ at the cone's edge θ_c."""
    draw = rng.random(cos.shape, dtype=np.float32)
    if cone_deg <= 0:
        return np.zeros(cos.shape, bool)
    theta = np.degrees(np.arccos(np.clip(cos, 0.0, 1.0)))
    p = np.exp(-math.log(2.0) * (theta / cone_deg) ** 2)
    return (kind == sensor.METAL) & (draw < p)
