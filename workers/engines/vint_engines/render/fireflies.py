"""Fireflies out of a raw path-traced image, deterministically: a pixel whose brightest channel
exceeds the brightest of its 8 neighbours by more than `threshold` (of full scale) is an isolated
bright sample — a firefly — and takes, per channel, the median of those neighbours. Plain numpy.

This is the default because OpenImageDenoise, which removes fireflies and noise alike, is not
byte-reproducible between processes in this Blender build (one 8-bit level at about one pixel
per image differs from run to run, whatever its thread count, prefilter or quality:
docs/rendering.md), and a dataset must be the same bytes for the same spec. A firefly by this
definition is the one the checks count (`tests/python/check_fireflies.py`, the render study); a
detail two or more pixels wide is never touched. The engine runs it last, on the colour sensor's
output, so the sensor's gains cannot lift a pixel back over the threshold.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

SHIFTS = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dy or dx]


def spike_mask(image: npt.NDArray[np.uint8], threshold: float) -> npt.NDArray[np.bool_]:
    """Where `image` (H×W×3, 8-bit) has a firefly: the brightest channel above the brightest of
    the 8 neighbours by more than `threshold` of full scale (edges repeat the border)."""
    h, w = image.shape[:2]
    padded = np.pad(image, ((1, 1), (1, 1), (0, 0)), mode="edge")
    brightest = padded.max(axis=2).astype(np.int16)
    neighbours = np.max([brightest[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w] for dy, dx in SHIFTS], axis=0)
    return brightest[1:-1, 1:-1] - neighbours > threshold * 255.0


def despeckle(image: npt.NDArray[np.uint8], threshold: float) -> tuple[npt.NDArray[np.uint8], int]:
    """`image` (H×W×3, 8-bit) with its isolated bright pixels replaced by their neighbours'
    median, and how many there were; `threshold` 0 leaves it as it is."""
    if threshold <= 0.0:
        return image, 0
    spikes = spike_mask(image, threshold)
    count = int(np.count_nonzero(spikes))
    if count == 0:
        return image, 0
    h, w = image.shape[:2]
    padded = np.pad(image, ((1, 1), (1, 1), (0, 0)), mode="edge")
    around = np.stack([padded[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w] for dy, dx in SHIFTS])
    out = image.copy()
    median = np.median(around[:, spikes, :], axis=0)  # 8 neighbours → one value per channel
    out[spikes] = np.rint(median).astype(np.uint8)
    return out, count
