"""What an object is, as plain validated data: its catalog entry (name, mass, material, texture
and colours, symmetries) and its shape, parsed from a `[[object]]` table of `catalog/objects.toml`
or from task parameters (which carry that table as JSON).

The schema is shared with the Rust side (`catalog/objects.toml` is parsed there too); see the comment
at the top of that file. Nothing here builds meshes or reads files: `tessellate.py` and `meshio.py` do.
Every error is a `BadInput` whose message starts with the field's path (`params.object.shape.radius_m`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import PurePosixPath
from typing import Any

import numpy as np

from vint_engines import contract
from vint_engines import params as P
from vint_engines.protocol import BadInput

MATERIALS = ("plastic", "metal", "glass", "paper", "cardboard", "wood", "ceramic", "rubber")
TEXTURE_KEYS = {
    "plain": ("kind",),
    "label": ("kind", "band", "print"),
    "panels": ("kind", "print"),
    "wood_grain": ("kind", "axis"),
    "glaze": ("kind",),
    "brushed": ("kind",),
    "speckle": ("kind",),
}
COLOUR_KEYS = ("base", "band", "lower", "print", "cap")
CAP_KEYS = ("above", "colour")
AXES = ("x", "y", "z")
ORTHONORMAL_TOLERANCE = 1e-6  # a discrete symmetry's rotation: |RᵀR - I| and |det R - 1| below this
MESH_SUFFIXES = (".obj", ".stl", ".ply")
NAME = re.compile(r"[a-z0-9_]+")
SHA256 = re.compile(r"[0-9a-f]{64}")

# Bounds from the stage contract (vint_core::contract::object, via contract.schema.json).
LENGTH_M = contract.bounds("Shape", "radius_m", "cylinder")  # any single dimension
MASS_KG = contract.bounds("ObjectEntry", "mass_kg")
BOP_OBJ_ID = contract.bounds("ObjectEntry", "obj_id")
POSITION_M = contract.bounds("Part", "pos_m", "box")
EULER_DEG = contract.bounds("Part", "euler_deg", "box")
MIN_PROFILE_POINTS, MAX_PROFILE_POINTS = contract.count_bounds("Shape", "profile_m", "revolved")
MAX_PARTS = contract.count_bounds("Shape", "parts", "compound")[1]
MESH_SCALE = contract.bounds("Shape", "scale", "mesh")

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Cylinder:
    """Axis +z, centred on its own origin."""

    radius: float
    height: float


@dataclass(frozen=True)
class Box:
    """Full edge lengths along x, y, z, centred on its own origin."""

    size: Vec3


@dataclass(frozen=True)
class Revolved:
    """The solid swept by the (r, z) profile about +z, closed along the axis. Only the first and the
    last point may lie on the axis; the closed outline must not cross itself."""

    profile: tuple[tuple[float, float], ...]


PartShape = Cylinder | Box | Revolved


@dataclass(frozen=True)
class Part:
    """A part placed in the compound's frame: rotated by `euler_deg` (about the fixed x, then y,
    then z axes: R = Rz·Ry·Rx), then moved to `pos`."""

    shape: PartShape
    pos: Vec3
    euler_deg: Vec3


@dataclass(frozen=True)
class Compound:
    """The union of overlapping parts (they must form one connected solid)."""

    parts: tuple[Part, ...]


@dataclass(frozen=True)
class MeshFile:
    """A triangle mesh file (OBJ, STL or PLY): `path` relative to the catalog directory, or, for a
    user's object, `asset`, the SHA-256 of a file that came with the job (the engine finds it among
    its task's inputs); `scale` takes file units to metres."""

    path: str
    scale: float
    asset: str = ""


Shape = Cylinder | Box | Revolved | Compound | MeshFile


Rgb = tuple[float, float, float]


@dataclass(frozen=True)
class Colours:
    """The real product's colours (`vint_core::contract::object::Colours`), linear RGB 0–1: `base`
    the body, `band` the pattern's second colour, `lower` a two-tone label band's lower half,
    `print` a label's edges and logo or a box's inner panel and logo, `cap` = (above, colour):
    everything above that fraction of the height. What each paints per kind: `render/textures.py`."""

    base: Rgb
    band: Rgb | None = None
    lower: Rgb | None = None
    print: Rgb | None = None
    cap: tuple[float, Rgb] | None = None

    @property
    def height_bound(self) -> bool:
        """Whether some colour depends on the height alone (a two-tone band, a cap): such colours
        keep only the rotations that keep +z."""
        return self.lower is not None or self.cap is not None

    def to_json(self) -> dict[str, Any]:
        table: dict[str, Any] = {"base": list(self.base)}
        for key, value in (("band", self.band), ("lower", self.lower), ("print", self.print)):
            if value is not None:
                table[key] = list(value)
        if self.cap is not None:
            table["cap"] = {"above": self.cap[0], "colour": list(self.cap[1])}
        return table


@dataclass(frozen=True)
class Texture:
    """An object's surface pattern (`vint_core::contract::object::Texture`): `kind`, and for a
    label its `band` (bottom and top, fractions of the height) and `print`, for panels `print`,
    for wood grain the ring `axis`; with the entry's `colours` (kept beside the texture in the
    catalog), since together they are the object's look. The render engine builds it
    (`render/textures.py`)."""

    kind: str = "plain"
    band: tuple[float, float] = (0.0, 1.0)
    print: bool = False
    axis: str = "z"
    colours: Colours | None = None

    def table(self) -> dict[str, Any]:
        """The catalog's `texture` table."""
        keys = TEXTURE_KEYS[self.kind]
        full = {"kind": self.kind, "band": list(self.band), "print": self.print, "axis": self.axis}
        return {key: full[key] for key in keys}

    def to_json(self) -> dict[str, Any]:
        """The whole look: the `texture` table, with `colours` when the entry states them."""
        colours = {} if self.colours is None else {"colours": self.colours.to_json()}
        return {**self.table(), **colours}


@dataclass(frozen=True)
class Symmetries:
    """The textured object's symmetries in BOP's `models_info.json` form, in metres: continuous
    ones as (axis, offset), discrete ones as row-major 4×4 transforms (identity left out)."""

    continuous: tuple[tuple[Vec3, Vec3], ...] = ()
    discrete: tuple[tuple[float, ...], ...] = ()

    def to_json(self) -> dict[str, Any]:
        return {
            "symmetries_continuous": [{"axis": list(a), "offset": list(o)} for a, o in self.continuous],
            "symmetries_discrete": [list(m) for m in self.discrete],
        }


@dataclass(frozen=True)
class ObjectSpec:
    """One object: a catalog entry. Hashable, so engines can cache what they build per object."""

    name: str
    mass: float
    material: str
    shape: Shape
    texture: Texture = Texture()
    symmetries: Symmetries = Symmetries()
    ycb_id: str = ""
    description: str = ""
    obj_id: int | None = None  # a BOP dataset's own id, kept by the exports

    @staticmethod
    def parse(obj: Mapping[str, Any], where: str = "params.object") -> ObjectSpec:
        """A catalog entry: its fields checked here as `contract.schema.json`'s `ObjectEntry` has
        them, plus what a schema cannot say (a profile that crosses itself)."""
        _only(obj, ENTRY_KEYS, where)
        name = P.string(obj, "name", where)
        if not NAME.fullmatch(name):
            raise BadInput(f"{where}.name: {name!r} must match [a-z0-9_]+")
        return ObjectSpec(
            name=name,
            mass=P.number(obj, "mass_kg", where, low=MASS_KG[0], high=MASS_KG[1]),
            material=_choice(obj, "material", where, MATERIALS),
            texture=replace(
                _texture(obj.get("texture", {"kind": "plain"}), f"{where}.texture"),
                colours=_colours(obj["colours"], f"{where}.colours") if "colours" in obj else None,
            ),
            symmetries=_symmetries(obj, where),
            shape=parse_shape(P.section(obj, "shape", where), f"{where}.shape"),
            ycb_id=_text(obj, "ycb_id", where),
            description=_text(obj, "description", where),
            obj_id=(
                P.integer(obj, "obj_id", where, low=int(BOP_OBJ_ID[0]), high=int(BOP_OBJ_ID[1]))
                if "obj_id" in obj
                else None
            ),
        )

    def to_json(self) -> dict[str, Any]:
        """The entry in the catalog's schema (what the Rust planner sends)."""
        return {
            "name": self.name,
            "ycb_id": self.ycb_id,
            "mass_kg": self.mass,
            "material": self.material,
            "texture": self.texture.table(),
            **({} if self.texture.colours is None else {"colours": self.texture.colours.to_json()}),
            **self.symmetries.to_json(),
            "description": self.description,
            "shape": shape_json(self.shape),
            **({} if self.obj_id is None else {"obj_id": self.obj_id}),
        }


# `model` is what the grasp engine adds when it echoes the entry into grasps.json.
ENTRY_KEYS = (
    "name",
    "ycb_id",
    "mass_kg",
    "material",
    "texture",
    "colours",
    "symmetries_continuous",
    "symmetries_discrete",
    "description",
    "shape",
    "obj_id",
    "model",
)
SHAPE_KEYS = {
    "cylinder": ("type", "radius_m", "height_m"),
    "box": ("type", "size_m"),
    "revolved": ("type", "profile_m"),
    "compound": ("type", "parts"),
    "mesh": ("type", "path", "asset", "scale"),
}
PART_TYPES = ("cylinder", "box", "revolved")
PLACEMENT_KEYS = ("pos_m", "euler_deg")


def parse_shape(
    obj: Mapping[str, Any], where: str, types: Sequence[str] = tuple(SHAPE_KEYS), extra: Sequence[str] = ()
) -> Shape:
    """A shape table; `types` limits the shape types, `extra` names further allowed keys."""
    kind = _choice(obj, "type", where, types)
    _only(obj, (*SHAPE_KEYS[kind], *extra), where)
    if kind == "cylinder":
        return Cylinder(radius=_length(obj, "radius_m", where), height=_length(obj, "height_m", where))
    if kind == "box":
        x, y, z = _vector(obj, "size_m", where, low=LENGTH_M[0], high=LENGTH_M[1])
        return Box((x, y, z))
    if kind == "revolved":
        return Revolved(_profile(obj, "profile_m", where))
    if kind == "compound":
        parts = obj.get("parts")
        if not isinstance(parts, list) or not 1 <= len(parts) <= MAX_PARTS:
            raise BadInput(f"{where}.parts: expected a list of 1 to {MAX_PARTS} part tables")
        return Compound(tuple(_part(part, f"{where}.parts[{i}]") for i, part in enumerate(parts)))
    return _mesh_file(obj, where)


def shape_json(shape: Shape) -> dict[str, Any]:
    """A shape as its catalog table."""
    if isinstance(shape, Cylinder):
        return {"type": "cylinder", "radius_m": shape.radius, "height_m": shape.height}
    if isinstance(shape, Box):
        return {"type": "box", "size_m": list(shape.size)}
    if isinstance(shape, Revolved):
        return {"type": "revolved", "profile_m": [list(point) for point in shape.profile]}
    if isinstance(shape, Compound):
        return {
            "type": "compound",
            "parts": [
                {**shape_json(p.shape), "pos_m": list(p.pos), "euler_deg": list(p.euler_deg)}
                for p in shape.parts
            ],
        }
    if shape.asset:
        return {"type": "mesh", "asset": shape.asset, "scale": shape.scale}
    return {"type": "mesh", "path": shape.path, "scale": shape.scale}


def _texture(obj: Any, where: str) -> Texture:
    if not isinstance(obj, Mapping):
        raise BadInput(f"{where}: expected a table with a kind")
    kind = _choice(obj, "kind", where, tuple(TEXTURE_KEYS))
    _only(obj, TEXTURE_KEYS[kind], where)
    if kind == "label":
        raw = obj.get("band")
        if not isinstance(raw, list) or len(raw) != 2:
            raise BadInput(f"{where}.band: expected [bottom, top], got {raw!r}")
        bottom, top = (_number_at(v, f"{where}.band[{i}]", 0.0, 1.0) for i, v in enumerate(raw))
        if bottom >= top:
            raise BadInput(f"{where}.band: the bottom {bottom} must lie below the top {top}")
        return Texture(kind, band=(bottom, top), print=P.boolean(obj, "print", where))
    if kind == "panels":
        return Texture(kind, print=P.boolean(obj, "print", where))
    if kind == "wood_grain":
        return Texture(kind, axis=_choice(obj, "axis", where, AXES))
    return Texture(kind)


def _colours(obj: Any, where: str) -> Colours:
    if not isinstance(obj, Mapping):
        raise BadInput(f"{where}: expected a table with a base colour")
    _only(obj, COLOUR_KEYS, where)

    def rgb(key: str) -> Rgb | None:
        return _vector(obj, key, where, low=0.0, high=1.0) if key in obj else None

    base = rgb("base")
    if base is None:
        raise BadInput(f"{where}.base: missing (the body's colour, [r, g, b] linear 0–1)")
    cap = None
    if "cap" in obj:
        table = obj["cap"]
        if not isinstance(table, Mapping):
            raise BadInput(f"{where}.cap: expected {{above, colour}}")
        _only(table, CAP_KEYS, f"{where}.cap")
        above = P.number(table, "above", f"{where}.cap", low=0.0, high=1.0)
        cap = (above, _vector(table, "colour", f"{where}.cap", low=0.0, high=1.0))
    return Colours(base, band=rgb("band"), lower=rgb("lower"), print=rgb("print"), cap=cap)


def _symmetries(obj: Mapping[str, Any], where: str) -> Symmetries:
    """BOP-style symmetry lists: unit axes, and rigid transforms (orthonormal rotation, det +1,
    last row 0 0 0 1)."""
    continuous = obj.get("symmetries_continuous", [])
    discrete = obj.get("symmetries_discrete", [])
    if not isinstance(continuous, list) or not isinstance(discrete, list):
        raise BadInput(f"{where}: symmetries_continuous and symmetries_discrete must be lists")
    axes = []
    for i, entry in enumerate(continuous):
        at = f"{where}.symmetries_continuous[{i}]"
        if not isinstance(entry, Mapping):
            raise BadInput(f"{at}: expected {{axis, offset}}")
        _only(entry, ("axis", "offset"), at)
        axis = _vector(entry, "axis", at, low=-1.0, high=1.0)
        if abs(math.hypot(*axis) - 1.0) > ORTHONORMAL_TOLERANCE:
            raise BadInput(f"{at}.axis: {list(axis)} is not a unit vector")
        axes.append((axis, _vector(entry, "offset", at, low=POSITION_M[0], high=POSITION_M[1])))
    transforms = []
    for i, raw in enumerate(discrete):
        at = f"{where}.symmetries_discrete[{i}]"
        if not isinstance(raw, list) or len(raw) != 16:
            raise BadInput(f"{at}: expected 16 numbers (a row-major 4×4 transform)")
        m = np.array([_number_at(v, f"{at}[{k}]", -1e3, 1e3) for k, v in enumerate(raw)]).reshape(4, 4)
        r = m[:3, :3]
        if (
            np.abs(r.T @ r - np.eye(3)).max() > ORTHONORMAL_TOLERANCE
            or abs(np.linalg.det(r) - 1.0) > ORTHONORMAL_TOLERANCE
            or np.abs(m[3] - (0.0, 0.0, 0.0, 1.0)).max() > 0.0
        ):
            raise BadInput(f"{at}: not a rigid transform (rotation with det +1, last row 0 0 0 1)")
        transforms.append(tuple(float(v) for v in raw))
    return Symmetries(tuple(axes), tuple(transforms))


def _part(obj: Any, where: str) -> Part:
    if not isinstance(obj, Mapping):
        raise BadInput(f"{where}: expected a part table")
    shape = parse_shape(obj, where, PART_TYPES, PLACEMENT_KEYS)
    assert isinstance(shape, Cylinder | Box | Revolved)
    x, y, z = _vector(obj, "pos_m", where, low=POSITION_M[0], high=POSITION_M[1])
    rx, ry, rz = _vector(
        obj, "euler_deg", where, low=EULER_DEG[0], high=EULER_DEG[1], default=(0.0, 0.0, 0.0)
    )
    return Part(shape, (x, y, z), (rx, ry, rz))


def _mesh_file(obj: Mapping[str, Any], where: str) -> MeshFile:
    scale = P.number(obj, "scale", where, low=MESH_SCALE[0], high=MESH_SCALE[1])
    if "asset" in obj:
        if "path" in obj:
            raise BadInput(f"{where}: give either path or asset, not both")
        asset = P.string(obj, "asset", where)
        if not SHA256.fullmatch(asset):
            raise BadInput(f"{where}.asset: {asset!r} is not a SHA-256 (64 lowercase hex digits)")
        return MeshFile(path="", scale=scale, asset=asset)
    path = P.string(obj, "path", where)
    pure = PurePosixPath(path)
    if pure.is_absolute() or ".." in pure.parts or "\\" in path:
        raise BadInput(f"{where}.path: {path!r} must be relative to the catalog directory, without '..'")
    if pure.suffix.lower() not in MESH_SUFFIXES:
        raise BadInput(f"{where}.path: {path!r} is not one of {list(MESH_SUFFIXES)}")
    return MeshFile(path=path, scale=scale)


def _profile(obj: Mapping[str, Any], key: str, where: str) -> tuple[tuple[float, float], ...]:
    raw = obj.get(key)
    if not isinstance(raw, list) or not MIN_PROFILE_POINTS <= len(raw) <= MAX_PROFILE_POINTS:
        raise BadInput(
            f"{where}.{key}: expected a list of {MIN_PROFILE_POINTS} to {MAX_PROFILE_POINTS} [r, z] points"
        )
    points = []
    for i, point in enumerate(raw):
        if not isinstance(point, list) or len(point) != 2:
            raise BadInput(f"{where}.{key}[{i}]: expected [r, z], got {point!r}")
        r = _number_at(point[0], f"{where}.{key}[{i}][0]", 0.0, LENGTH_M[1])
        z = _number_at(point[1], f"{where}.{key}[{i}][1]", -LENGTH_M[1], LENGTH_M[1])
        if r == 0.0 and 0 < i < len(raw) - 1:
            raise BadInput(f"{where}.{key}[{i}]: only the first and last points may lie on the axis (r = 0)")
        if points and (r, z) == points[-1]:
            raise BadInput(f"{where}.{key}[{i}]: repeats the previous point")
        points.append((r, z))
    if all(r == 0.0 for r, _ in points):
        raise BadInput(f"{where}.{key}: the profile lies on the axis")
    _check_simple(points, f"{where}.{key}")
    return tuple(points)


def closed_outline(profile: Sequence[tuple[float, float]]) -> list[tuple[float, float]]:
    """The profile closed along the axis: it starts and ends at r = 0."""
    outline = list(profile)
    if outline[0][0] > 0.0:
        outline.insert(0, (0.0, outline[0][1]))
    if outline[-1][0] > 0.0:
        outline.append((0.0, outline[-1][1]))
    return outline


def _check_simple(profile: Sequence[tuple[float, float]], where: str) -> None:
    """BadInput if the outline closed along the axis crosses or touches itself, or has no area."""
    ring = np.array(closed_outline(profile))
    a, b = ring, np.roll(ring, -1, axis=0)
    area = 0.5 * float(np.sum(a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1]))
    if abs(area) < 1e-10:
        raise BadInput(f"{where}: the profile encloses no area")
    n = len(ring)
    for i in range(n):
        for j in range(i + 2, n):
            if i == 0 and j == n - 1:
                continue  # neighbours across the closing edge
            if _segments_meet(a[i], b[i], a[j], b[j]):
                raise BadInput(
                    f"{where}: the outline crosses itself (edges {i} and {j} of the closed outline)"
                )


def _segments_meet(p1: np.ndarray, p2: np.ndarray, q1: np.ndarray, q2: np.ndarray) -> bool:
    def orient(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
        return float((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))

    def within(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> bool:
        return bool(np.all(np.minimum(a, b) <= c) and np.all(c <= np.maximum(a, b)))

    d1, d2 = orient(q1, q2, p1), orient(q1, q2, p2)
    d3, d4 = orient(p1, p2, q1), orient(p1, p2, q2)
    if ((d1 > 0) != (d2 > 0)) and ((d3 > 0) != (d4 > 0)) and 0 not in (d1, d2, d3, d4):
        return True
    return (
        (d1 == 0 and within(q1, q2, p1))
        or (d2 == 0 and within(q1, q2, p2))
        or (d3 == 0 and within(p1, p2, q1))
        or (d4 == 0 and within(p1, p2, q2))
    )


def _only(obj: Mapping[str, Any], allowed: Sequence[str], where: str) -> None:
    unknown = sorted(set(obj) - set(allowed))
    if unknown:
        raise BadInput(f"{where}.{unknown[0]}: unknown field (expected one of {list(allowed)})")


def _choice(obj: Mapping[str, Any], key: str, where: str, choices: Sequence[str]) -> str:
    value = P.string(obj, key, where)
    if value not in choices:
        raise BadInput(f"{where}.{key}: {value!r} is not one of {list(choices)}")
    return value


def _text(obj: Mapping[str, Any], key: str, where: str) -> str:
    value = obj.get(key, "")
    if not isinstance(value, str):
        raise BadInput(f"{where}.{key}: expected a string, got {value!r}")
    return value


def _length(obj: Mapping[str, Any], key: str, where: str) -> float:
    return P.number(obj, key, where, low=LENGTH_M[0], high=LENGTH_M[1])


def _vector(
    obj: Mapping[str, Any],
    key: str,
    where: str,
    *,
    low: float,
    high: float,
    default: Vec3 | None = None,
) -> Vec3:
    raw = obj.get(key, None if default is None else list(default))
    if not isinstance(raw, list) or len(raw) != 3:
        raise BadInput(f"{where}.{key}: expected 3 numbers, got {raw!r}")
    x, y, z = (_number_at(v, f"{where}.{key}[{i}]", low, high) for i, v in enumerate(raw))
    return (x, y, z)


def _number_at(value: Any, path: str, low: float, high: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise BadInput(f"{path}: expected a finite number, got {value!r}")
    if not low <= value <= high:
        raise BadInput(f"{path}: {value} is outside [{low}, {high}]")
    return float(value)


def euler_matrix(euler_deg: Vec3) -> np.ndarray:
    """R = Rz·Ry·Rx of rotations (degrees) about the fixed x, y and z axes."""
    rx, ry, rz = (math.radians(a) for a in euler_deg)
    cx, sx, cy, sy, cz, sz = (
        math.cos(rx),
        math.sin(rx),
        math.cos(ry),
        math.sin(ry),
        math.cos(rz),
        math.sin(rz),
    )
    r_x = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    r_y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    r_z = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return r_z @ r_y @ r_x
