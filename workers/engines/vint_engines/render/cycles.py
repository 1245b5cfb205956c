"""Cycles configuration: the compute device, the path-tracing settings of the RGB render, the
settings of the geometry passes (no path tracing), and the bounce caps pruned to what the scene's
materials can use.

Pruning is exact: a bounce cap only limits paths that scatter off a lobe of that kind, so a cap for
a lobe no material in the scene has (transmission without glass, transparency without alpha) never
binds and is set to 0; the total cap can never bind above the sum of the per-kind caps
(transparent bounces are counted apart in Cycles, volume bounces are 0: there are no volumes).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import bpy

from vint_engines import contract

DEVICE_ENV = "VINT_RENDER_DEVICE"  # "cpu" forces the CPU even when a GPU is present
THREADS_ENV = "VINT_RENDER_THREADS"  # CPU threads per render (`render_threads`)
GPU_BACKENDS = ("OPTIX", "CUDA")  # in order of preference
# Geometry passes sample each pixel once at its centre: a box filter this narrow (Cycles' minimum)
# puts the one camera ray within 0.005 px of the centre, where K says the pixel is.
CENTRE_FILTER_WIDTH = 0.01
LOBES = ("diffuse", "glossy", "transmission", "transparent")


@dataclass(frozen=True)
class Bounces:
    """Cycles' light-path caps (volume bounces are always 0: vint scenes have no volumes).
    Bounds and defaults (Cycles' own) are `Bounces` in the stage contract."""

    total: int
    diffuse: int
    glossy: int
    transmission: int
    transparent: int

    @staticmethod
    def parse(obj: Mapping[str, Any], where: str) -> Bounces:
        return Bounces(**contract.validated_part("Bounces", obj, where))

    def pruned(self, lobes: Iterable[str]) -> Bounces:
        """The caps the scene's material lobes can use (see the module comment)."""
        present = set(lobes)
        diffuse, glossy, transmission, transparent = (
            getattr(self, lobe) if lobe in present else 0 for lobe in LOBES
        )
        return Bounces(
            total=min(self.total, diffuse + glossy + transmission),
            diffuse=diffuse,
            glossy=glossy,
            transmission=transmission,
            transparent=transparent,
        )

    def apply(self, scene: bpy.types.Scene) -> None:
        c = scene.cycles
        c.max_bounces = self.total
        c.diffuse_bounces = self.diffuse
        c.glossy_bounces = self.glossy
        c.transmission_bounces = self.transmission
        c.transparent_max_bounces = self.transparent
        c.volume_bounces = 0


@dataclass(frozen=True)
class PathTracing:
    """How the RGB image is rendered: samples per pixel, whether it is denoised, the bounce caps
    and the clamp on indirect light (0 is off).

    Cycles never denoises: with `denoise`, the render stores the albedo and normal passes and the
    engine runs OpenImageDenoise on them itself (`denoise.py`), because Cycles' own OIDN call is
    not byte-reproducible between processes in this Blender build (docs/rendering.md)."""

    samples: int
    denoise: bool
    bounces: Bounces
    clamp_indirect: float = 10.0

    def apply(self, scene: bpy.types.Scene, seed: int) -> None:
        c = scene.cycles
        c.samples = self.samples
        c.use_denoising = False
        c.sample_clamp_indirect = self.clamp_indirect
        c.seed = seed % 2**31  # Cycles takes a 32-bit signed seed
        self.bounces.apply(scene)


def select_device() -> str:
    """Make Cycles render on the first GPU backend that sees a device (OptiX, then CUDA), unless
    `VINT_RENDER_DEVICE=cpu`; returns what `configure_device` should set ("CPU" or the backend)."""
    if os.environ.get(DEVICE_ENV, "").strip().lower() == "cpu":
        return "CPU"
    preferences = bpy.context.preferences.addons["cycles"].preferences
    for backend in GPU_BACKENDS:
        try:
            devices = preferences.get_devices_for_type(backend)
        except (TypeError, ValueError, RuntimeError):
            continue  # a backend this Blender build does not know
        if any(device.type == backend for device in devices):
            preferences.compute_device_type = backend
            for device in devices:
                device.use = device.type == backend
            return backend
    return "CPU"


def render_threads() -> int:
    """CPU threads per render: `VINT_RENDER_THREADS`, default 1; 0 lets Cycles use every core.

    Cycles on several CPU threads is not byte-deterministic: on the hardest tiny.toml view (the
    allegro in the mug under a turned HDRI) one pixel of the RGB image differed in 2 of 18 fresh
    processes on all cores and in 0 of 24 on one thread. A dataset must be the same bytes for the
    same spec, so an engine renders on one thread and a machine runs one worker per core instead
    (views are independent, so that is also how the work parallelises best). More threads trade
    the guarantee for per-view latency. Blender's own work around a render runs on as many
    threads (`cpus.py`)."""
    text = os.environ.get(THREADS_ENV, "1").strip()
    if not text.isdigit() or int(text) > 1024:
        raise ValueError(f"{THREADS_ENV}: expected 0 (all cores) to 1024 threads, got {text!r}")
    return int(text)


def configure_scene(scene: bpy.types.Scene, backend: str, threads: int) -> None:
    """Settings every vint scene shares: Cycles on the selected device and `threads` CPU threads
    (0: all), a fixed seed per render, no adaptive sampling (output depends on the sample count
    alone), persistent data (a re-render after moving objects is several times faster)."""
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU" if backend == "CPU" else "GPU"
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_animated_seed = False
    scene.cycles.use_denoising = False
    scene.render.use_persistent_data = True
    scene.render.resolution_percentage = 100
    if threads > 0:
        scene.render.threads_mode = "FIXED"
        scene.render.threads = threads
    else:
        scene.render.threads_mode = "AUTO"


def configure_geometry_pass(scene: bpy.types.Scene) -> None:
    """No path tracing: one camera ray per pixel centre, no bounces, no light."""
    scene.cycles.samples = 1
    scene.cycles.seed = 0
    scene.cycles.pixel_filter_type = "BOX"
    scene.cycles.filter_width = CENTRE_FILTER_WIDTH
    Bounces(0, 0, 0, 0, 0).apply(scene)
