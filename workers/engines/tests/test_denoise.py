"""The denoiser outside Blender: it brings a noisy image of a known clean picture much closer to
that picture, removes an isolated firefly, keeps an edge the albedo guide marks, gives the same
bytes in fresh processes and whatever its thread count, and refuses guides of another shape.

The images are made here, not rendered: a clean picture (two flat albedo regions under smooth
shading, split by a sharp edge), plus Gaussian noise and one firefly, with the exact albedo and a
constant normal as guides."""

from __future__ import annotations

import hashlib
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vint_engines.render.denoise import COLOUR_BITS, Denoiser, significant_bits

H, W = 96, 128
EDGE = 64  # column of the albedo edge


def picture() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(clean linear image, albedo, normal), H×W×3 float32."""
    albedo = np.empty((H, W, 3), np.float32)
    albedo[:, :EDGE] = (0.7, 0.55, 0.1)  # a yellow label
    albedo[:, EDGE:] = (0.1, 0.1, 0.12)  # a black link
    shading = np.linspace(0.6, 1.0, W, dtype=np.float32)[None, :, None] * np.ones((H, 1, 1), np.float32)
    normal = np.zeros((H, W, 3), np.float32)
    normal[..., 2] = 1.0
    return albedo * shading, albedo, normal


def noisy(clean: np.ndarray, seed: int = 1) -> np.ndarray:
    image = clean + np.random.default_rng(seed).normal(0.0, 0.08, clean.shape).astype(np.float32)
    image = np.maximum(image, 0.0)
    image[30, 20] = 25.0  # one firefly on the label
    return image


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(10 * np.log10(1.0 / np.mean((np.clip(a, 0, 1) - np.clip(b, 0, 1)) ** 2)))


def test_brings_the_noisy_image_close_to_the_clean_one() -> None:
    clean, albedo, normal = picture()
    image = noisy(clean)
    out = Denoiser(1)(image, albedo, normal)
    assert out.shape == clean.shape and out.dtype == np.float32
    before, after = psnr(image, clean), psnr(out, clean)
    assert after > before + 10.0, (before, after)
    assert abs(float(out[30, 20, 0]) - float(clean[30, 20, 0])) < 0.1, "the firefly is gone"
    # The edge stays sharp: one column either side keeps its own side's level.
    left, right = out[10:-10, EDGE - 2].mean(axis=0), out[10:-10, EDGE + 1].mean(axis=0)
    assert np.allclose(left, clean[10:-10, EDGE - 2].mean(axis=0), atol=0.04)
    assert np.allclose(right, clean[10:-10, EDGE + 1].mean(axis=0), atol=0.04)


def test_same_bytes_whatever_the_thread_count() -> None:
    clean, albedo, normal = picture()
    image = noisy(clean)
    one = Denoiser(1)(image, albedo, normal)
    every = Denoiser(0)(image, albedo, normal)
    assert one.tobytes() == every.tobytes()


FRESH = """
import hashlib, sys
sys.path.insert(0, {tests!r})
from test_denoise import noisy, picture
from vint_engines.render.denoise import COLOUR_BITS, Denoiser, significant_bits
clean, albedo, normal = picture()
print(hashlib.sha256(Denoiser(1)(noisy(clean), albedo, normal).tobytes()).hexdigest())
"""


def test_same_bytes_in_fresh_processes() -> None:
    """What Cycles' own OIDN call did not give (docs/rendering.md): the same output every process."""
    clean, albedo, normal = picture()
    here = hashlib.sha256(Denoiser(1)(noisy(clean), albedo, normal).tobytes()).hexdigest()
    code = FRESH.format(tests=str(Path(__file__).parent))
    for _ in range(2):
        engines = Path(__file__).resolve().parents[1]  # where `vint_engines` is importable from
        run = subprocess.run(
            [sys.executable, "-c", code], cwd=engines, capture_output=True, text=True, check=False
        )
        assert run.returncode == 0, run.stderr[-3000:]
        assert run.stdout.strip() == here


def test_guides_of_another_shape_are_refused() -> None:
    clean, albedo, normal = picture()
    with pytest.raises(ValueError, match="must all be H×W×3"):
        Denoiser(1)(clean, albedo[:-1], normal)


def test_rounds_the_colour_to_significant_bits() -> None:
    values = np.random.default_rng(3).lognormal(-2.0, 2.0, 10_000).astype(np.float32)
    rounded = significant_bits(values, COLOUR_BITS)
    assert np.all(np.abs(rounded - values) <= values * 2.0**-COLOUR_BITS)  # half a step of 2^(e-8)
    assert significant_bits(np.zeros(3, np.float32), COLOUR_BITS).tolist() == [0.0, 0.0, 0.0]


def test_a_last_bits_difference_in_the_render_does_not_reach_the_output() -> None:
    """Cycles' image of one view can differ by ~1e-5 of a value at a few pixels between a warm and
    a fresh engine; the denoiser is given values rounded far coarser than that."""
    clean, albedo, normal = picture()
    image = noisy(clean)
    nudged = image.copy()
    rng = np.random.default_rng(9)
    ys, xs = rng.integers(0, H, 20), rng.integers(0, W, 20)
    nudged[ys, xs] *= np.float32(1.0 + 1e-6)
    assert not np.array_equal(image, nudged)
    denoiser = Denoiser(1)
    assert denoiser(image, albedo, normal).tobytes() == denoiser(nudged, albedo, normal).tobytes()
