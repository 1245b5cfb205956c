"""Procedural surface patterns: one shader node graph per catalog `texture` kind
(`vint_core::contract::object::Texture`), feeding a Principled BSDF's base colour (and, for metal and
glaze, its roughness).

Patterns are functions of the object's own coordinates — `Generated` (the model's bounding box
mapped to [0, 1]³, so 0.5 is the object frame's origin) and `Object` (metres) — because the
procedural meshes have no UVs. They are fixed by the object, never by time, worker or seed: the
colours are the entry's `colours` (the real product's, for the built-in objects; `Paint` says what
each paints), or for an entry without them (a spec's own objects) picks from small palettes by a
CRC of its name; noise offsets come from that CRC too. Each kind is built to keep exactly the
rotations `Texture::keeps_rotation` says it keeps, which is what lets the catalog declare the
textured object's symmetries (a two-tone band or a cap, `Colours::keeps_rotation`, depends on the
height alone and keeps only the rotations that keep +z):
- `label` (no print) reads only the height's distance from the band's middle: any turn about z,
  and the flips of z when the band is centred. Its print sits at azimuth 0, in the band's upper
  half: it keeps nothing.
- `panels` (no print) reads only |2·g - 1| per axis, symmetrically in the three axes: every
  rotation that maps the box onto itself. Its print (text lines, an off-centre logo) keeps nothing.
- `wood_grain` reads the distance from its axis and |position along it|; `brushed` only the
  height; `glaze` and `speckle` are 3-D noise and keep nothing.
Must not touch scenes, cameras or files: `scene.py` assigns the material.
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import bpy

from vint_engines.objects.spec import Rgb, Texture

RGBA = tuple[float, float, float, float]
Operand = Any  # a node socket or a number

INK: RGBA = (0.04, 0.04, 0.05, 1.0)
LABEL_COLOURS: Sequence[RGBA] = (
    (0.85, 0.1, 0.08, 1),
    (0.95, 0.93, 0.88, 1),
    (0.1, 0.25, 0.65, 1),
    (0.95, 0.75, 0.1, 1),
    (0.1, 0.45, 0.2, 1),
)
ACCENT_COLOURS: Sequence[RGBA] = (
    (0.9, 0.8, 0.2, 1),
    (0.95, 0.95, 0.95, 1),
    (0.6, 0.05, 0.1, 1),
    (0.05, 0.15, 0.4, 1),
)
WOOD_DARK: RGBA = (0.16, 0.08, 0.03, 1.0)
SPOT_DARKEN = 0.35  # speckle spots: the base colour times this
POOL_DARKEN = 0.55  # glaze pools
DULL_DARKEN = 0.5  # brushed metal's dull streaks


def pick(palette: Sequence[RGBA], key: str) -> RGBA:
    """A palette entry chosen by a CRC of `key` (deterministic across processes and machines)."""
    return palette[zlib.crc32(key.encode()) % len(palette)]


def rgba(colour: Rgb) -> RGBA:
    r, g, b = colour
    return (r, g, b, 1.0)


@dataclass(frozen=True)
class Paint:
    """The colours a pattern is drawn in. `base`: the body (outside a label's band, a box's face
    borders, earlywood, the metal, the glaze, the foam); `second`: the pattern's other colour (a
    label's band — its upper half when `lower` is given —, a box's panel, latewood, glaze pools,
    brushed metal's dull streaks, speckle's spots); `lower`: a two-tone band's lower half;
    `accent`: a label's edges, a box's inner panel; `logo`; `cap`: (above, colour), everything
    above that fraction of the height."""

    base: RGBA
    second: RGBA
    accent: RGBA
    logo: RGBA
    lower: RGBA | None = None
    cap: tuple[float, RGBA] | None = None


def paint(name: str, texture: Texture, base: RGBA) -> Paint:
    """The colours of object `name`'s `texture` over `base` (the material's base colour): the
    entry's own colours where it states them, else the palette picks by name."""
    shade = {
        "label": base,
        "panels": base,
        "wood_grain": WOOD_DARK,
        "glaze": shaded(base, POOL_DARKEN),
        "brushed": shaded(base, DULL_DARKEN),
        "speckle": shaded(base, SPOT_DARKEN),
    }.get(texture.kind, base)
    c = texture.colours
    if c is None:
        if texture.kind == "label":
            return Paint(
                base,
                pick(LABEL_COLOURS, name + "/label"),
                pick(ACCENT_COLOURS, name + "/accent"),
                pick(ACCENT_COLOURS, name + "/logo"),
            )
        if texture.kind == "panels":
            return Paint(
                base,
                pick(LABEL_COLOURS, name + "/panel"),
                pick(ACCENT_COLOURS, name + "/accent"),
                pick(LABEL_COLOURS, name + "/logo"),
            )
        return Paint(base, shade, base, base)
    printed = base if c.print is None else rgba(c.print)
    return Paint(
        base,
        shade if c.band is None else rgba(c.band),
        printed,
        printed,
        lower=None if c.lower is None else rgba(c.lower),
        cap=None if c.cap is None else (c.cap[0], rgba(c.cap[1])),
    )


def shaded(colour: RGBA, factor: float) -> RGBA:
    r, g, b, a = colour
    return (factor * r, factor * g, factor * b, a)


def noise_offset(name: str) -> tuple[float, float, float]:
    """Where in noise space the object's pattern starts: its own, fixed by its name."""
    h = zlib.crc32(name.encode())
    return (h % 997 / 10.0, h // 997 % 991 / 10.0, h // 988027 % 983 / 10.0)


class Graph:
    """Small helpers over a material's node tree, so a pattern reads like its formula."""

    def __init__(self, material: bpy.types.Material, name: str) -> None:
        self.tree = material.node_tree
        self.bsdf = self.tree.nodes["Principled BSDF"]
        self.offset = noise_offset(name)
        coords = self.tree.nodes.new("ShaderNodeTexCoord")
        self.g = self._split(coords.outputs["Generated"])
        self.o = self._split(coords.outputs["Object"])

    def _split(self, vector: Any) -> tuple[Any, Any, Any]:
        node = self.tree.nodes.new("ShaderNodeSeparateXYZ")
        self.tree.links.new(vector, node.inputs["Vector"])
        return node.outputs["X"], node.outputs["Y"], node.outputs["Z"]

    def math(self, operation: str, a: Operand, b: Operand = 0.0) -> Any:
        node = self.tree.nodes.new("ShaderNodeMath")
        node.operation = operation
        for socket, value in zip(node.inputs, (a, b), strict=False):
            if isinstance(value, int | float):
                socket.default_value = float(value)
            else:
                self.tree.links.new(value, socket)
        return node.outputs[0]

    def add(self, a: Operand, b: Operand) -> Any:
        return self.math("ADD", a, b)

    def mul(self, a: Operand, b: Operand) -> Any:
        return self.math("MULTIPLY", a, b)

    def lt(self, a: Operand, b: Operand) -> Any:
        return self.math("LESS_THAN", a, b)

    def gt(self, a: Operand, b: Operand) -> Any:
        return self.math("GREATER_THAN", a, b)

    def abs_centred(self, a: Operand, centre: float) -> Any:
        """|a - centre|."""
        return self.math("ABSOLUTE", self.math("SUBTRACT", a, centre))

    def noise(self, x: Operand, y: Operand, z: Operand, scale: float, detail: float = 2.0) -> Any:
        """Perlin noise (about 0.2–0.8) at (x, y, z)·scale, shifted by the object's offset."""
        combine = self.tree.nodes.new("ShaderNodeCombineXYZ")
        for socket, value, shift in zip(combine.inputs, (x, y, z), self.offset, strict=True):
            self.tree.links.new(self.add(self.mul(value, scale), shift), socket)
        node = self.tree.nodes.new("ShaderNodeTexNoise")
        node.inputs["Scale"].default_value = 1.0
        node.inputs["Detail"].default_value = detail
        self.tree.links.new(combine.outputs["Vector"], node.inputs["Vector"])
        return node.outputs["Fac"]

    def mix(self, factor: Operand, a: RGBA | Any, b: RGBA | Any) -> Any:
        """Colour `a` where factor is 0, `b` where it is 1."""
        node = self.tree.nodes.new("ShaderNodeMix")
        node.data_type = "RGBA"
        sockets = {socket.identifier: socket for socket in node.inputs}
        for key, value in (("Factor_Float", factor), ("A_Color", a), ("B_Color", b)):
            if isinstance(value, tuple | float | int):
                sockets[key].default_value = value
            else:
                self.tree.links.new(value, sockets[key])
        return next(socket for socket in node.outputs if socket.identifier == "Result_Color")

    def base_colour(self, colour: Any) -> None:
        self.tree.links.new(colour, self.bsdf.inputs["Base Color"])

    def roughness(self, value: Any) -> None:
        self.tree.links.new(value, self.bsdf.inputs["Roughness"])


def apply(material: bpy.types.Material, name: str, texture: Texture, base: RGBA) -> None:
    """Build `texture`'s pattern over `base` (the material's base colour) into `material`."""
    colours = paint(name, texture, base)
    if texture.kind == "plain" and colours.cap is None:
        return
    graph = Graph(material, name)
    builders = {
        "plain": _plain,
        "label": _label,
        "panels": _panels,
        "wood_grain": _wood_grain,
        "glaze": _glaze,
        "brushed": _brushed,
        "speckle": _speckle,
    }
    colour = builders[texture.kind](graph, texture, colours)
    if colours.cap is not None:
        above, cap = colours.cap
        colour = graph.mix(graph.gt(graph.g[2], above), colour, cap)
    graph.base_colour(colour)


def _plain(graph: Graph, texture: Texture, paint: Paint) -> Operand:
    return paint.base


def _label(graph: Graph, texture: Texture, paint: Paint) -> Operand:
    bottom, top = texture.band
    centre, half = (bottom + top) / 2.0, (top - bottom) / 2.0
    d = graph.abs_centred(graph.g[2], centre)  # mirrored about the band's middle
    in_band = graph.lt(d, half)
    edge = graph.mul(in_band, graph.gt(d, 0.78 * half))
    rule = graph.mul(in_band, graph.lt(graph.math("FRACT", graph.mul(d, 5.0 / half)), 0.1))
    band = paint.second
    if paint.lower is not None:  # two-toned: no longer mirrored, so it keeps no flip of z
        band = graph.mix(graph.lt(graph.g[2], centre), paint.second, paint.lower)
    colour = graph.mix(in_band, paint.base, band)
    colour = graph.mix(edge, colour, paint.accent)
    colour = graph.mix(rule, colour, INK)
    if texture.print:
        h = graph.g[2]
        azimuth = graph.math("ABSOLUTE", graph.math("ARCTAN2", graph.o[1], graph.o[0]))
        upper = graph.mul(graph.gt(h, centre + 0.5 * half), graph.lt(h, centre + 0.85 * half))
        logo = graph.mul(upper, graph.lt(azimuth, 0.45))
        text_rows = graph.mul(graph.gt(h, centre + 0.05 * half), graph.lt(h, centre + 0.42 * half))
        lines = graph.lt(graph.math("FRACT", graph.mul(h, 14.0 / half)), 0.5)
        words = graph.gt(graph.noise(azimuth, h, 0.0, 12.0), 0.47)
        text = graph.mul(graph.mul(text_rows, graph.lt(azimuth, 0.7)), graph.mul(lines, words))
        colour = graph.mix(logo, colour, paint.logo)
        colour = graph.mix(text, colour, INK)
    return colour


def _panels(graph: Graph, texture: Texture, paint: Paint) -> Operand:
    folded = [graph.math("ABSOLUTE", graph.math("SUBTRACT", graph.mul(g, 2.0), 1.0)) for g in graph.g]

    def inside(limit: float) -> Any:  # on a face, both in-face coordinates within `limit`
        count = graph.add(
            graph.add(graph.lt(folded[0], limit), graph.lt(folded[1], limit)), graph.lt(folded[2], limit)
        )
        return graph.gt(count, 1.5)

    colour = graph.mix(inside(0.82), paint.base, paint.second)
    colour = graph.mix(inside(0.45), colour, paint.accent)
    if texture.print:
        gy, gz = graph.g[1], graph.g[2]
        logo_r2 = graph.add(
            graph.math("POWER", graph.math("SUBTRACT", gy, 0.32), 2.0),
            graph.math("POWER", graph.math("SUBTRACT", gz, 0.8), 2.0),
        )
        logo = graph.lt(logo_r2, 0.012)
        rows = graph.mul(graph.gt(gz, 0.55), graph.lt(gz, 0.7))
        lines = graph.lt(graph.math("FRACT", graph.mul(gz, 40.0)), 0.5)
        words = graph.gt(graph.noise(graph.g[0], gy, gz, 14.0), 0.5)
        colour = graph.mix(logo, colour, paint.logo)
        colour = graph.mix(graph.mul(rows, graph.mul(lines, words)), colour, INK)
    return colour


def _wood_grain(graph: Graph, texture: Texture, paint: Paint) -> Operand:
    k = "xyz".index(texture.axis)
    along = graph.math("ABSOLUTE", graph.o[k])
    u, v = (graph.o[i] for i in range(3) if i != k)
    r = graph.math("SQRT", graph.add(graph.mul(u, u), graph.mul(v, v)))
    wobble = graph.noise(r, along, 0.0, 25.0, detail=3.0)
    rings = graph.math("FRACT", graph.add(graph.mul(r, 150.0), graph.mul(wobble, 4.0)))
    late = graph.math("POWER", rings, 2.0)  # darkening to the latewood at the end of each ring
    fine = graph.mul(graph.noise(r, along, 0.0, 300.0, detail=1.0), 0.5)
    return graph.mix(graph.math("MINIMUM", graph.add(late, fine), 1.0), paint.base, paint.second)


def _glaze(graph: Graph, texture: Texture, paint: Paint) -> Operand:
    pool = graph.noise(*graph.o, 30.0, detail=4.0)
    factor = graph.math(
        "MINIMUM", graph.math("MAXIMUM", graph.mul(graph.math("SUBTRACT", pool, 0.4), 3.0), 0.0), 1.0
    )
    graph.roughness(graph.add(0.06, graph.mul(factor, 0.2)))
    return graph.mix(factor, paint.base, paint.second)


def _brushed(graph: Graph, texture: Texture, paint: Paint) -> Operand:
    streak = graph.noise(0.0, 0.0, graph.o[2], 1500.0, detail=1.0)
    grooves = graph.lt(graph.math("FRACT", graph.mul(graph.o[2], 60.0)), 0.06)  # turned rings, 1.7 mm pitch
    shade = graph.add(0.55, graph.mul(streak, 0.6))
    graph.roughness(graph.add(0.12, graph.mul(streak, 0.35)))
    dull = graph.math("MAXIMUM", graph.math("SUBTRACT", 1.0, shade), grooves)
    return graph.mix(dull, paint.base, paint.second)


def _speckle(graph: Graph, texture: Texture, paint: Paint) -> Operand:
    spots = graph.gt(graph.noise(*graph.o, 120.0, detail=2.0), 0.6)
    return graph.mix(spots, paint.base, paint.second)
