"""The hands vint models, built into an `MjSpec` from named dimensions.

`trx3` is a three-finger hand (our own model, loosely Barrett-like): a palm box with two fingers on
one edge and an opposing thumb on the other. Each finger is three hinge links (capsules) ending in a
round fingertip; all three hinges of a finger curl in one plane, so a closing hand wraps around an
upright cylinder. The palm is a free body welded to a mocap target (the "arm"), and hand bodies are
gravity-compensated, as a real arm controller would do.

Palm frame: +z is the palm normal (fingers grow along it), +y is "up" across the palm, +x points
from the two-finger edge to the thumb edge. Links are named `palm`, `f{i}_prox`, `f{i}_mid`,
`f{i}_tip`; joints `f{i}_j{k}` (k = 0 proximal … 2 distal).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from vint_engines.protocol import BadInput

# Collision filtering: hand geoms collide with the object and the ground but never with each other.
HAND_CONTYPE, HAND_CONAFFINITY = 2, 1
WORLD_CONTYPE, WORLD_CONAFFINITY = 1, 1

FINGER_LINKS = ("prox", "mid", "tip")


@dataclass(frozen=True)
class FingerBase:
    """Where a finger leaves the palm face (palm frame) and which way it curls (+1: towards +x)."""

    x: float
    y: float
    curl: float
    strength: float  # scales the actuator force limits (the thumb opposes two fingers)


@dataclass(frozen=True)
class HandDims:
    name: str
    palm_half: tuple[float, float, float]
    palm_mass: float
    link_lengths: tuple[float, float, float]
    link_masses: tuple[float, float, float]
    link_radius: float
    tip_radius: float
    tip_mass: float
    fingers: tuple[FingerBase, ...]
    joint_ranges: tuple[tuple[float, float], tuple[float, float], tuple[float, float]]
    armature: float
    damping: float
    kp: float
    torque_limits: tuple[float, float, float]  # N·m per joint of a strength-1 finger
    open_pose: tuple[float, float, float]
    closed_pose: tuple[float, float, float]  # position targets while grasping (beyond contact)

    @property
    def dof(self) -> int:
        return 3 * len(self.fingers)

    def joint_names(self) -> list[str]:
        return [f"f{i}_j{k}" for i in range(len(self.fingers)) for k in range(3)]

    def link_names(self) -> list[str]:
        return ["palm", *(f"f{i}_{link}" for i in range(len(self.fingers)) for link in FINGER_LINKS)]


TRX3 = HandDims(
    name="trx3",
    palm_half=(0.055, 0.035, 0.012),
    palm_mass=0.30,
    link_lengths=(0.045, 0.035, 0.025),
    link_masses=(0.045, 0.030, 0.020),
    link_radius=0.009,
    tip_radius=0.010,
    tip_mass=0.008,
    fingers=(
        FingerBase(x=-0.047, y=0.022, curl=1.0, strength=1.0),
        FingerBase(x=-0.047, y=-0.022, curl=1.0, strength=1.0),
        FingerBase(x=0.047, y=0.0, curl=-1.0, strength=2.0),
    ),
    joint_ranges=((-0.5, 1.6), (0.0, 1.9), (0.0, 1.7)),
    armature=0.002,
    damping=0.08,
    kp=6.0,
    torque_limits=(0.8, 0.6, 0.4),
    open_pose=(-0.25, 0.1, 0.1),
    closed_pose=(1.5, 1.8, 1.6),
)

HANDS: dict[str, HandDims] = {TRX3.name: TRX3}


def hand_dims(name: str) -> HandDims:
    try:
        return HANDS[name]
    except KeyError:
        raise BadInput(f"params.hand.name: unknown hand {name!r} (known: {sorted(HANDS)})") from None


def add_hand(spec: mujoco.MjSpec, dims: HandDims) -> None:
    """Add the mocap target `hand_target`, the welded palm and the fingers with their actuators."""
    spec.worldbody.add_body(name="hand_target", mocap=True)
    palm = spec.worldbody.add_body(name="palm", gravcomp=1.0)
    palm.add_freejoint(name="hand_free")
    palm.add_geom(
        name="palm",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=list(dims.palm_half),
        mass=dims.palm_mass,
        contype=HAND_CONTYPE,
        conaffinity=HAND_CONAFFINITY,
    )
    for i, base in enumerate(dims.fingers):
        _add_finger(spec, palm, dims, i, base)
    spec.add_equality(
        type=mujoco.mjtEq.mjEQ_WELD,
        name="arm",
        name1="hand_target",
        name2="palm",
        objtype=mujoco.mjtObj.mjOBJ_BODY,
        solref=[0.01, 1.0],
    )


def _add_finger(spec: mujoco.MjSpec, palm: mujoco.MjsBody, dims: HandDims, i: int, base: FingerBase) -> None:
    parent = palm
    pos = [base.x, base.y, dims.palm_half[2]]
    axis = [0.0, base.curl, 0.0]  # rotating +z about +y moves a fingertip towards +x
    for k, link in enumerate(FINGER_LINKS):
        length = dims.link_lengths[k]
        body = parent.add_body(name=f"f{i}_{link}", pos=pos, gravcomp=1.0)
        body.add_joint(
            name=f"f{i}_j{k}",
            type=mujoco.mjtJoint.mjJNT_HINGE,
            axis=axis,
            range=list(dims.joint_ranges[k]),
            limited=mujoco.mjtLimited.mjLIMITED_TRUE,
            armature=dims.armature,
            damping=dims.damping,
        )
        body.add_geom(
            name=f"f{i}_{link}",
            type=mujoco.mjtGeom.mjGEOM_CAPSULE,
            size=[dims.link_radius, length / 2, 0.0],
            pos=[0.0, 0.0, length / 2],
            mass=dims.link_masses[k],
            contype=HAND_CONTYPE,
            conaffinity=HAND_CONAFFINITY,
        )
        torque = dims.torque_limits[k] * base.strength
        actuator = spec.add_actuator(
            name=f"f{i}_a{k}",
            target=f"f{i}_j{k}",
            trntype=mujoco.mjtTrn.mjTRN_JOINT,
            forcelimited=mujoco.mjtLimited.mjLIMITED_TRUE,
            forcerange=[-torque, torque],
            ctrllimited=mujoco.mjtLimited.mjLIMITED_TRUE,
            ctrlrange=list(dims.joint_ranges[k]),
        )
        actuator.set_to_position(kp=dims.kp * base.strength)
        parent, pos = body, [0.0, 0.0, length]
    parent.add_geom(
        name=f"f{i}_tip_pad",
        type=mujoco.mjtGeom.mjGEOM_SPHERE,
        size=[dims.tip_radius, 0.0, 0.0],
        pos=[0.0, 0.0, dims.link_lengths[2]],
        mass=dims.tip_mass,
        contype=HAND_CONTYPE,
        conaffinity=HAND_CONAFFINITY,
    )


def palm_frame_facing(direction: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Rotation (palm → world) whose palm normal (+z) is `direction` and whose +y is `up`."""
    z = direction / np.linalg.norm(direction)
    y = up - np.dot(up, z) * z
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    return np.column_stack([x, y, z])
