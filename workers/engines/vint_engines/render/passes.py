"""Render passes from Cycles into numpy: depth and object index from a scene's compositor, and the
RGB image.

The compositor writes each pass as a 32-bit float EXR into a scratch directory, one file prefix
per scene; we load them through `bpy.data.images`, copy the pixels out, then remove the images and
files so nothing piles up over thousands of views. (A Viewer node produces no image in background
mode.) The RGB PNG is read back too: Blender stamps render times into its PNGs, and outputs must be
byte-identical for a seed, so the engine re-encodes the pixels itself.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import bpy
import cv2
import numpy as np
import numpy.typing as npt

SOCKETS = {"depth": "Depth", "index": "Object Index"}

# Blender marks background depth with 1e10; anything this far is "nothing hit".
BACKGROUND_DEPTH = 1e9


def add_pass_outputs(scene: bpy.types.Scene, scratch: Path, prefix: str, passes: Sequence[str]) -> None:
    """Enable `passes` (keys of SOCKETS) and wire Render Layers → File Output (EXR, full float)
    into `scratch`, files named `<prefix><pass>.exr`."""
    layer = scene.view_layers[0]
    layer.use_pass_z = "depth" in passes
    layer.use_pass_object_index = "index" in passes
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
        output.file_output_items.new("FLOAT", item)
        tree.links.new(render_layers.outputs[SOCKETS[item]], output.inputs[item])


def read_depth(scratch: Path, prefix: str) -> npt.NDArray[np.float32]:
    """Metres along the optical axis, 0 where nothing is hit (rows top to bottom)."""
    depth = _read_exr(scratch / f"{prefix}depth.exr")
    return np.where(depth < BACKGROUND_DEPTH, depth, 0.0).astype(np.float32)


def read_index(scratch: Path, prefix: str) -> npt.NDArray[np.int32]:
    """Object pass index per pixel, 0 for background (rows top to bottom)."""
    return np.rint(_read_exr(scratch / f"{prefix}index.exr")).astype(np.int32)


def read_rgb(path: Path) -> npt.NDArray[np.uint8]:
    """H×W×3 sRGB in OpenCV's BGR order; the file is deleted."""
    rgb = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if rgb is None:
        raise RuntimeError(f"Blender wrote no readable image at {path}")
    path.unlink()
    return rgb


def _read_exr(path: Path) -> npt.NDArray[np.float32]:
    image = bpy.data.images.load(str(path), check_existing=False)
    try:
        width, height = image.size
        pixels = np.empty(width * height * image.channels, np.float32)
        image.pixels.foreach_get(pixels)
    finally:
        bpy.data.images.remove(image)
        path.unlink()
    # Blender stores rows bottom to top; the first channel carries the pass.
    return pixels.reshape(height, width, -1)[::-1, :, 0].copy()
