"""A Kinect-Azure-like depth-noise model over float32 depth maps (metres, 0 = invalid).

The model, in order: invalid input (0, NaN, Inf, negative) stays invalid; pixels whose 3×3
neighbourhood spans more than `edge_hole_jump_m` become holes (flying pixels at depth edges; an
invalid neighbour counts as a jump, so silhouettes against the background lose their rim);
Gaussian noise with σ(d) = sigma_base_m + sigma_per_m·max(0, d - 0.5); readings outside
[min_range_m, max_range_m] are invalid; each pixel drops out with probability `dropout`.

Randomness comes only from the generator passed in, and the draws do not depend on the image
content, so a seed fixes the result.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from vint_engines import contract
from vint_engines.protocol import BadInput

Depth = npt.NDArray[np.float32]

# Stand-in depth for invalid pixels in the edge test: far enough to count as a jump from anything.
_FAR = np.float32(1e6)
_KERNEL = np.ones((3, 3), np.uint8)


@dataclass(frozen=True)
class NoiseModel:
    """Fields, bounds and defaults: `NoiseModel` in the stage contract; `parse({})` gives the
    defaults."""

    sigma_base_m: float
    sigma_per_m: float
    min_range_m: float
    max_range_m: float
    edge_hole_jump_m: float
    dropout: float

    @staticmethod
    def parse(obj: Any, where: str = "params.noise") -> NoiseModel:
        model = NoiseModel(**contract.validated_part("NoiseModel", obj, where))
        if model.min_range_m >= model.max_range_m:
            raise BadInput(
                f"{where}: min_range_m {model.min_range_m} must be below max_range_m {model.max_range_m}"
            )
        return model

    def apply(self, depth: Depth, rng: np.random.Generator) -> Depth:
        """A noisy copy of `depth` (H×W float32 metres); 0 marks invalid pixels."""
        if depth.ndim != 2 or depth.size == 0:
            raise BadInput(f"depth map must be a non-empty H×W array, got shape {depth.shape}")
        depth = depth.astype(np.float32, copy=False)
        # Fixed draw order and sizes: the random streams do not depend on the content.
        gaussian = rng.standard_normal(depth.shape, dtype=np.float32)
        dropped = rng.random(depth.shape, dtype=np.float32) < self.dropout

        valid = np.isfinite(depth) & (depth > 0)
        clean = np.where(valid, depth, np.float32(0))
        valid &= ~self._edge_holes(clean, valid)
        sigma = self.sigma_base_m + self.sigma_per_m * np.maximum(clean - np.float32(0.5), 0)
        noisy = clean + sigma.astype(np.float32) * gaussian
        valid &= (noisy >= self.min_range_m) & (noisy <= self.max_range_m) & ~dropped
        return np.where(valid, noisy, np.float32(0)).astype(np.float32)

    def _edge_holes(self, clean: Depth, valid: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
        far_invalid = np.where(valid, clean, _FAR)
        # Outside the image border the morphology ignores pixels, so the border is not an edge.
        span = cv2.dilate(far_invalid, _KERNEL) - cv2.erode(far_invalid, _KERNEL)
        return span > self.edge_hole_jump_m
