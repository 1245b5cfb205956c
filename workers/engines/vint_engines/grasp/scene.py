"""The physics scene of a grasp: ground plane, one object, one hand, compiled once and cached.

Object frame convention (shared with the renderer): the body origin is the object's centre; a
`cylinder` has its axis along the body's +z.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from vint_engines import params as P
from vint_engines.grasp.hand import WORLD_CONAFFINITY, WORLD_CONTYPE, HandDims, add_hand
from vint_engines.protocol import BadInput

SHAPES = ("cylinder",)


@dataclass(frozen=True)
class ObjectSpec:
    name: str
    shape: str
    radius: float
    height: float
    mass: float

    @staticmethod
    def parse(obj: Mapping[str, Any]) -> ObjectSpec:
        where = "params.object"
        shape = P.string(obj, "shape", where)
        if shape not in SHAPES:
            raise BadInput(f"{where}.shape: unsupported shape {shape!r} (supported: {list(SHAPES)})")
        return ObjectSpec(
            name=P.string(obj, "name", where),
            shape=shape,
            radius=P.number(obj, "radius", where, low=0.005, high=0.2),
            height=P.number(obj, "height", where, low=0.01, high=0.5),
            mass=P.number(obj, "mass", where, low=0.001, high=5.0),
        )

    @property
    def rest_height(self) -> float:
        """Height of the object's centre when it stands upright on the ground."""
        return self.height / 2


@dataclass(frozen=True)
class GraspScene:
    """A compiled model plus the ids a trial needs."""

    model: mujoco.MjModel
    hand: HandDims
    obj: ObjectSpec
    object_body: int
    object_qpos: int
    palm_body: int
    palm_qpos: int
    mocap: int
    link_bodies: dict[str, int]
    joint_qpos: dict[str, int]
    joint_ctrl: dict[str, int]

    def link_of_geom(self, geom: int) -> str | None:
        """The hand link owning `geom`, or None for non-hand geoms."""
        body = int(self.model.geom_bodyid[geom])
        name = self.model.body(body).name
        return name if name in self.link_bodies else None


def build_scene(hand: HandDims, obj: ObjectSpec) -> GraspScene:
    spec = mujoco.MjSpec()
    spec.modelname = f"{hand.name}_{obj.name}"
    spec.compiler.degree = False  # MjSpec defaults to degrees; every angle here is in radians
    opt = spec.option
    opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    opt.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    opt.impratio = 10.0
    opt.jacobian = mujoco.mjtJacobian.mjJAC_DENSE
    spec.worldbody.add_geom(
        name="ground",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[1.0, 1.0, 0.05],
        contype=WORLD_CONTYPE,
        conaffinity=WORLD_CONAFFINITY,
    )
    body = spec.worldbody.add_body(name="object", pos=[0.0, 0.0, obj.rest_height])
    body.add_freejoint(name="object_free")
    body.add_geom(
        name="object",
        type=mujoco.mjtGeom.mjGEOM_CYLINDER,
        size=[obj.radius, obj.height / 2, 0.0],
        mass=obj.mass,
        contype=WORLD_CONTYPE,
        conaffinity=WORLD_CONAFFINITY,
    )
    add_hand(spec, hand)
    model = spec.compile()

    def qpos_of(joint: str) -> int:
        return int(model.jnt_qposadr[model.joint(joint).id])

    return GraspScene(
        model=model,
        hand=hand,
        obj=obj,
        object_body=model.body("object").id,
        object_qpos=qpos_of("object_free"),
        palm_body=model.body("palm").id,
        palm_qpos=qpos_of("hand_free"),
        mocap=int(model.body_mocapid[model.body("hand_target").id]),
        link_bodies={name: model.body(name).id for name in hand.link_names()},
        joint_qpos={name: qpos_of(name) for name in hand.joint_names()},
        joint_ctrl={name: model.actuator(name.replace("_j", "_a")).id for name in hand.joint_names()},
    )


def hand_geometry(scene: GraspScene) -> list[dict[str, Any]]:
    """Every hand link's geoms as compiled (MuJoCo size convention, pose in the link frame)."""
    model = scene.model
    sizes = {
        mujoco.mjtGeom.mjGEOM_BOX: 3,
        mujoco.mjtGeom.mjGEOM_SPHERE: 1,
        mujoco.mjtGeom.mjGEOM_CAPSULE: 2,
        mujoco.mjtGeom.mjGEOM_CYLINDER: 2,
    }
    links = []
    for name, body in scene.link_bodies.items():
        geoms = []
        for geom in np.flatnonzero(model.geom_bodyid == body):
            kind = mujoco.mjtGeom(int(model.geom_type[geom]))
            geoms.append(
                {
                    "type": kind.name.removeprefix("mjGEOM_").lower(),
                    "size": [float(v) for v in model.geom_size[geom][: sizes[kind]]],
                    "p": [float(v) for v in model.geom_pos[geom]],
                    "q": [float(v) for v in model.geom_quat[geom]],
                }
            )
        links.append({"name": name, "geoms": geoms})
    return links
