"""Render passes from Cycles into numpy: depth and object index of the geometry scenes, and the
path-traced image (scene-linear light) with, for the denoiser, its albedo and normal guides.

The compositor writes each pass as a 32-bit float EXR into a scratch directory, one file prefix
per scene; we load them through `bpy.data.images`, copy the pixels out, then remove the images and
files so nothing piles up over thousands of views. (A Viewer node produces no image in background
mode.) The image leaves Blender as linear float, not as a PNG: the denoiser, the colour sensor and
the 8-bit sRGB encoding are the engine's own (`denoise.py`, `sensor.py`), so nothing in between
rounds it, and no render time is stamped into an output.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import bpy
import numpy as np
import numpy.typing as npt

# pass → (Render Layers socket, File Output item type)
SOCKETS = {
    "depth": ("Depth", "FLOAT"),
    "index": ("Object Index", "FLOAT"),
    "image": ("Image", "RGBA"),
    "albedo": ("Denoising Albedo", "RGBA"),
    "normal": ("Denoising Normal", "VECTOR"),
}
GUIDES = ("albedo", "normal")  # Cycles stores them with `denoising_store_passes`

# Blender marks background depth with 1e10; anything this far is "nothing hit".
BACKGROUND_DEPTH = 1e9


def add_pass_outputs(
    scene: bpy.types.Scene, scratch: Path, prefix: str, passes: Sequence[str]
) -> bpy.types.NodeTree:
    """Enable `passes` (keys of SOCKETS) and wire Render Layers → File Output (EXR, full float)
    into `scratch`, files named `<prefix><pass>.exr`; the tree becomes the scene's compositor
    and is returned (a scene may switch between several: `use_pass_tree`)."""
    enable_passes(scene, passes)
    tree = bpy.data.node_groups.new(f"{prefix}passes", "CompositorNodeTree")
    scene.compositing_node_group = tree
    render_layers = tree.nodes.new("CompositorNodeRLayers")
    render_layers.scene = scene
    output = tree.nodes.new("CompositorNodeOutputFile")
    output.format.media_type = "IMAGE"  # must precede file_format
    output.format.file_format = "OPEN_EXR"
    output.format.color_depth = "32"
    output.format.color_mode = "RGB"
    output.directory = str(scratch)
    output.file_name = prefix
    for item in passes:
        socket, kind = SOCKETS[item]
        output.file_output_items.new(kind, item)
        tree.links.new(render_layers.outputs[socket], output.inputs[item])
    return tree


def enable_passes(scene: bpy.types.Scene, passes: Sequence[str]) -> None:
    """Make the scene's render layer produce `passes` and nothing more."""
    layer = scene.view_layers[0]
    layer.use_pass_z = "depth" in passes
    layer.use_pass_object_index = "index" in passes
    layer.cycles.denoising_store_passes = any(item in GUIDES for item in passes)


def use_pass_tree(scene: bpy.types.Scene, tree: bpy.types.NodeTree, passes: Sequence[str]) -> None:
    """Switch the scene to a tree made by `add_pass_outputs` for `passes`."""
    enable_passes(scene, passes)
    scene.compositing_node_group = tree


def read_depth(scratch: Path, prefix: str) -> npt.NDArray[np.float32]:
    """Metres along the optical axis, 0 where nothing is hit (rows top to bottom)."""
    depth = _read_exr(scratch / f"{prefix}depth.exr")
    return np.where(depth < BACKGROUND_DEPTH, depth, 0.0).astype(np.float32)


def read_index(scratch: Path, prefix: str) -> npt.NDArray[np.int32]:
    """Object pass index per pixel, 0 for background (rows top to bottom)."""
    return np.rint(_read_exr(scratch / f"{prefix}index.exr")).astype(np.int32)


def read_colour(scratch: Path, prefix: str, item: str) -> npt.NDArray[np.float32]:
    """A colour or vector pass as H×W×3 float (R, G, B or x, y, z; rows top to bottom)."""
    return _read_exr(scratch / f"{prefix}{item}.exr", channels=3)


def _read_exr(path: Path, channels: int = 1) -> npt.NDArray[np.float32]:
    image = bpy.data.images.load(str(path), check_existing=False)
    try:
        width, height = image.size
        pixels = np.empty(width * height * image.channels, np.float32)
        image.pixels.foreach_get(pixels)
    finally:
        bpy.data.images.remove(image)
        path.unlink()
    # Blender stores rows bottom to top; a scalar pass is in the first channel.
    rows = pixels.reshape(height, width, -1)[::-1]
    return (rows[:, :, 0] if channels == 1 else rows[:, :, :channels]).copy()
