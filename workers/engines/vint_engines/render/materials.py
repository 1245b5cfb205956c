"""Blender materials: Principled BSDF set-ups per object material tag, and the hand's.

An object's look follows its catalog `material` tag (which sets the scattering: metal stays
specular, glass transmissive), its `texture` (the pattern, `textures.py`) and the entry's
`colours` (the real product's, carried on the texture). An entry without colours (a spec's own
object) takes its tag's palette colour picked by a CRC of the object's name (deterministic, and
different objects of one tag do not all look alike). Textures change colours and roughness only,
never a lobe, so `lobes` depends on the tag alone.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import bpy

from vint_engines.objects.spec import Texture
from vint_engines.render import textures
from vint_engines.render.textures import RGBA, pick, rgba

PLAIN = Texture()

HAND = {"Base Color": (0.08, 0.08, 0.09, 1.0), "Metallic": 0.0, "Roughness": 0.55}

# Principled inputs per tag; "Base Color" is the entry's base colour, or comes from the tag's palette.
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


def object_material(object_name: str, tag: str, texture: Texture = PLAIN) -> bpy.types.Material:
    """The material of object `object_name` with catalog material `tag` (unknown tags: plastic),
    patterned by `texture` in its colours."""
    tag = tag if tag in TAGS else "plastic"
    colours = texture.colours
    colour = pick(PALETTES[tag], object_name) if colours is None else rgba(colours.base)
    material = principled(f"vint_{tag}_{object_name}", {**TAGS[tag], "Base Color": colour})
    textures.apply(material, object_name, texture, colour)
    return material


def surface_material(
    object_name: str, tag: str, image: bpy.types.Image | None, colour_attribute: str | None
) -> bpy.types.Material:
    """The material of a user's object whose file carries its colour: the tag's Principled inputs
    (roughness, metal, glass) with the base colour read from `image` through the mesh's UV map, or
    from the mesh's colour attribute `colour_attribute`."""
    tag = tag if tag in TAGS else "plastic"
    material = principled(f"vint_{tag}_{object_name}_look", TAGS[tag])
    tree = material.node_tree
    bsdf = tree.nodes["Principled BSDF"]
    if image is not None:
        node = tree.nodes.new("ShaderNodeTexImage")
        node.image = image
        node.interpolation = "Linear"
        node.extension = "EXTEND"  # texels at a chart's border do not wrap to the atlas's far side
        tree.links.new(node.outputs["Color"], bsdf.inputs["Base Color"])
    elif colour_attribute is not None:
        node = tree.nodes.new("ShaderNodeVertexColor")
        node.layer_name = colour_attribute
        tree.links.new(node.outputs["Color"], bsdf.inputs["Base Color"])
    return material
