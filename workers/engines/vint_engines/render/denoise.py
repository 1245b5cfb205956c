"""OpenImageDenoise on the path-traced image, outside Blender, so that it is byte-reproducible.

The denoiser is Intel's OpenImageDenoise (OIDN 2.5, through the `pyoidn` binding from PyPI) with
its "RT" filter, fed the noisy linear image (HDR) and Cycles' denoising albedo and normal passes as
guides (prefiltered by OIDN itself: they are noisy too, at low sample counts): the guides keep
texture and edges sharp where the colour alone would blur them. It removes the Monte-Carlo noise
and the fireflies of a low sample count (the render study: 32 spp reach 35 dB on the object and
hand pixels, docs/rendering.md).

Why not Cycles' own OIDN: in bpy 5.2.3 on the CPU its output differs between fresh processes by
one 8-bit level at about one pixel per image, whatever its thread count, prefilter or quality, and
a dataset must be the same bytes for the same spec. The same OIDN called here on the same passes
gives the same bytes in every process (tests/test_denoise.py, and the worker-count check of the
tiny run); across CPUs it differs slightly (OIDN picks kernels per instruction set), which is
what `vintctl diff`'s tolerances are for.

What it is given is rounded first: the colour to 8 significant bits (a step of 0.4–0.8 % of the value,
far below the Monte-Carlo noise it removes), the guides to steps of 2^-10. Cycles' float image of
the same view is not always the same bits: between a warm engine and a fresh one, 1–3 pixels of a
view in about one view of twelve differed by ~1e-5 of their value on tiny.toml, and the denoiser
spreads such a difference over its neighbourhood, where it flips an 8-bit level now and then.
Rounded first, a difference that small survives only where it straddles a rounding step (a few
differing pixels in a thousand): the same odds the undenoised 8-bit image has always had.

One CPU device per process, made on first use with the engine's render thread count (`cycles.
render_threads`: one worker per core, so the denoiser must not take every core either) and no
thread pinning (several workers share a machine).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pyoidn

COLOUR_BITS = 8  # significant bits of the colour the denoiser is given
GUIDE_BITS = 10  # the guides are given in steps of 2^-GUIDE_BITS


class Denoiser:
    """A committed OIDN CPU device and RT filter, reused for every image of an engine."""

    def __init__(self, threads: int) -> None:
        self.threads = threads
        self._device: pyoidn.Device | None = None
        self._filter: pyoidn.Filter | None = None

    def __call__(
        self,
        colour: npt.NDArray[np.float32],
        albedo: npt.NDArray[np.float32],
        normal: npt.NDArray[np.float32],
    ) -> npt.NDArray[np.float32]:
        """The denoised image (H×W×3 linear float, the colour's channel order); the guides are
        Cycles' albedo in [0, 1] and its normals in [-1, 1], same shape."""
        if colour.shape != albedo.shape or colour.shape != normal.shape or colour.ndim != 3:
            raise ValueError(
                f"denoiser: colour {colour.shape}, albedo {albedo.shape} and normal {normal.shape} "
                "must all be H×W×3"
            )
        device, flt = self._open()
        images = {
            pyoidn.OIDN_IMAGE_COLOR: _contiguous(significant_bits(np.maximum(colour, 0.0), COLOUR_BITS)),
            pyoidn.OIDN_IMAGE_ALBEDO: _contiguous(_steps(np.clip(albedo, 0.0, 1.0))),
            pyoidn.OIDN_IMAGE_NORMAL: _contiguous(_steps(np.clip(normal, -1.0, 1.0))),
        }
        output = np.empty_like(images[pyoidn.OIDN_IMAGE_COLOR])
        for name, image in (*images.items(), (pyoidn.OIDN_IMAGE_OUTPUT, output)):
            flt.set_image(name, image, pyoidn.OIDN_FORMAT_FLOAT3)
        flt.set_bool("hdr", True)
        flt.set_bool("cleanAux", False)
        flt.set_quality(pyoidn.OIDN_QUALITY_HIGH)
        flt.commit()
        flt.execute()
        _check(device, "denoising")
        return output

    def close(self) -> None:
        if self._filter is not None:
            self._filter.release()
        if self._device is not None:
            self._device.release()
        self._filter = self._device = None

    def _open(self) -> tuple[pyoidn.Device, pyoidn.Filter]:
        if self._device is None or self._filter is None:
            device = pyoidn.Device(pyoidn.OIDN_DEVICE_TYPE_CPU)
            device.set_int("numThreads", self.threads)
            device.set_bool("setAffinity", False)
            device.commit()
            _check(device, "opening the CPU device")
            self._device, self._filter = device, pyoidn.Filter(device, pyoidn.OIDN_FILTER_TYPE_RT)
            _check(device, "making the RT filter")
        return self._device, self._filter


def significant_bits(image: npt.NDArray[np.floating], bits: int) -> npt.NDArray[np.float32]:
    """`image` with each value rounded to `bits` significant bits (0 stays 0)."""
    mantissa, exponent = np.frexp(image.astype(np.float32))
    return np.ldexp(np.round(mantissa * 2.0**bits) / 2.0**bits, exponent).astype(np.float32)


def _steps(image: npt.NDArray[np.floating]) -> npt.NDArray[np.float32]:
    return (np.round(image * 2.0**GUIDE_BITS) / 2.0**GUIDE_BITS).astype(np.float32)


def _contiguous(image: npt.NDArray[np.floating]) -> npt.NDArray[np.float32]:
    return np.ascontiguousarray(image, dtype=np.float32)


def _check(device: pyoidn.Device, doing: str) -> None:
    error = device.get_error()
    if error:
        raise RuntimeError(f"OpenImageDenoise failed {doing}: {error}")
