"""Builds a hand (`hands/`) into an `MjSpec`: palm, fingers, actuators, the arm weld, a touch probe.

The palm is a free body welded to a mocap target (the "arm"), and hand bodies are
gravity-compensated, as a real arm controller would do. Each link is a capsule with an explicit
mass (MuJoCo infers its inertia from the shape); the last link of a finger also carries the round
fingertip (`f{i}_tip_pad`). Every joint has armature, damping, a limited range and a position
actuator with a force limit (`forcerange`) and a control range equal to the joint range.

Frames and names are defined in `hands/model.py` (palm frame: +z palm normal, +y up across the
palm, +x finger edge → thumb edge). A user's MJCF hand (`hands/mjcf.py`) is copied from its
compiled model instead: the palm's subtree with its inertias, hinges and position actuators, every
geom given the skin; the arm weld and the touch probe are the same.
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from vint_engines.grasp.hands import ALLEGRO, TRX3, GraspHand, HandDims, MjcfHand, hand_dims
from vint_engines.grasp.hands.model import Finger, Vec3

__all__ = ["ALLEGRO", "TRX3", "GraspHand", "HandDims", "add_hand", "hand_dims"]

# Collision filtering: hand geoms collide with the object but never with each other.
HAND_CONTYPE, HAND_CONAFFINITY = 2, 1
WORLD_CONTYPE, WORLD_CONAFFINITY = 1, 1

# A collision-free sphere that the touch model (`touch.py`) moves onto each taxel to measure its
# distance to the object with `mj_geomDistance`; it takes part in no contact and carries no mass.
TOUCH_PROBE = "touch_probe"
TOUCH_PROBE_RADIUS = 1e-5

# The scene's copies of a user hand's meshes are named by this prefix and the mesh's id in the
# user's compiled model (`grasp/scene.py` reads them back for grasps.json).
HAND_MESH_PREFIX = "hand_mesh_"

# Every hand geom is covered by the tactile skin, whose contact parameters govern the hand's
# contacts (priority 1 over the object's): rubber-like friction and a stiff contact
# (time constant 5 ms, at least 2 timesteps), so a squeezed can sinks < 1 mm into the palm (MuJoCo's
# default 20 ms let it sink 6 mm under the fingers' 60 N). The skin's softness is the touch model's
# sensing depth instead (`touch.py`).
SKIN: dict[str, Any] = {
    "contype": HAND_CONTYPE,
    "conaffinity": HAND_CONAFFINITY,
    "priority": 1,
    "friction": [1.0, 0.005, 0.0001],
    "solref": [0.005, 1.0],
}

JOINT_AXES: dict[str, list[float]] = {"flex": [0.0, 1.0, 0.0], "abduct": [1.0, 0.0, 0.0]}


def add_hand(spec: mujoco.MjSpec, hand: GraspHand) -> None:
    """Add the mocap target `hand_target`, the welded palm, the fingers with their actuators and
    the touch probe."""
    spec.worldbody.add_body(name="hand_target", mocap=True)
    if isinstance(hand, MjcfHand):
        _add_mjcf_hand(spec, hand)
    else:
        assert isinstance(hand, HandDims)
        _add_built_in_hand(spec, hand)
    spec.add_equality(
        type=mujoco.mjtEq.mjEQ_WELD,
        name="arm",
        name1="hand_target",
        name2="palm",
        objtype=mujoco.mjtObj.mjOBJ_BODY,
        solref=[0.01, 1.0],
    )
    add_touch_probe(spec)


def _add_built_in_hand(spec: mujoco.MjSpec, dims: HandDims) -> None:
    palm = spec.worldbody.add_body(name="palm", gravcomp=1.0)
    palm.add_freejoint(name="hand_free")
    palm.add_geom(
        name="palm",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=list(dims.palm_half),
        mass=dims.palm_mass,
        **SKIN,
    )
    for i, finger in enumerate(dims.fingers):
        _add_finger(spec, palm, dims, i, finger)


def _add_mjcf_hand(spec: mujoco.MjSpec, hand: MjcfHand) -> None:
    """Copy the user's compiled hand: bodies (palm at the origin, with the arm's free joint),
    explicit inertias, primitive geoms with the skin, hinges, and position actuators."""
    model = hand.model
    added: dict[int, mujoco.MjsBody] = {}
    for b in hand.bodies():
        name = model.body(b).name
        if name == "palm":
            body = spec.worldbody.add_body(name="palm", gravcomp=1.0)
            body.add_freejoint(name="hand_free")
        else:
            parent = added[int(model.body_parentid[b])]
            body = parent.add_body(
                name=name, pos=list(model.body_pos[b]), quat=list(model.body_quat[b]), gravcomp=1.0
            )
        added[b] = body
        body.explicitinertial = True
        body.mass = float(model.body_mass[b])
        body.ipos = [float(v) for v in model.body_ipos[b]]
        body.iquat = [float(v) for v in model.body_iquat[b]]
        body.inertia = [float(v) for v in model.body_inertia[b]]
        for g in np.flatnonzero(model.geom_bodyid == b):
            _add_mjcf_geom(spec, body, model, int(g))
        for j in range(int(model.body_jntadr[b]), int(model.body_jntadr[b] + model.body_jntnum[b])):
            dof = int(model.jnt_dofadr[j])
            body.add_joint(
                name=model.joint(j).name,
                type=mujoco.mjtJoint.mjJNT_HINGE,
                axis=[float(v) for v in model.jnt_axis[j]],
                pos=[float(v) for v in model.jnt_pos[j]],
                range=[float(v) for v in model.jnt_range[j]],
                limited=mujoco.mjtLimited.mjLIMITED_TRUE,
                armature=float(model.dof_armature[dof]),
                damping=float(model.dof_damping[dof]),
                frictionloss=float(model.dof_frictionloss[dof]),
            )
    for j, joint in enumerate(hand.joints):
        a = hand.actuator_of(model.joint(joint).id)
        low, high = (float(v) for v in model.actuator_forcerange[a])
        actuator = spec.add_actuator(
            name=f"{joint}_actuator",
            target=joint,
            trntype=mujoco.mjtTrn.mjTRN_JOINT,
            forcelimited=mujoco.mjtLimited.mjLIMITED_TRUE,
            forcerange=[low, high],
            ctrllimited=mujoco.mjtLimited.mjLIMITED_TRUE,
            ctrlrange=list(hand.ctrl_ranges[j]),
        )
        kp, kv = float(model.actuator_gainprm[a, 0]), -float(model.actuator_biasprm[a, 2])
        actuator.set_to_position(kp=kp, kv=kv if kv > 0 else -1)


def _add_mjcf_geom(spec: mujoco.MjSpec, body: mujoco.MjsBody, model: mujoco.MjModel, g: int) -> None:
    """One geom of a user's compiled hand: colliding ones with the skin, visual ones (no contact)
    as they are; a mesh as its compiled vertices and faces (`hand_mesh_<id>`, added once); each in
    its colour (its material's rgba when it has one), which the renderer paints."""
    kind = mujoco.mjtGeom(int(model.geom_type[g]))
    matid = int(model.geom_matid[g])
    rgba = model.mat_rgba[matid] if matid >= 0 else model.geom_rgba[g]
    extra: dict[str, Any] = {"rgba": [float(v) for v in rgba]}
    if kind == mujoco.mjtGeom.mjGEOM_MESH:
        mesh_id = int(model.geom_dataid[g])
        name = f"{HAND_MESH_PREFIX}{mesh_id}"
        if spec.mesh(name) is None:
            vert = model.mesh_vert[
                model.mesh_vertadr[mesh_id] : model.mesh_vertadr[mesh_id] + model.mesh_vertnum[mesh_id]
            ]
            face = model.mesh_face[
                model.mesh_faceadr[mesh_id] : model.mesh_faceadr[mesh_id] + model.mesh_facenum[mesh_id]
            ]
            mesh = spec.add_mesh(name=name, uservert=vert.ravel().tolist(), userface=face.ravel().tolist())
            mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL  # unused: the body's is explicit
        extra["meshname"] = name
    else:
        extra["size"] = [float(v) for v in model.geom_size[g]]
    visual = not model.geom_contype[g] and not model.geom_conaffinity[g]
    contact = {"contype": 0, "conaffinity": 0, "group": 1} if visual else SKIN
    body.add_geom(
        type=kind,
        pos=[float(v) for v in model.geom_pos[g]],
        quat=[float(v) for v in model.geom_quat[g]],
        mass=0.0,
        **extra,
        **contact,
    )


def add_touch_probe(spec: mujoco.MjSpec) -> None:
    """The collision-free sphere the touch model moves to each taxel to measure object distances."""
    spec.worldbody.add_geom(
        name=TOUCH_PROBE,
        type=mujoco.mjtGeom.mjGEOM_SPHERE,
        size=[TOUCH_PROBE_RADIUS, 0.0, 0.0],
        contype=0,
        conaffinity=0,
        group=5,
        mass=0.0,
    )


def _add_finger(spec: mujoco.MjSpec, palm: mujoco.MjsBody, dims: HandDims, i: int, finger: Finger) -> None:
    parent = palm
    pos, quat = list(finger.base), finger_quat(finger.grow, finger.palmar)
    for k, link in enumerate(finger.links):
        body = parent.add_body(name=f"f{i}_{link.name}", pos=pos, quat=quat, gravcomp=1.0)
        joint = link.joint
        body.add_joint(
            name=f"f{i}_j{k}",
            type=mujoco.mjtJoint.mjJNT_HINGE,
            axis=JOINT_AXES[joint.kind],
            range=list(joint.range),
            limited=mujoco.mjtLimited.mjLIMITED_TRUE,
            armature=dims.armature,
            damping=dims.damping,
        )
        body.add_geom(
            name=f"f{i}_{link.name}",
            type=mujoco.mjtGeom.mjGEOM_CAPSULE,
            size=[link.radius, link.length / 2, 0.0],
            pos=[0.0, 0.0, link.length / 2],
            mass=link.mass,
            **SKIN,
        )
        actuator = spec.add_actuator(
            name=f"f{i}_a{k}",
            target=f"f{i}_j{k}",
            trntype=mujoco.mjtTrn.mjTRN_JOINT,
            forcelimited=mujoco.mjtLimited.mjLIMITED_TRUE,
            forcerange=[-joint.torque, joint.torque],
            ctrllimited=mujoco.mjtLimited.mjLIMITED_TRUE,
            ctrlrange=list(joint.range),
        )
        actuator.set_to_position(kp=joint.kp)
        parent, pos, quat = body, [0.0, 0.0, link.length], [1.0, 0.0, 0.0, 0.0]
    parent.add_geom(
        name=f"f{i}_tip_pad",
        type=mujoco.mjtGeom.mjGEOM_SPHERE,
        size=[finger.tip_radius, 0.0, 0.0],
        pos=[0.0, 0.0, finger.links[-1].length],
        mass=finger.tip_mass,
        **SKIN,
    )


def finger_quat(grow: Vec3, palmar: Vec3) -> list[float]:
    """Orientation (palm frame) of a finger's first link: +z along `grow`, +x along `palmar`."""
    z, x = np.asarray(grow, dtype=float), np.asarray(palmar, dtype=float)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.column_stack([x, np.cross(z, x), z]).flatten())
    return [float(v) for v in quat]
