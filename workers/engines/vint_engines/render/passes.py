"""Depth and object-index passes (and the RGB image) from Cycles into numpy.

The compositor writes both passes as 32-bit float EXRs into a scratch directory; we load them
through `bpy.data.images`, copy the pixels out, then remove the images and files so nothing piles
up over thousands of views. (A Viewer node produces no image in background mode.) The RGB PNG is
read back too: Blender stamps render times into its PNGs, and outputs must be byte-identical for a
seed, so the engine re-encodes the pixels itself.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import bpy
import cv2
import numpy as np
import numpy.typing as npt

PASSES = {"depth": "Depth", "index": "Object Index"}
FILE_PREFIX = "pass_"

# Blender marks background depth with 1e10; anything this far is "nothing hit".
BACKGROUND_DEPTH = 1e9


@dataclass(frozen=True)
class Passes:
    depth: npt.NDArray[np.float32]  # metres along the optical axis, 0 where nothing is hit
    index: npt.NDArray[np.int32]  # object pass index, 0 for background
    rgb: npt.NDArray[np.uint8] | None  # H×W×3 sRGB in OpenCV's BGR order, when rendered


def add_pass_outputs(scene: bpy.types.Scene, scratch: Path) -> None:
    """Enable the passes and wire Render Layers → File Output (EXR, full float) into `scratch`."""
    layer = scene.view_layers[0]
    layer.use_pass_z = True
    layer.use_pass_object_index = True
    tree = bpy.data.node_groups.new("vint_passes", "CompositorNodeTree")
    scene.compositing_node_group = tree
    render_layers = tree.nodes.new("CompositorNodeRLayers")
    output = tree.nodes.new("CompositorNodeOutputFile")
    output.format.media_type = "IMAGE"  # must precede file_format
    output.format.file_format = "OPEN_EXR"
    output.format.color_depth = "32"
    output.format.color_mode = "RGB"
    output.directory = str(scratch)
    output.file_name = FILE_PREFIX
    for item, socket in PASSES.items():
        output.file_output_items.new("FLOAT", item)
        tree.links.new(render_layers.outputs[socket], output.inputs[item])


def read_passes(scratch: Path, rgb_file: str | None) -> Passes:
    """Load what the last render wrote (rows top to bottom, as images are stored) and delete it."""
    depth = _read_exr(scratch / f"{FILE_PREFIX}depth.exr")
    index = _read_exr(scratch / f"{FILE_PREFIX}index.exr")
    depth = np.where(depth < BACKGROUND_DEPTH, depth, 0.0).astype(np.float32)
    rgb = None
    if rgb_file is not None:
        path = scratch / rgb_file
        rgb = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if rgb is None:
            raise RuntimeError(f"Blender wrote no readable image at {path}")
        path.unlink()
    return Passes(depth=depth, index=np.rint(index).astype(np.int32), rgb=rgb)


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
