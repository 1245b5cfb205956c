"""Blender materials: Principled BSDF set-ups per object material tag, and the hand's.

An object's look follows its catalog `material` tag; within a tag, the colour is picked from a
small palette by a hash of the object's name (deterministic, and different objects of one tag do
not all look alike). Paper and cardboard get a procedural label: a printed band with lines of
"text" across the middle of the object's height (generated texture coordinates).
"""

from __future__ import annotations

import zlib
from collections.abc import Mapping, Sequence
from typing import Any

import bpy

RGBA = tuple[float, float, float, float]

HAND = {"Base Color": (0.08, 0.08, 0.09, 1.0), "Metallic": 0.0, "Roughness": 0.55}

# Principled inputs per tag; "Base Color" comes from the tag's palette.
TAGS: dict[str, dict[str, Any]] = {
    "plastic": {"Metallic": 0.0, "Roughness": 0.35, "Specular IOR Level": 0.5},
    "metal": {"Metallic": 1.0, "Roughness": 0.3},
    "glass": {"Metallic": 0.0, "Roughness": 0.02, "Transmission Weight": 1.0, "IOR": 1.45},
    "paper": {"Metallic": 0.0, "Roughness": 0.9, "Specular IOR Level": 0.3},
    "cardboard": {"Metallic": 0.0, "Roughness": 0.85, "Specular IOR Level": 0.3},
    "wood": {"Metallic": 0.0, "Roughness": 0.65, "Specular IOR Level": 0.4},
    "ceramic": {"Metallic": 0.0, "Roughness": 0.12, "Coat Weight": 0.6, "Coat Roughness": 0.05},
    "rubber": {"Metallic": 0.0, "Roughness": 0.9, "Specular IOR Level": 0.2},
}
PALETTES: dict[str, Sequence[RGBA]] = {
    "plastic": ((0.75, 0.55, 0.05, 1), (0.08, 0.2, 0.6, 1), (0.7, 0.1, 0.08, 1), (0.85, 0.85, 0.82, 1)),
    "metal": ((0.85, 0.85, 0.87, 1), (0.8, 0.75, 0.65, 1), (0.7, 0.72, 0.75, 1)),
    "glass": ((1.0, 1.0, 1.0, 1),),
    "paper": ((0.9, 0.88, 0.82, 1), (0.85, 0.2, 0.15, 1), (0.2, 0.45, 0.8, 1)),
    "cardboard": ((0.78, 0.62, 0.4, 1), (0.85, 0.25, 0.1, 1), (0.2, 0.35, 0.7, 1), (0.9, 0.85, 0.2, 1)),
    "wood": ((0.55, 0.37, 0.2, 1), (0.7, 0.52, 0.32, 1)),
    "ceramic": ((0.92, 0.91, 0.88, 1), (0.6, 0.08, 0.08, 1), (0.15, 0.25, 0.45, 1)),
    "rubber": ((0.75, 0.2, 0.12, 1), (0.12, 0.12, 0.12, 1), (0.2, 0.5, 0.25, 1)),
}
LABELLED = ("paper", "cardboard")
INK: RGBA = (0.05, 0.05, 0.06, 1.0)


def lobes(inputs: Mapping[str, Any]) -> frozenset[str]:
    """The kinds of scattering a Principled BSDF with `inputs` has, as Cycles counts bounces:
    diffuse unless fully metallic or transmissive, glossy always (specular, metal and coat layers),
    transmission when it transmits, transparent when its alpha is below 1."""
    metallic = float(inputs.get("Metallic", 0.0))
    transmission = float(inputs.get("Transmission Weight", 0.0))
    kinds = {"glossy"}
    if metallic < 1.0 and transmission < 1.0:
        kinds.add("diffuse")
    if transmission > 0.0:
        kinds.add("transmission")
    if float(inputs.get("Alpha", 1.0)) < 1.0:
        kinds.add("transparent")
    return frozenset(kinds)


def object_lobes(tag: str) -> frozenset[str]:
    """The lobes of an object with catalog material `tag` (unknown tags look like plastic)."""
    return lobes(TAGS[tag if tag in TAGS else "plastic"])


HAND_LOBES = lobes(HAND)


def principled(name: str, inputs: Mapping[str, Any]) -> bpy.types.Material:
    """A node material whose Principled BSDF takes `inputs`."""
    material = bpy.data.materials.new(name)
    material.use_nodes = True
    bsdf = material.node_tree.nodes["Principled BSDF"]
    for key, value in inputs.items():
        bsdf.inputs[key].default_value = value
    return material


def object_material(object_name: str, tag: str) -> bpy.types.Material:
    """The material of object `object_name` with catalog material `tag` (unknown tags: plastic)."""
    tag = tag if tag in TAGS else "plastic"
    colour = pick(PALETTES[tag], object_name)
    material = principled(f"vint_{tag}_{object_name}", {**TAGS[tag], "Base Color": colour})
    if tag in LABELLED:
        add_label(material, colour, pick(PALETTES[tag], object_name + "/label"))
    return material


def pick(palette: Sequence[RGBA], key: str) -> RGBA:
    return palette[zlib.crc32(key.encode()) % len(palette)]


def add_label(material: bpy.types.Material, base: RGBA, label: RGBA) -> None:
    """Base colour = `base`, with a band of `label` colour over the middle 60 % of the object's
    height carrying dark horizontal lines."""
    tree = material.node_tree
    nodes, links = tree.nodes, tree.links
    coords = nodes.new("ShaderNodeTexCoord")
    split = nodes.new("ShaderNodeSeparateXYZ")
    links.new(coords.outputs["Generated"], split.inputs["Vector"])
    above = _math(tree, "GREATER_THAN", split.outputs["Z"], 0.2)
    below = _math(tree, "LESS_THAN", split.outputs["Z"], 0.8)
    band = _math(tree, "MULTIPLY", above.outputs[0], below.outputs[0])
    waves = nodes.new("ShaderNodeTexWave")
    waves.wave_type = "BANDS"
    waves.bands_direction = "Z"
    waves.inputs["Scale"].default_value = 9.0
    links.new(coords.outputs["Generated"], waves.inputs["Vector"])
    lines = _math(tree, "GREATER_THAN", waves.outputs["Fac"], 0.75)
    ink = _math(tree, "MULTIPLY", band.outputs[0], lines.outputs[0])
    labelled = _mix(tree, band.outputs[0], base, label)
    printed = _mix(tree, ink.outputs[0], labelled, INK)
    links.new(_colour_out(printed), nodes["Principled BSDF"].inputs["Base Color"])


def _math(tree: bpy.types.NodeTree, operation: str, value: Any, operand: Any) -> bpy.types.Node:
    node = tree.nodes.new("ShaderNodeMath")
    node.operation = operation
    tree.links.new(value, node.inputs[0])
    if isinstance(operand, float):
        node.inputs[1].default_value = operand
    else:
        tree.links.new(operand, node.inputs[1])
    return node


def _colour_out(mix: bpy.types.Node) -> Any:
    return next(socket for socket in mix.outputs if socket.identifier == "Result_Color")


def _mix(tree: bpy.types.NodeTree, factor: Any, a: RGBA | bpy.types.Node, b: RGBA) -> bpy.types.Node:
    """A colour mix node: `a` (a colour, or another mix node's result) where factor is 0, `b` where
    it is 1."""
    node = tree.nodes.new("ShaderNodeMix")
    node.data_type = "RGBA"
    sockets = {socket.identifier: socket for socket in node.inputs}
    tree.links.new(factor, sockets["Factor_Float"])
    if isinstance(a, tuple):
        sockets["A_Color"].default_value = a
    else:
        tree.links.new(_colour_out(a), sockets["A_Color"])
    sockets["B_Color"].default_value = b
    return node
