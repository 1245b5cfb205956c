"""Convex decomposition of shapes, for collision: a physics engine collides convex pieces.

- cylinders and boxes are one MuJoCo primitive each (exact);
- a revolved profile is cut analytically into horizontal slabs: where a slab's cross-section is a
  disc the piece is a frustum (stacked frusta merge while their union stays convex), where it is a
  ring the ring is cut into angular sectors, fine enough that a sector's inner chord stays within
  `CHORD_FRACTION` of the wall thickness;
- a compound is the pieces of its parts, placed;
- a mesh file is decomposed by CoACD (seeded, so deterministic), or kept whole when convex.

Pieces are in the shape's frame; `ConvexPiece.moved` places them.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import manifold3d
import numpy as np

from vint_engines.objects.spec import Box, Compound, Cylinder, MeshFile, Revolved, Shape, closed_outline
from vint_engines.objects.tessellate import (
    SEGMENTS,
    Array,
    TriangleMesh,
    canonical,
    circle,
    part_transform,
    primitive_mesh,
)

MERGE_TOLERANCE_M = 2e-4  # how far a merged frustum stack may bulge past the true surface
CHORD_FRACTION = 0.05
COACD_THRESHOLD = 0.05  # CoACD's concavity threshold (its default)
COACD_SEED = 0


@dataclass(frozen=True, eq=False)
class ConvexPiece:
    """A convex piece: a MuJoCo primitive (`box`: half extents; `cylinder`: radius, half length)
    placed by `pose`, or a `hull` of `points`."""

    kind: str
    size: tuple[float, ...]
    pose: Array = field(default_factory=lambda: np.eye(4))
    points: Array = field(default_factory=lambda: np.zeros((0, 3)))

    def moved(self, transform: Array) -> ConvexPiece:
        if self.kind == "hull":
            return ConvexPiece("hull", (), np.eye(4), self.points @ transform[:3, :3].T + transform[:3, 3])
        return ConvexPiece(self.kind, self.size, transform @ self.pose)

    def mesh(self) -> TriangleMesh:
        """The piece as a closed triangle mesh (primitives tessellated like the model mesh)."""
        if self.kind == "box":
            hx, hy, hz = self.size
            return primitive_mesh(Box((2 * hx, 2 * hy, 2 * hz))).moved(self.pose)
        if self.kind == "cylinder":
            return primitive_mesh(Cylinder(self.size[0], 2 * self.size[1])).moved(self.pose)
        hull = manifold3d.Manifold.hull_points(np.ascontiguousarray(self.points)).to_mesh64()
        return canonical(np.asarray(hull.vert_properties)[:, :3], np.asarray(hull.tri_verts, dtype=np.int64))


def convex_pieces(shape: Shape, mesh: TriangleMesh) -> list[ConvexPiece]:
    """The shape's convex pieces; `mesh` is its surface (used for mesh files)."""
    if isinstance(shape, Cylinder):
        return [ConvexPiece("cylinder", (shape.radius, shape.height / 2))]
    if isinstance(shape, Box):
        return [ConvexPiece("box", tuple(s / 2 for s in shape.size))]
    if isinstance(shape, Revolved):
        return revolved_pieces(shape.profile)
    if isinstance(shape, Compound):
        return [
            piece.moved(part_transform(part))
            for part in shape.parts
            for piece in convex_pieces(part.shape, primitive_mesh(part.shape))
        ]
    assert isinstance(shape, MeshFile)
    return mesh_pieces(mesh)


# -- revolved profiles -------------------------------------------------------------------------------


@dataclass
class _Stack:
    """Vertically adjacent slab sections of one wall (or of the core, when `inner` stays 0)."""

    z: list[float]
    inner: list[float]
    outer: list[float]

    def extends(self, z0: float, inner0: float, outer0: float) -> bool:
        """Whether a section starting at z0 continues this stack (radii equal up to rounding)."""
        return (
            self.z[-1] == z0
            and math.isclose(self.inner[-1], inner0, abs_tol=1e-12)
            and math.isclose(self.outer[-1], outer0, abs_tol=1e-12)
        )

    def stays_convex(self, z1: float, inner1: float, outer1: float) -> bool:
        """Whether adding the level keeps the union of sections equal to its hull (within the
        tolerance): the outer radius must not dip, the inner must not bulge, between the ends."""
        z = [*self.z, z1]
        for radii, sign in (([*self.outer, outer1], 1.0), ([*self.inner, inner1], -1.0)):
            for k in range(1, len(z) - 1):
                t = (z[k] - z[0]) / (z[-1] - z[0])
                line = radii[0] + t * (radii[-1] - radii[0])
                if sign * (radii[k] - line) < -MERGE_TOLERANCE_M:
                    return False
        return True


def revolved_pieces(profile: Sequence[tuple[float, float]]) -> list[ConvexPiece]:
    outline = closed_outline(profile)
    edges = list(zip(outline, outline[1:] + outline[:1], strict=True))
    levels = sorted({z for _, z in outline})
    stacks: list[_Stack] = []
    finished: list[_Stack] = []
    for z0, z1 in itertools.pairwise(levels):
        sections = _slab_sections(edges, z0, z1)
        still_open = []
        for inner0, inner1, outer0, outer1 in sections:
            stack = next((s for s in stacks if s.extends(z0, inner0, outer0)), None)
            if stack is not None and stack.stays_convex(z1, inner1, outer1):
                stacks.remove(stack)
            else:
                stack = _Stack([z0], [inner0], [outer0])
            stack.z.append(z1)
            stack.inner.append(inner1)
            stack.outer.append(outer1)
            still_open.append(stack)
        finished.extend(stacks)
        stacks = still_open
    finished.extend(stacks)
    return [piece for stack in finished for piece in _stack_pieces(stack)]


def _slab_sections(
    edges: Sequence[tuple[tuple[float, float], tuple[float, float]]], z0: float, z1: float
) -> list[tuple[float, float, float, float]]:
    """The solid's radial intervals between heights z0 < z1 (no outline vertex strictly inside):
    (inner at z0, inner at z1, outer at z0, outer at z1) per interval, inside out."""
    crossings = []
    for (ra, za), (rb, zb) in edges:
        if min(za, zb) <= z0 and max(za, zb) >= z1 and za != zb:
            at0 = ra + (rb - ra) * (z0 - za) / (zb - za)
            at1 = ra + (rb - ra) * (z1 - za) / (zb - za)
            crossings.append((max(at0, 0.0), max(at1, 0.0)))
    crossings.sort(key=lambda c: c[0] + c[1])
    return [(i0, i1, o0, o1) for (i0, i1), (o0, o1) in zip(crossings[::2], crossings[1::2], strict=True)]


def _stack_pieces(stack: _Stack) -> list[ConvexPiece]:
    """A core stack is one hull; a wall stack is cut into angular sectors."""
    if max(stack.inner) == 0.0:
        points = np.concatenate([_ring_points(r, z) for r, z in zip(stack.outer, stack.z, strict=True)])
        return [ConvexPiece("hull", (), points=points)]
    sectors = _sector_count(stack)
    per = SEGMENTS // sectors
    pieces = []
    for s in range(sectors):
        index = (np.arange(s * per, (s + 1) * per + 1)) % SEGMENTS
        points = [
            circle(r, z)[index]
            for radii in (stack.inner, stack.outer)
            for r, z in zip(radii, stack.z, strict=True)
        ]
        pieces.append(ConvexPiece("hull", (), points=np.concatenate(points)))
    return pieces


def _ring_points(radius: float, z: float) -> Array:
    return np.array([[0.0, 0.0, z]]) if radius == 0.0 else circle(radius, z)


def _sector_count(stack: _Stack) -> int:
    """The fewest sectors (a divisor of SEGMENTS) whose inner chords cut into the wall by at most
    CHORD_FRACTION of its thickness; SEGMENTS sectors reproduce the mesh exactly."""
    thickness = min(o - i for i, o in zip(stack.inner, stack.outer, strict=True))
    radius = max(stack.inner)
    sectors = 8
    while sectors < SEGMENTS and radius * (1 - math.cos(math.pi / sectors)) > CHORD_FRACTION * thickness:
        sectors *= 2
    return sectors


# -- mesh files --------------------------------------------------------------------------------------


def mesh_pieces(mesh: TriangleMesh) -> list[ConvexPiece]:
    """One hull when the mesh is convex (its volume equals its hull's), else CoACD's pieces."""
    hull = manifold3d.Manifold.hull_points(np.ascontiguousarray(mesh.vertices))
    if hull.volume() <= mesh.volume() * (1 + 1e-6):
        return [ConvexPiece("hull", (), points=mesh.vertices)]
    import coacd  # only mesh files need it

    coacd.set_log_level("error")
    parts = coacd.run_coacd(coacd.Mesh(mesh.vertices, mesh.faces), threshold=COACD_THRESHOLD, seed=COACD_SEED)
    return [ConvexPiece("hull", (), points=np.asarray(vertices, dtype=np.float64)) for vertices, _ in parts]
