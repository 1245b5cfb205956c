"""The physics scene of a grasp: one object and one hand in free space, compiled once and cached.

There is no ground: after VinT-Sim, the object is placed in a predetermined pose (a random
orientation at the world origin, `trial.py`), held there while the hand approaches and closes, then
released to the hand. The renderer draws no ground either.

Object frame convention (shared with the renderer and the model PLY; see `vint_engines.objects`):
the body origin is the centre of the object's bounding box, cylinders and revolved shapes have
their axis along the body's +z. The object collides through its convex pieces (MuJoCo primitives
or mesh hulls) and carries its catalog mass with the inertia of its uniform-density mesh.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from vint_engines import hand_meshes as hand_mesh_codec
from vint_engines.grasp.hand import HAND_MESH_PREFIX, WORLD_CONAFFINITY, WORLD_CONTYPE, GraspHand, add_hand
from vint_engines.grasp.surface import ObjectSurface
from vint_engines.objects import MODEL_FILE, ObjectModel, ObjectSpec, build_model
from vint_engines.poses import matrix_to_quat

__all__ = [
    "GraspScene",
    "ObjectSpec",
    "SceneObject",
    "build_scene",
    "hand_geometry",
    "hand_meshes",
    "object_record",
    "write_object_model",
]


@dataclass(frozen=True, eq=False)
class SceneObject:
    """The object as a trial sees it: its model and its surface (`surface.py`)."""

    model: ObjectModel
    surface: ObjectSurface

    @property
    def spec(self) -> ObjectSpec:
        return self.model.spec

    @property
    def name(self) -> str:
        return self.model.spec.name


@dataclass(frozen=True)
class GraspScene:
    """A compiled model plus the ids a trial needs."""

    model: mujoco.MjModel
    hand: GraspHand
    obj: SceneObject
    object_body: int
    object_geoms: tuple[int, ...]
    object_qpos: int
    palm_body: int
    palm_qpos: int
    mocap: int
    link_bodies: dict[str, int]
    joint_qpos: dict[str, int]
    joint_ctrl: dict[str, int]
    # As compiled: a trial's physics overrides (`trial.configure`) start from these every time, so
    # trials stay independent of the order they run in on one cached scene.
    hand_geoms: tuple[int, ...] = ()
    object_mass: float = 0.0
    object_inertia: tuple[float, float, float] = (0.0, 0.0, 0.0)
    actuator_forcerange: tuple[tuple[float, float], ...] = ()

    def link_of_geom(self, geom: int) -> str | None:
        """The hand link owning `geom`, or None for non-hand geoms."""
        body = int(self.model.geom_bodyid[geom])
        name = self.model.body(body).name
        return name if name in self.link_bodies else None


def build_scene(hand: GraspHand, obj: ObjectSpec, object_model: ObjectModel | None = None) -> GraspScene:
    """Compile the scene; `object_model` is the object's built model when the caller caches them."""
    built = object_model if object_model is not None else build_model(obj)
    placed = SceneObject(built, ObjectSurface.of(built.mesh))
    spec = mujoco.MjSpec()
    spec.modelname = f"{hand.name}_{obj.name}"
    spec.compiler.degree = False  # MjSpec defaults to degrees; every angle here is in radians
    opt = spec.option
    opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    opt.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    opt.impratio = 10.0
    opt.jacobian = mujoco.mjtJacobian.mjJAC_DENSE
    add_object(spec, placed.model)
    add_hand(spec, hand)
    model = spec.compile()
    object_body = model.body("object").id
    hand_bodies = [model.body(name).id for name in hand.link_names()]

    def qpos_of(joint: str) -> int:
        return int(model.jnt_qposadr[model.joint(joint).id])

    return GraspScene(
        model=model,
        hand=hand,
        obj=placed,
        object_body=model.body("object").id,
        object_geoms=tuple(int(g) for g in np.flatnonzero(model.geom_bodyid == model.body("object").id)),
        object_qpos=qpos_of("object_free"),
        palm_body=model.body("palm").id,
        palm_qpos=qpos_of("hand_free"),
        mocap=int(model.body_mocapid[model.body("hand_target").id]),
        link_bodies={name: model.body(name).id for name in hand.link_names()},
        joint_qpos={name: qpos_of(name) for name in hand.joint_names()},
        joint_ctrl={model.joint(int(model.actuator_trnid[a, 0])).name: a for a in range(model.nu)},
        hand_geoms=tuple(
            int(g)
            for g in np.flatnonzero(np.isin(model.geom_bodyid, hand_bodies))
            if model.geom_contype[g] or model.geom_conaffinity[g]  # a user hand's visual geoms feel nothing
        ),
        object_mass=float(model.body_mass[object_body]),
        object_inertia=tuple(float(v) for v in model.body_inertia[object_body]),
        actuator_forcerange=tuple((float(lo), float(hi)) for lo, hi in model.actuator_forcerange),
    )


def add_object(spec: mujoco.MjSpec, model: ObjectModel) -> None:
    """The free body `object` at the origin (each trial places it): one geom per convex piece
    (`object_{i}`; hulls are meshes `object_piece_{i}`), the catalog mass and the mesh's inertia."""
    body = spec.worldbody.add_body(name="object")
    body.add_freejoint(name="object_free")
    body.explicitinertial = True
    body.mass = model.spec.mass
    body.ipos = [float(v) for v in model.centroid]
    inertia = model.inertia
    body.fullinertia = [float(v) for v in (*np.diag(inertia), inertia[0, 1], inertia[0, 2], inertia[1, 2])]
    for i, piece in enumerate(model.pieces):
        collision = {"name": f"object_{i}", "contype": WORLD_CONTYPE, "conaffinity": WORLD_CONAFFINITY}
        if piece.kind == "hull":
            mesh = spec.add_mesh(name=f"object_piece_{i}", uservert=piece.points.ravel().tolist())
            mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL  # unused: the body's is explicit
            body.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname=mesh.name, **collision)
            continue
        kind = mujoco.mjtGeom.mjGEOM_BOX if piece.kind == "box" else mujoco.mjtGeom.mjGEOM_CYLINDER
        body.add_geom(
            type=kind,
            size=[*piece.size, 0.0][:3],
            pos=[float(v) for v in piece.pose[:3, 3]],
            quat=[float(v) for v in matrix_to_quat(piece.pose[:3, :3])],
            **collision,
        )


def object_record(scene: GraspScene, entry: Mapping[str, Any]) -> dict[str, Any]:
    """grasps.json's `object`: the entry as the task gave it, plus its model file's description."""
    return {**entry, "model": scene.obj.model.record()}


def write_object_model(scene: GraspScene, out_dir: Path) -> Path:
    """Write the object's model mesh (`object.ply`, millimetres) into `out_dir`."""
    path = out_dir / MODEL_FILE
    path.write_bytes(scene.obj.model.ply())
    return path


def hand_geometry(scene: GraspScene) -> list[dict[str, Any]]:
    """Every hand link's geoms as compiled (MuJoCo size convention, pose in the link frame). A
    user's hand may add mesh geoms (`"mesh"`: a key of `hand_meshes`) and visual geoms (`"visual":
    true`, in no contact); those carry their colour (`"rgba"`, the material's when they have one)."""
    model = scene.model
    sizes = {
        mujoco.mjtGeom.mjGEOM_BOX: 3,
        mujoco.mjtGeom.mjGEOM_SPHERE: 1,
        mujoco.mjtGeom.mjGEOM_CAPSULE: 2,
        mujoco.mjtGeom.mjGEOM_CYLINDER: 2,
    }
    keys = _hand_mesh_data(scene)[0]
    links = []
    for name, body in scene.link_bodies.items():
        geoms = []
        for geom in np.flatnonzero(model.geom_bodyid == body):
            kind = mujoco.mjtGeom(int(model.geom_type[geom]))
            record: dict[str, Any] = {"type": kind.name.removeprefix("mjGEOM_").lower()}
            if kind == mujoco.mjtGeom.mjGEOM_MESH:
                record["mesh"] = keys[int(model.geom_dataid[geom])]
            else:
                record["size"] = [float(v) for v in model.geom_size[geom][: sizes[kind]]]
            record["p"] = [float(v) for v in model.geom_pos[geom]]
            record["q"] = [float(v) for v in model.geom_quat[geom]]
            visual = not model.geom_contype[geom] and not model.geom_conaffinity[geom]
            if visual:
                record["visual"] = True
            if visual or kind == mujoco.mjtGeom.mjGEOM_MESH:
                record["rgba"] = [float(v) for v in model.geom_rgba[geom]]
            geoms.append(record)
        links.append({"name": name, "geoms": geoms})
    return links


def hand_meshes(scene: GraspScene) -> dict[str, dict[str, Any]]:
    """The meshes a user's hand geoms name (`hand_geometry`), each once by a key of its content
    (a visual and a collision mesh from one file, or four fingers' copies, are one): vertices (m,
    the mesh frame MuJoCo compiled) and triangles, encoded as `vint_engines.hand_meshes` says.
    Empty for primitive hands."""
    return _hand_mesh_data(scene)[1]


def _hand_mesh_data(scene: GraspScene) -> tuple[dict[int, str], dict[str, dict[str, Any]]]:
    """Each hand mesh id's content key, and each key's encoded mesh."""
    model = scene.model
    keys: dict[int, str] = {}
    meshes: dict[str, dict[str, Any]] = {}
    for m in range(model.nmesh):
        if not model.mesh(m).name.startswith(HAND_MESH_PREFIX):
            continue
        first, count = int(model.mesh_vertadr[m]), int(model.mesh_vertnum[m])
        face_first, face_count = int(model.mesh_faceadr[m]), int(model.mesh_facenum[m])
        vertices = model.mesh_vert[first : first + count].astype("<f4")
        faces = model.mesh_face[face_first : face_first + face_count].astype("<u4")
        key = "mesh_" + hashlib.sha256(vertices.tobytes() + faces.tobytes()).hexdigest()[:16]
        keys[m] = key
        if key not in meshes:
            meshes[key] = hand_mesh_codec.encode(vertices, faces)
    return keys, meshes


def geom_distance(model: mujoco.MjModel, data: mujoco.MjData, geom1: int, geom2: int, cap: float) -> float:
    """`mj_geomDistance`, asked again of libccd when MuJoCo's native CCD answers exactly 0: it
    does so for some convex mesh pairs centimetres apart (MuJoCo issue #3383; here a palm 5 cm
    from a mug's hull pieces), which stopped the hand's slide far short of its standoff."""
    distance = mujoco.mj_geomDistance(model, data, geom1, geom2, cap, None)
    if distance != 0.0:
        return distance
    native = int(mujoco.mjtDisableBit.mjDSBL_NATIVECCD)
    flags = model.opt.disableflags
    model.opt.disableflags = flags | native
    try:
        return mujoco.mj_geomDistance(model, data, geom1, geom2, cap, None)
    finally:
        model.opt.disableflags = flags
