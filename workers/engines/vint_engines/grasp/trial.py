"""One grasp trial: place the open hand beside the object, close, lift, hold, judge, read out.

A trial depends only on the scene, the physics parameters, the hand's skin and its seed; `data` is
reset fully at the start, so trials can run in any order on one `MjData`. A grasp is kept when the
hand lifted and held the object (it slid less than `max_drop_m` relative to the palm) with
tactile contact: at least `touch.min_active_taxels` taxels active on the captured state.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from typing import Any

import mujoco
import numpy as np

from vint_engines import params as P
from vint_engines.grasp.hand import palm_frame_facing
from vint_engines.grasp.scene import GraspScene
from vint_engines.grasp.touch import Skin
from vint_engines.poses import matrix_to_quat, pose_json

# Phase durations (s) before the hold; the hold itself comes from params.
SETTLE_S = 0.05
CLOSE_S = 0.40
SQUEEZE_S = 0.20
STAGGER = 0.5
LIFT_S = 0.60

# Approach sampling: where along the object the palm centre sits, and the gap to its surface.
HEIGHT_FRACTION = (0.45, 0.62)
STANDOFF_M = (0.003, 0.012)
GROUND_CLEARANCE_M = 0.004


@dataclass(frozen=True)
class Physics:
    timestep: float
    lift_height: float
    hold_s: float
    max_drop_m: float

    @staticmethod
    def parse(obj: Mapping[str, Any]) -> Physics:
        where = "params.physics"
        return Physics(
            timestep=P.number(obj, "timestep", where, 0.002, low=1e-4, high=0.005),
            lift_height=P.number(obj, "lift_height", where, 0.10, low=0.0, high=1.0),
            hold_s=P.number(obj, "hold_s", where, 1.0, low=0.0, high=30.0),
            max_drop_m=P.number(obj, "max_drop_m", where, 0.02, low=0.0),
        )

    def to_json(self) -> dict[str, float]:
        return asdict(self)


@dataclass(frozen=True)
class Approach:
    """Where the hand starts: palm normal towards the object's axis from `azimuth`."""

    azimuth: float
    height: float
    standoff: float

    @staticmethod
    def sample(rng: np.random.Generator, scene: GraspScene) -> Approach:
        # The palm's lower edge must clear the ground: a wide palm holds a short object higher up.
        floor = scene.hand.palm_half[1] + GROUND_CLEARANCE_M + scene.hand.grasp_centre[1]
        low, high = (max(fraction * scene.obj.height, floor) for fraction in HEIGHT_FRACTION)
        return Approach(
            azimuth=float(rng.uniform(0.0, 2.0 * math.pi)),
            height=float(rng.uniform(low, high)),
            standoff=float(rng.uniform(*STANDOFF_M)),
        )


class TrialRejected(Exception):
    """The trial ran but its grasp is not kept; `reason` says why."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


def run_trial(
    scene: GraspScene, data: mujoco.MjData, physics: Physics, skin: Skin, grasp_index: int, seed: int
) -> dict:
    """Simulate one trial and return its JSON record (accepted or with a rejection reason)."""
    approach = Approach.sample(np.random.default_rng(seed), scene)
    record: dict[str, Any] = {
        "grasp_index": grasp_index,
        "seed": seed,
        "accepted": False,
        "reason": None,
        "approach": asdict(approach),
    }
    rollout = Rollout(scene, data, physics)
    try:
        rollout.place(approach)
        rollout.close_fingers()
        if not finger_contacts(scene, data):
            raise TrialRejected("no_contact")
        hold = rollout.lift_and_hold()
        contacts = finger_contacts(scene, data)
        if hold["drop_m"] >= physics.max_drop_m:
            raise TrialRejected("dropped")
        if not contacts:
            raise TrialRejected("no_contact")
        touch = skin.read(data, {contact["link"] for contact in contacts})
        if touch["active_count"] < skin.params.min_active_taxels:
            raise TrialRejected("no_touch")
    except TrialRejected as rejection:
        record["reason"] = rejection.reason
        record["steps"] = rollout.steps
        return record
    record.update(accepted=True, **readout(scene, data), contacts=contacts, hold=hold, touch=touch)
    return record


class Rollout:
    """Steps one trial through its phases, checking for divergence after each phase."""

    def __init__(self, scene: GraspScene, data: mujoco.MjData, physics: Physics) -> None:
        self.scene, self.data, self.physics = scene, data, physics
        self.steps = 0
        self.dims = scene.hand
        self.ctrl = np.array([scene.joint_ctrl[j] for j in self.dims.joint_names()])
        self.qadr = np.array([scene.joint_qpos[j] for j in self.dims.joint_names()])
        self.open = np.array(self.dims.open_pose())
        self.closed = np.array(self.dims.closed_pose())

    def place(self, approach: Approach) -> None:
        scene, data, model = self.scene, self.data, self.scene.model
        model.opt.timestep = self.physics.timestep
        mujoco.mj_resetData(model, data)
        obj = scene.obj
        data.qpos[scene.object_qpos : scene.object_qpos + 7] = [0, 0, obj.rest_height, *obj.rest_quat]
        toward_axis = -np.array([math.cos(approach.azimuth), math.sin(approach.azimuth), 0.0])
        rot = palm_frame_facing(toward_axis, np.array([0.0, 0.0, 1.0]))
        back_off = obj.radius + approach.standoff + self.dims.palm_half[2]
        centre = rot @ np.array([*self.dims.grasp_centre, 0.0])
        palm_pos = np.array([0.0, 0.0, approach.height]) - back_off * toward_axis - centre
        palm_quat = matrix_to_quat(rot)
        data.qpos[scene.palm_qpos : scene.palm_qpos + 7] = [*palm_pos, *palm_quat]
        data.mocap_pos[scene.mocap] = palm_pos
        data.mocap_quat[scene.mocap] = palm_quat
        data.qpos[self.qadr] = self.open
        data.ctrl[self.ctrl] = self.open
        mujoco.mj_forward(model, data)
        self.run(SETTLE_S)

    def close_fingers(self) -> None:
        # Proximal joints lead and distal ones follow, so a finger wraps the object instead of
        # hooking it with its tip: joint k of a finger ramps over [start_k, start_k + 1 - STAGGER].
        start = np.array(
            [STAGGER * k / max(1, len(f.links) - 1) for f in self.dims.fingers for k in range(len(f.links))]
        )

        def close(s: float) -> None:
            progress = np.clip((s - start) / (1.0 - STAGGER), 0.0, 1.0)
            self.data.ctrl[self.ctrl] = self.open + progress * (self.closed - self.open)

        self.ramp(CLOSE_S, close)
        self.run(SQUEEZE_S)

    def lift_and_hold(self) -> dict[str, float]:
        scene, data = self.scene, self.data
        start = data.mocap_pos[scene.mocap].copy()
        offset_before = self.object_minus_palm_z()
        object_z0 = float(data.xpos[scene.object_body][2])

        def raise_hand(s: float) -> None:
            smooth = 0.5 - 0.5 * math.cos(math.pi * s)
            data.mocap_pos[scene.mocap] = start + np.array([0.0, 0.0, smooth * self.physics.lift_height])

        self.ramp(LIFT_S, raise_hand)
        hold_steps = self.run(self.physics.hold_s)
        return {
            "drop_m": offset_before - self.object_minus_palm_z(),
            "object_rise_m": float(data.xpos[scene.object_body][2]) - object_z0,
            "steps": hold_steps,
        }

    def object_minus_palm_z(self) -> float:
        xpos = self.data.xpos
        return float(xpos[self.scene.object_body][2] - xpos[self.scene.palm_body][2])

    def run(self, seconds: float) -> int:
        steps = round(seconds / self.physics.timestep)
        if steps:
            mujoco.mj_step(self.scene.model, self.data, nstep=steps)
        self.steps += steps
        self.check()
        return steps

    def ramp(self, seconds: float, apply: Callable[[float], None]) -> None:
        """Step for `seconds`, calling apply(s) with s rising from 0 to 1 before each step."""
        steps = max(1, round(seconds / self.physics.timestep))
        for k in range(steps):
            apply((k + 1) / steps)
            mujoco.mj_step(self.scene.model, self.data)
        self.steps += steps
        self.check()

    def check(self) -> None:
        data = self.data
        if not (np.isfinite(data.qpos).all() and np.isfinite(data.qvel).all()):
            raise TrialRejected("nan_state")
        for i, warning in enumerate(data.warning):
            if warning.number > 0:
                raise TrialRejected(f"diverged: {mujoco.mjtWarning(i).name}")


def finger_contacts(scene: GraspScene, data: mujoco.MjData) -> list[dict[str, Any]]:
    """Hand–object contacts: link, point, normal (from the link into the object), normal force."""
    contacts = []
    force = np.zeros(6)
    for i in range(data.ncon):
        contact = data.contact[i]
        bodies = scene.model.geom_bodyid[[contact.geom1, contact.geom2]]
        if scene.object_body not in bodies:
            continue
        other = contact.geom2 if bodies[0] == scene.object_body else contact.geom1
        link = scene.link_of_geom(int(other))
        if link is None:
            continue
        mujoco.mj_contactForce(scene.model, data, i, force)
        normal = contact.frame[:3] if other == contact.geom1 else -contact.frame[:3]
        contacts.append(
            {
                "link": link,
                "p": [float(v) for v in contact.pos],
                "normal": [float(v) for v in normal],
                "force": float(force[0]),
            }
        )
    return contacts


def readout(scene: GraspScene, data: mujoco.MjData) -> dict[str, Any]:
    """Poses of the object, the palm and every link, and the finger joint angles."""

    def body_pose(body: int) -> dict[str, list[float]]:
        return pose_json(data.xpos[body], data.xquat[body])

    return {
        "object_pose": body_pose(scene.object_body),
        "hand_pose": body_pose(scene.palm_body),
        "link_poses": {name: body_pose(body) for name, body in scene.link_bodies.items()},
        "joints": {name: float(data.qpos[adr]) for name, adr in scene.joint_qpos.items()},
    }
