"""Blender meshes: MuJoCo's primitive geoms (box, sphere, capsule, cylinder) built with bmesh, and
triangle meshes from vertex and face arrays (the object's model mesh, a user hand's mesh geoms).

Sizes follow MuJoCo: box half extents, sphere [r], capsule and cylinder [r, half length] along +z.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import bmesh
import bpy
import numpy as np
from mathutils import Matrix, Quaternion, Vector

from vint_engines.protocol import BadInput

SEGMENTS = 32
RINGS = 16
DISC_SEGMENTS = 10  # sides of a taxel's disc


# A rounded box's edges: bevel segments (4 keep the silhouette within 0.1 mm of a true round at
# the palm's 4 mm radius).
BEVEL_SEGMENTS = 4


def add_primitive(
    bm: bmesh.types.BMesh,
    kind: str,
    size: Sequence[float],
    matrix: Matrix,
    material_index: int = 0,
    edge_radius: float = 0.0,
) -> None:
    """Add one primitive, placed by `matrix`, to `bm`: curved faces smooth, flat faces sharp-edged,
    every face on material slot `material_index`. A box with `edge_radius` > 0 gets rounded edges
    (within its extent: the rounding removes material, never adds it)."""
    before = set(bm.faces)
    _create(bm, kind, size, matrix)
    if kind == "box" and edge_radius > 0.0:
        # In mesh order, never a set's: bevelling edges in another order moves vertices by a few
        # ULP, and a set of BMesh elements iterates in memory-address order, which differs between
        # processes (the depth of a bevelled palm differed at a few pixels).
        edges = []
        for face in (f for f in bm.faces if f not in before):
            edges.extend(edge for edge in face.edges if edge not in edges)
        radius = min(edge_radius, 0.45 * min(size))
        bmesh.ops.bevel(
            bm,
            geom=edges,
            offset=radius,
            segments=BEVEL_SEGMENTS,
            profile=0.5,
            affect="EDGES",
            clamp_overlap=True,
        )
    for face in set(bm.faces) - before:
        face.material_index = material_index
        flat = kind == "box" and edge_radius <= 0.0
        face.smooth = not flat and len(face.verts) <= 4  # cylinder caps are n-gons
        if not face.smooth:
            for edge in face.edges:
                edge.smooth = False


def _create(bm: bmesh.types.BMesh, kind: str, size: Sequence[float], matrix: Matrix) -> None:
    if kind == "box":
        hx, hy, hz = size
        bmesh.ops.create_cube(bm, size=1.0, matrix=matrix @ Matrix.Diagonal((2 * hx, 2 * hy, 2 * hz, 1.0)))
    elif kind == "sphere":
        _uv_sphere(bm, size[0], matrix)
    elif kind == "cylinder":
        radius, half = size
        bmesh.ops.create_cone(
            bm,
            cap_ends=True,
            segments=SEGMENTS,
            radius1=radius,
            radius2=radius,
            depth=2 * half,
            matrix=matrix,
        )
    elif kind == "capsule":
        radius, half = size
        bmesh.ops.create_cone(
            bm,
            cap_ends=False,
            segments=SEGMENTS,
            radius1=radius,
            radius2=radius,
            depth=2 * half,
            matrix=matrix,
        )
        for end in (-half, half):
            _uv_sphere(bm, radius, matrix @ Matrix.Translation((0.0, 0.0, end)))
    else:
        raise BadInput(f"unsupported geom type {kind!r}")


def _uv_sphere(bm: bmesh.types.BMesh, radius: float, matrix: Matrix) -> None:
    """A UV sphere of SEGMENTS meridians and RINGS bands placed by `matrix`, its vertices and faces
    made one by one in a fixed order, faces wound outwards. (`bmesh.ops.create_uvsphere` orders its
    faces and their loops differently from one process to the next; the ray tracer breaks a tie
    between two triangles of a mesh by their order, so a view's pixels could differ by a few ULP —
    a path's whole branch after a bounce — between processes.)"""
    top = bm.verts.new(matrix @ Vector((0.0, 0.0, radius)))
    turns = [2.0 * math.pi * j / SEGMENTS for j in range(SEGMENTS)]
    rings = []
    for i in range(1, RINGS):
        theta = math.pi * i / RINGS
        z, rho = radius * math.cos(theta), radius * math.sin(theta)
        rings.append(
            [bm.verts.new(matrix @ Vector((rho * math.cos(a), rho * math.sin(a), z))) for a in turns]
        )
    bottom = bm.verts.new(matrix @ Vector((0.0, 0.0, -radius)))
    for j in range(SEGMENTS):
        k = (j + 1) % SEGMENTS
        bm.faces.new((top, rings[0][j], rings[0][k]))
        for upper, lower in itertools.pairwise(rings):
            bm.faces.new((upper[j], lower[j], lower[k], upper[k]))
        bm.faces.new((rings[-1][j], bottom, rings[-1][k]))


def add_discs(
    bm: bmesh.types.BMesh,
    centres: np.ndarray,
    normals: np.ndarray,
    radius: float,
    half_height: float,
    material_index: int,
) -> None:
    """One flat disc (a short cylinder of DISC_SEGMENTS sides) per row of `centres`, its axis along
    the matching unit normal, flat-shaded on material slot `material_index`; vertices and faces
    made one by one in a fixed order, wound outwards (as `_uv_sphere`, and for its reason)."""
    turns = [2.0 * math.pi * j / DISC_SEGMENTS for j in range(DISC_SEGMENTS)]
    for centre, normal in zip(centres, normals, strict=True):
        matrix = axis_matrix(centre, normal)
        rings = [
            [bm.verts.new(matrix @ Vector((radius * math.cos(a), radius * math.sin(a), z))) for a in turns]
            for z in (-half_height, half_height)
        ]
        bottom, top = rings
        faces = [bm.faces.new(tuple(reversed(bottom))), bm.faces.new(tuple(top))]
        for j in range(DISC_SEGMENTS):
            k = (j + 1) % DISC_SEGMENTS
            faces.append(bm.faces.new((bottom[j], bottom[k], top[k], top[j])))
        for face in faces:
            face.material_index = material_index
            face.smooth = False


def geom_matrix(p: Sequence[float], q: Sequence[float]) -> Matrix:
    return Matrix.LocRotScale(Vector(p), Quaternion(q), None)


def axis_matrix(centre: Sequence[float], axis: Sequence[float]) -> Matrix:
    """A frame at `centre` whose +z is `axis` (a unit vector)."""
    rotation = Vector((0.0, 0.0, 1.0)).rotation_difference(Vector(axis))
    return Matrix.LocRotScale(Vector(centre), rotation, None)


Primitive = tuple[str, Sequence[float], Matrix]


Triangles = tuple[np.ndarray, np.ndarray, Matrix, int]  # vertices, faces, placement, material slot
Discs = tuple[np.ndarray, np.ndarray, float, float, int]  # centres, normals, radius, half height, slot

# Edges of a triangle mesh geom sharper than this are drawn sharp; the rest are shaded smooth.
MESH_SHARP_DEG = 30.0


def add_triangles(
    bm: bmesh.types.BMesh, vertices: np.ndarray, faces: np.ndarray, matrix: Matrix, material_index: int
) -> None:
    """Add a triangle mesh (a user hand's mesh geom), placed by `matrix`, on slot `material_index`:
    smooth, but sharp across edges sharper than `MESH_SHARP_DEG`. Degenerate and repeated
    triangles (which bmesh refuses) are left out."""
    verts = [bm.verts.new(matrix @ Vector(v)) for v in np.asarray(vertices, dtype=np.float64).tolist()]
    added = []
    for a, b, c in np.asarray(faces, dtype=np.int64).tolist():
        if len({a, b, c}) < 3:
            continue
        try:
            face = bm.faces.new((verts[a], verts[b], verts[c]))
        except ValueError:  # the same triangle twice
            continue
        face.material_index = material_index
        face.smooth = True
        added.append(face)
    sharp = math.radians(MESH_SHARP_DEG)
    for edge in {edge for face in added for edge in face.edges}:
        if len(edge.link_faces) != 2 or edge.calc_face_angle(0.0) > sharp:
            edge.smooth = False


def new_mesh(
    name: str,
    geoms: Sequence[Primitive],
    material_indices: Sequence[int] = (),
    edge_radius: float = 0.0,
    triangles: Sequence[Triangles] = (),
    discs: Discs | None = None,
) -> bpy.types.Mesh:
    """One mesh holding every (kind, size, matrix) primitive, the i-th on material slot
    `material_indices[i]` (0 when not given); boxes get rounded edges of `edge_radius`;
    `triangles` adds triangle meshes (`add_triangles`), `discs` flat discs (`add_discs`)."""
    bm = bmesh.new()
    try:
        for i, (kind, size, matrix) in enumerate(geoms):
            slot = material_indices[i] if i < len(material_indices) else 0
            add_primitive(bm, kind, size, matrix, slot, edge_radius)
        for vertices, faces, matrix, slot in triangles:
            add_triangles(bm, vertices, faces, matrix, slot)
        if discs is not None:
            add_discs(bm, *discs)
        mesh = bpy.data.meshes.new(name)
        bm.to_mesh(mesh)
    finally:
        bm.free()
    return mesh


def triangle_mesh(name: str, vertices: np.ndarray, faces: np.ndarray, sharp_deg: float) -> bpy.types.Mesh:
    """A mesh of the given triangles, shaded smooth except across edges sharper than `sharp_deg`."""
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(np.asarray(vertices, dtype=np.float64).tolist(), [], np.asarray(faces).tolist())
    if mesh.validate():
        raise BadInput(f"mesh {name!r} has invalid geometry")
    mesh.shade_smooth()
    mesh.set_sharp_from_angle(angle=math.radians(sharp_deg))
    return mesh
