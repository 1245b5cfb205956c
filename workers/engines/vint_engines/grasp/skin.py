"""Lays a hand's taxels out on its collision surfaces: the generator of the built-in layouts.

`scripts/gen_taxels.py` writes `generate_layout(hand)` to `catalog/hands/<hand>/taxels.csv`; the
engine only ever reads those files (`taxels.py`), so a scanned layout of a real sensor can replace
one. The layout follows the compiled model's geometry: each link's geoms are read back from MuJoCo
(pose in the link frame, MuJoCo sizes) and sampled where a tactile skin covers a real hand
(VinT-6D, sec. "Simulating Touch": fingertips, pulps and palm):

- `palm`: the palmar face of the palm box (+z of the palm frame);
- `pulp`: the palmar half (link +x side) of the cylindrical part of every finger link but the last;
- `tip`: the last link of each finger: the palmar half of its capsule and the fingertip dome (the
  sphere's half towards the finger's end plus a palmar band down to 120° from the finger axis).

Candidates are dense grids (0.5 mm) on each patch, kept 1.5 mm inside the patch's edges and 1 mm
clear of every other hand geom with the hand open (where links overlap at joints, a fingertip
sphere swallows the end of its capsule or the thumb's base lies on the palm). The sensor's taxel
count (620 for `trx3`, 679 for `allegro`, as on the real sensors) is shared out between patches in
proportion to their area (largest remainder), and each patch's taxels are picked by farthest-point
sampling, which spreads them evenly. No randomness: the result depends on the model alone.

The same layout on any CPU: numpy and MuJoCo take different SIMD paths on different CPUs (AVX-512
or AVX2), so their floating-point results differ in the last bits, and a choice made by comparing
floats that tie in exact arithmetic (e.g. a fingertip dome exactly 1 mm clear of the capsule it
swallows) goes either way. So every choice is made on integers: clearances are rounded to whole
nanometres before the comparison, candidate positions are snapped to whole micrometres (what the
file keeps), and the share-out and the farthest-point sampling run in exact integer or rational
arithmetic, ties going to the lowest index. A different CPU changes a choice only when a value
lies within its last-bit difference (~1e-17 m) of a rounding boundary (half a nm or µm): about
once in 1e8 values. Layouts are still compared within a tolerance (`taxels.layout_differences`),
and the committed files, not the generator, are what the engines read and datasets cite.

A user's MJCF hand (`hands/mjcf.py`) is sampled the same way (`scripts/gen_taxels.py --mjcf`); its
fingertip links are the ends of its chains. Its boxes, capsules and spheres follow the built-in
hands' link convention (link +x on the palmar side, +z along the link). Its colliding **mesh** geoms
are felt through the convex hull MuJoCo compiles for them, so their taxels lie on that hull, and a
real hand's mesh frames follow its CAD, not our convention: on a mesh the skin covers
(`_mesh_candidates`)

- `palm`: the hull's faces turned within 60° of the palm's +z (the palm normal every hand has);
- `pulp`: the faces turned within 60° of the way the link moves as the hand closes (its leading
  side: the motion of the hull's centroid from the open pose a step towards `vint_closed`);
- `tip`: the same, and the faces turned within 60° of the link's length (from the link's origin,
  its joint, to the hull's centroid): the fingertip's end.

Each chosen hull face is cut into n² equal triangles (n from its area, for 0.5 mm spacing) whose
centroids are the candidates, kept 1.5 mm from the border of the chosen faces and 1 mm clear of
every other geom (a hull's distance is the largest of its face planes', a lower bound: never too
close). A link that does not move as the hand closes (and is not the palm) gets no taxels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction

import mujoco
import numpy as np
import numpy.typing as npt

from vint_engines.grasp.hand import add_hand
from vint_engines.grasp.hands import GraspHand
from vint_engines.grasp.taxels import TaxelLayout

Array = npt.NDArray[np.float64]

SENSOR_TAXELS = {"trx3": 620, "allegro": 679}  # taxels of the real sensors (VinT-6D)
SPACING = 0.0005  # m between candidates
EDGE_MARGIN = 0.0015  # m
CLEARANCE = 0.001  # m
TIP_PALMAR_POLAR = math.radians(120.0)
MESH_FACING_COS = 0.5  # a mesh face is on a side when its normal is within 60° of the side's direction
CLOSING_STEP = 0.01  # of the way from the open pose to the closed one: the motion that finds a link's lead
STILL_M = 1e-9  # a link's centroid moving less than this on that step does not move
MICROMETRES_PER_M = 1_000_000  # candidate positions are snapped to this lattice (the file's digits)
NANOMETRES_PER_M = 1_000_000_000  # clearances are compared in whole nanometres


@dataclass(frozen=True)
class Patch:
    """Candidate taxel sites on one geom of one link (link frame, on the micrometre lattice) and
    the area they cover."""

    link: str
    region: str
    points: Array
    normals: Array
    area: float


def generate_layout(dims: GraspHand, count: int | None = None) -> TaxelLayout:
    """`count` taxels (default: the built-in hand's real sensor's) on the hand's skin patches."""
    patches = hand_patches(dims)
    total = SENSOR_TAXELS[dims.name] if count is None else count
    counts = share_out(total, [patch.area for patch in patches])
    links: list[str] = []
    positions, normals, regions = [], [], []
    for patch, count in zip(patches, counts, strict=True):
        chosen = farthest_points(patch.points, count)
        p = micrometres(patch.points[chosen])
        chosen = chosen[np.lexsort((p[:, 0], p[:, 1], p[:, 2]))]  # a readable, stable order
        links += [patch.link] * len(chosen)
        regions += [patch.region] * len(chosen)
        positions.append(patch.points[chosen])
        normals.append(patch.normals[chosen])
    return TaxelLayout(tuple(links), np.vstack(positions), np.vstack(normals), tuple(regions))


def compile_hand(dims: GraspHand) -> mujoco.MjModel:
    spec = mujoco.MjSpec()
    spec.compiler.degree = False
    add_hand(spec, dims)
    return spec.compile()


def hand_patches(dims: GraspHand) -> list[Patch]:
    model = compile_hand(dims)
    data = mujoco.MjData(model)
    for name, angle in zip(dims.joint_names(), dims.open_pose(), strict=True):
        data.qpos[model.joint(name).qposadr[0]] = angle
    mujoco.mj_kinematics(model, data)  # the open hand; the palm sits at the world origin
    closing = mujoco.MjData(model)  # a step towards the closed hand: which way each link leads
    for name, start, end in zip(dims.joint_names(), dims.open_pose(), dims.closed_pose(), strict=True):
        closing.qpos[model.joint(name).qposadr[0]] = start + CLOSING_STEP * (end - start)
    mujoco.mj_kinematics(model, closing)
    solid = [g for g in range(model.ngeom) if model.geom_contype[g]]  # not the touch probe
    last_links = set(dims.fingertips())
    patches = []
    for link in dims.link_names():
        body = model.body(link).id
        for geom in (g for g in solid if model.geom_bodyid[g] == body):
            region = "palm" if link == "palm" else "tip" if link in last_links else "pulp"
            to_link = _geom_in_link(model, geom)
            if model.geom_type[geom] == mujoco.mjtGeom.mjGEOM_MESH:
                hull = _hull(model, geom, to_link)
                sides = _mesh_sides(hull, region, data, closing, body)
                points, normals, area_of = _mesh_candidates(hull, sides)
                cell = 0.0
            else:
                points, normals, cell = _candidates(model, geom, palm=link == "palm")
                points, normals = points @ to_link[:3, :3].T + to_link[:3, 3], normals @ to_link[:3, :3].T
                area_of = None
            keep = _clear_of_others(model, data, body, geom, solid, points)
            if keep.any():
                on_lattice = micrometres(points[keep]) / MICROMETRES_PER_M
                # fsum: one correctly rounded area whatever the order (the share-out compares them)
                area = cell * int(keep.sum()) if area_of is None else math.fsum(area_of[keep])
                patches.append(Patch(link, region, on_lattice, normals[keep], area))
    return patches


def micrometres(points: Array) -> npt.NDArray[np.int64]:
    """Positions in metres as whole micrometres."""
    return np.rint(points * MICROMETRES_PER_M).astype(np.int64)


def share_out(total: int, areas: list[float]) -> list[int]:
    """`total` split in proportion to `areas`, rounded by largest remainder (ties: first patch).

    In exact rational arithmetic: patches of equal area (the same link on two fingers) tie exactly,
    and a float sum taken in a SIMD order could break the tie differently on another CPU."""
    exact = [Fraction(total) * Fraction(area) / sum(map(Fraction, areas)) for area in areas]
    counts = [math.floor(share) for share in exact]
    order = sorted(range(len(areas)), key=lambda i: exact[i] - counts[i], reverse=True)  # stable
    for i in order[: total - sum(counts)]:
        counts[i] += 1
    return counts


def farthest_points(points: Array, count: int) -> npt.NDArray[np.intp]:
    """`count` indices of `points`, greedily each farthest from those already picked, starting
    from the point nearest the centroid (rounded to the micrometre).

    On whole micrometres in 64-bit integers, where squared distances are exact: candidates on
    symmetric surfaces tie exactly, and the tie goes to the lowest index on every CPU."""
    if count <= 0:
        return np.zeros(0, dtype=np.intp)
    lattice = micrometres(points)
    centroid = lattice.sum(axis=0) // len(lattice)
    first = int(np.argmin(((lattice - centroid) ** 2).sum(axis=1)))  # argmin/argmax: first of ties
    chosen = [first]
    nearest = ((lattice - lattice[first]) ** 2).sum(axis=1)
    for _ in range(count - 1):
        pick = int(np.argmax(nearest))
        chosen.append(pick)
        nearest = np.minimum(nearest, ((lattice - lattice[pick]) ** 2).sum(axis=1))
    return np.array(chosen, dtype=np.intp)


def _candidates(model: mujoco.MjModel, geom: int, palm: bool) -> tuple[Array, Array, float]:
    """Candidate points and outward normals in the geom's frame, and the area of one candidate."""
    kind, size = model.geom_type[geom], model.geom_size[geom]
    palmar = np.array([0.0, 0.0, 1.0]) if palm else np.array([1.0, 0.0, 0.0])
    palmar = _geom_in_link(model, geom)[:3, :3].T @ palmar  # the palmar direction, geom frame
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        return _box_face(size, palmar)
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        return _capsule_side(size[0], size[1], palmar)
    if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        return _dome(size[0], palmar)
    name = mujoco.mjtGeom(int(kind)).name.removeprefix("mjGEOM_").lower()
    raise ValueError(
        f"no taxel sampling for a {name} geom (body {model.body(int(model.geom_bodyid[geom])).name!r}): the "
        "generator lays taxels on boxes, capsules, spheres and meshes; give this hand a layout of its "
        "own (docs/hands.md, taxel layout)"
    )


@dataclass(frozen=True)
class Hull:
    """A colliding mesh geom's convex hull as MuJoCo compiled it, in its link's frame: vertices,
    triangles and their outward unit normals."""

    vertices: Array
    faces: npt.NDArray[np.int64]
    normals: Array


def _hull(model: mujoco.MjModel, geom: int, pose: Array) -> Hull:
    """The convex hull MuJoCo collides with for mesh `geom` (`mesh_graph`: numvert, numface, then
    vert_edgeadr, vert_globalid, edge_localid and face_globalid), moved by the 4×4 `pose` from the
    geom's frame (the link's: `_geom_in_link`; the geom's own: the identity)."""
    mesh = int(model.geom_dataid[geom])
    adr = int(model.mesh_graphadr[mesh])
    if adr < 0:
        body = model.body(int(model.geom_bodyid[geom])).name
        raise ValueError(f"mesh geom {geom} of body {body!r} has no convex hull to lay taxels on")
    graph = model.mesh_graph
    nv, nf = int(graph[adr]), int(graph[adr + 1])
    start = adr + 2 + 2 * nv + (nv + 3 * nf)  # edge_localid: each vertex's edges, -1 ended
    faces = np.asarray(graph[start : start + 3 * nf], dtype=np.int64).reshape(nf, 3)
    first, count = int(model.mesh_vertadr[mesh]), int(model.mesh_vertnum[mesh])
    vertices = np.asarray(model.mesh_vert[first : first + count], dtype=np.float64)
    vertices = vertices @ pose[:3, :3].T + pose[:3, 3]
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    normals = np.cross(b - a, c - a)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    inward = np.einsum("ij,ij->i", normals, a - vertices[np.unique(faces)].mean(axis=0)) < 0
    normals[inward] *= -1.0
    faces[inward] = faces[inward][:, ::-1]
    return Hull(vertices, faces, normals)


def _mesh_sides(
    hull: Hull, region: str, data: mujoco.MjData, closing: mujoco.MjData, body: int
) -> npt.NDArray[np.bool_]:
    """Which hull faces the skin covers (module docstring): facing the palm normal on the palm,
    facing the link's closing motion on a finger link, and its length too on a fingertip."""
    if region == "palm":
        return hull.normals @ np.array([0.0, 0.0, 1.0]) >= MESH_FACING_COS
    centroid = hull.vertices[np.unique(hull.faces)].mean(axis=0)
    moved = (closing.xmat[body].reshape(3, 3) @ centroid + closing.xpos[body]) - (
        data.xmat[body].reshape(3, 3) @ centroid + data.xpos[body]
    )
    if np.linalg.norm(moved) < STILL_M * CLOSING_STEP:
        return np.zeros(len(hull.faces), dtype=bool)
    lead = data.xmat[body].reshape(3, 3).T @ moved  # in the link's frame (open pose)
    sides = hull.normals @ (lead / np.linalg.norm(lead)) >= MESH_FACING_COS
    if region == "tip" and np.linalg.norm(centroid) > 0.0:
        sides |= hull.normals @ (centroid / np.linalg.norm(centroid)) >= MESH_FACING_COS
    return sides


def _mesh_candidates(hull: Hull, sides: npt.NDArray[np.bool_]) -> tuple[Array, Array, Array]:
    """Candidates on the chosen hull faces (link frame): each face cut into n×n equal triangles, n
    from its area, their centroids; the area each stands for; none within EDGE_MARGIN of the
    border of the chosen faces."""
    points, normals, areas = [], [], []
    for face in np.flatnonzero(sides):
        a, b, c = hull.vertices[hull.faces[face]]
        area = 0.5 * float(np.linalg.norm(np.cross(b - a, c - a)))
        n = max(1, math.ceil(math.sqrt(2.0 * area) / SPACING))
        i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
        up = (i + j) <= n - 1
        down = (i + j) <= n - 2
        u = np.concatenate([(i[up] + 1 / 3) / n, (i[down] + 2 / 3) / n])
        v = np.concatenate([(j[up] + 1 / 3) / n, (j[down] + 2 / 3) / n])
        points.append(a + u[:, None] * (b - a) + v[:, None] * (c - a))
        normals.append(np.broadcast_to(hull.normals[face], (len(u), 3)))
        areas.append(np.full(len(u), area / (n * n)))
    if not points:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)
    p, nrm, w = np.vstack(points), np.vstack(normals), np.concatenate(areas)
    keep = _distance_to_segments(p, _border(hull, sides)) >= EDGE_MARGIN
    return p[keep], nrm[keep], w[keep]


def _border(hull: Hull, sides: npt.NDArray[np.bool_]) -> Array:
    """The chosen faces' border: edges of a chosen face whose other face is not chosen, as
    (m, 2, 3) end points."""
    chosen: dict[tuple[int, int], int] = {}
    for face in np.flatnonzero(sides):
        tri = hull.faces[face]
        for k in range(3):
            edge = (int(min(tri[k], tri[(k + 1) % 3])), int(max(tri[k], tri[(k + 1) % 3])))
            chosen[edge] = chosen.get(edge, 0) + 1
    border = [edge for edge, uses in chosen.items() if uses == 1]
    if not border:
        return np.zeros((0, 2, 3))
    return hull.vertices[np.array(border)]


def _distance_to_segments(points: Array, segments: Array) -> Array:
    """Each point's distance to the nearest segment (inf with none)."""
    nearest = np.full(len(points), np.inf)
    for start, end in segments:
        along = end - start
        t = np.clip((points - start) @ along / float(along @ along), 0.0, 1.0)
        nearest = np.minimum(nearest, np.linalg.norm(points - (start + t[:, None] * along), axis=1))
    return nearest


def _box_face(half: Array, outward: Array) -> tuple[Array, Array, float]:
    axis = int(np.argmax(np.abs(outward)))
    u, v = (a for a in range(3) if a != axis)
    grid_u = _grid(-half[u] + EDGE_MARGIN, half[u] - EDGE_MARGIN)
    grid_v = _grid(-half[v] + EDGE_MARGIN, half[v] - EDGE_MARGIN)
    gu, gv = np.meshgrid(grid_u, grid_v, indexing="ij")
    points = np.zeros((gu.size, 3))
    points[:, u], points[:, v] = gu.ravel(), gv.ravel()
    points[:, axis] = math.copysign(half[axis], outward[axis])
    normals = np.zeros_like(points)
    normals[:, axis] = math.copysign(1.0, outward[axis])
    return points, normals, SPACING**2


def _capsule_side(radius: float, half_length: float, palmar: Array) -> tuple[Array, Array, float]:
    """The half of the cylindrical side facing `palmar` (perpendicular to the capsule's +z)."""
    reach = math.pi / 2 - EDGE_MARGIN / radius
    angles = _grid(-reach * radius, reach * radius) / radius
    heights = _grid(-half_length + EDGE_MARGIN, half_length - EDGE_MARGIN)
    ga, gz = np.meshgrid(angles, heights, indexing="ij")
    base = palmar / np.linalg.norm(palmar)
    side = np.cross([0.0, 0.0, 1.0], base)
    normals = np.cos(ga.ravel())[:, None] * base + np.sin(ga.ravel())[:, None] * side
    points = radius * normals + gz.ravel()[:, None] * np.array([0.0, 0.0, 1.0])
    return points, normals, SPACING**2


def _dome(radius: float, palmar: Array) -> tuple[Array, Array, float]:
    """Fingertip sphere: the half towards the finger's end (+z) and a palmar band below it."""
    count = max(1, round(4 * math.pi * radius**2 / SPACING**2))
    k = np.arange(count) + 0.5
    z = 1.0 - 2.0 * k / count  # cos(polar angle): a Fibonacci lattice, even area per point
    ring = np.sqrt(1.0 - z * z)  # sqrt is exact-rounded on every CPU; arccos is not
    azimuth = math.pi * (1.0 + math.sqrt(5.0)) * k
    normals = np.column_stack([ring * np.cos(azimuth), ring * np.sin(azimuth), z])
    margin = EDGE_MARGIN / radius
    palmar_side = normals @ palmar > math.sin(margin)
    # polar <= 90° - margin, or on the palmar side polar <= TIP_PALMAR_POLAR - margin
    keep = (z >= math.sin(margin)) | (palmar_side & (z >= math.cos(TIP_PALMAR_POLAR - margin)))
    return radius * normals[keep], normals[keep], 4 * math.pi * radius**2 / count


def _grid(low: float, high: float) -> Array:
    steps = max(0, math.floor((high - low) / SPACING))
    centre = (low + high) / 2
    return centre + (np.arange(steps + 1) - steps / 2) * SPACING


def _geom_in_link(model: mujoco.MjModel, geom: int) -> Array:
    """4×4 pose of a geom in its body's frame."""
    rotation = np.zeros(9)
    mujoco.mju_quat2Mat(rotation, model.geom_quat[geom])
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rotation.reshape(3, 3), model.geom_pos[geom]
    return pose


def _clear_of_others(
    model: mujoco.MjModel, data: mujoco.MjData, body: int, geom: int, solid: list[int], points: Array
) -> npt.NDArray[np.bool_]:
    """Which link-frame `points` lie at least CLEARANCE outside every other hand geom, in whole
    nanometres: a fingertip dome lies exactly CLEARANCE outside the capsule end it swallows, and
    compared as floats, last-bit noise would keep or drop each of its points."""
    rotation, origin = data.xmat[body].reshape(3, 3), data.xpos[body]
    world = points @ rotation.T + origin
    keep = np.ones(len(points), dtype=bool)
    clearance_nm = round(CLEARANCE * NANOMETRES_PER_M)
    for other in solid:
        if other == geom:
            continue
        local = (world - data.geom_xpos[other]) @ data.geom_xmat[other].reshape(3, 3)
        if model.geom_type[other] == mujoco.mjtGeom.mjGEOM_MESH:
            hull = _hull(model, other, np.eye(4))
            # Beyond the hull's bounding sphere by the clearance a point is clear: no planes needed.
            reach = float(np.linalg.norm(hull.vertices, axis=1).max()) + 2 * CLEARANCE
            near = np.linalg.norm(local, axis=1) < reach
            distance = np.full(len(local), reach)
            distance[near] = hull_distance(hull, local[near])
        else:
            distance = signed_distance(int(model.geom_type[other]), model.geom_size[other], local)
        keep &= np.rint(distance * NANOMETRES_PER_M) >= clearance_nm
    return keep


def hull_distance(hull: Hull, local: Array) -> Array:
    """The largest signed distance of geom-frame points to a convex hull's face planes: exact
    inside and where a face is nearest, below the true distance near an edge or corner outside."""
    offsets = np.einsum("ij,ij->i", hull.normals, hull.vertices[hull.faces[:, 0]])
    distance: Array = (local @ hull.normals.T - offsets).max(axis=1)
    return distance


def signed_distance(kind: int, size: Array, local: Array) -> Array:
    """Signed distance of geom-frame points to a box, sphere or capsule (negative inside)."""
    if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        return np.linalg.norm(local, axis=1) - size[0]
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        along = np.clip(local[:, 2], -size[1], size[1])
        return np.linalg.norm(local - along[:, None] * np.array([0.0, 0.0, 1.0]), axis=1) - size[0]
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        q = np.abs(local) - size[:3]
        return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)
    raise ValueError(f"no signed distance for geom type {kind}")
