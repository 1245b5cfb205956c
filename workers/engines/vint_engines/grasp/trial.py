"""One grasp trial, after VinT-6D's procedure: pick a point on the object's graspable surface, align
the open palm tangentially to it at a standoff, close the fingers until they touch, squeeze (power
grasp), lift, hold, optionally shake, judge, read out.

A trial depends only on the scene, the physics parameters, the hand's skin and its seed; `data` is
reset fully at the start and the model's per-trial settings (`configure`) are rewritten from the
compiled values every time, so trials can run in any order on one `MjData`. A grasp is kept when the
hand lifted and held the object (it slid less than `max_drop_m` relative to the palm, through the
hold and the shake) with tactile contact: at least `touch.min_active_taxels` taxels active on the
captured state.

Numerical trouble is never accepted silently: the rollout watches MuJoCo's warning counters (the
default autoreset hides a divergence), NaN/Inf, the deepest contact penetration and the object's
speed and the system's kinetic energy. On trouble the trial is rerun with half the timestep (up to
`max_retries` times, not below `min_timestep`), then rejected with the reason. Every trial records
what it took in `stability`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import mujoco
import numpy as np

from vint_engines import contract
from vint_engines.grasp.hand import SKIN, palm_frame_facing
from vint_engines.grasp.scene import GraspScene
from vint_engines.grasp.touch import Skin, held_contacts
from vint_engines.poses import matrix_to_quat, pose_json, quat_to_matrix
from vint_engines.protocol import BadInput

# Phase durations (s) before the hold; the hold itself comes from params.
SETTLE_S = 0.05
CLOSE_S = 0.40
SQUEEZE_S = 0.20
STAGGER = 0.5
LIFT_S = 0.60

# Approach sampling: where along the object the palm centre sits (side approach), how far from the
# middle of a low object's long axis (top approach), and the hand's clearance above the ground. A
# hand whose palm centre cannot sit below SIDE_MAX_FRACTION of the object's height without its
# lower edge touching the ground approaches from the top.
HEIGHT_FRACTION = (0.45, 0.62)
SIDE_MAX_FRACTION = 0.8
AZIMUTH_TRIES = 8
TOP_OFFSET_FRACTION = 0.25
TOP_YAW_JITTER = 0.2
GROUND_CLEARANCE_M = 0.004
# Setting the standoff: at most this many slides of the hand, to within this tolerance; gaps are
# measured up to the standoff plus GAP_SEARCH_M (a farther hand is moved in by that much at once).
STANDOFF_ITERATIONS = 6
STANDOFF_TOLERANCE_M = 2e-4
GAP_SEARCH_M = 0.1
# The top approach's pre-shape: the closing path is searched at PRESHAPE_STEPS evenly spaced points,
# then refined by PRESHAPE_BISECTIONS halvings.
PRESHAPE_STEPS = 24
PRESHAPE_BISECTIONS = 5
# A pinch's lowest point (the fingertips) stays this far above the ground.
PINCH_CLEARANCE_M = 0.001
PINCH_ALIGNMENTS = 2
PINCH_MAX_TILT = 0.2

# The stability monitor looks at the state every CHECK_EVERY steps.
CHECK_EVERY = 5

CONES = {"elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC, "pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL}


@dataclass(frozen=True)
class Shake:
    """After the hold the arm shakes the hand: one sine period of peak acceleration `accel_mps2`
    along each of `directions` fixed directions (spread over the upper hemisphere), `duration_s`
    in all. Fields, bounds and defaults: `GraspShake` in the stage contract."""

    enabled: bool
    accel_mps2: float
    directions: int
    duration_s: float

    @staticmethod
    def parse(obj: Any, where: str = "params.physics.shake") -> Shake:
        return Shake(**contract.validated_part("GraspShake", obj, where))

    def unit_vectors(self) -> list[np.ndarray]:
        """Deterministic directions: a golden-angle spiral over the upper hemisphere."""
        out = []
        for k in range(self.directions):
            z = 1.0 - (k + 0.5) / self.directions
            r = math.sqrt(max(0.0, 1.0 - z * z))
            phi = k * math.pi * (3.0 - math.sqrt(5.0))
            out.append(np.array([r * math.cos(phi), r * math.sin(phi), z]))
        return out


@dataclass(frozen=True)
class Physics:
    """A grasp task's `physics`: fields, bounds and defaults are `GraspPhysics` in the stage
    contract (`vint_engines/contract.schema.json`); `parse({})` gives the defaults."""

    timestep: float
    lift_height: float
    hold_s: float
    max_drop_m: float
    # Standoff: gap between the palmar face and the object's surface along the approach, as a
    # fraction of the hand's finger length (`reach`); negative values start the palm inside.
    standoff_ratio: tuple[float, float]
    shake: Shake
    cone: str
    impratio: float
    hand_solref_timeconst: float
    force_scale: float
    mass_override_kg: float | None
    max_retries: int
    min_timestep: float
    max_penetration_m: float
    max_object_speed_mps: float

    @staticmethod
    def parse(obj: Any, where: str = "params.physics") -> Physics:
        fields = contract.validated_part("GraspPhysics", obj, where)
        low, high = fields["standoff_ratio"]
        if low > high:
            raise BadInput(f"{where}.standoff_ratio: min {low} exceeds max {high}")
        return Physics(
            **{
                **fields,
                "standoff_ratio": (float(low), float(high)),
                "shake": Shake(**fields["shake"]),
            }
        )

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        out["standoff_ratio"] = list(self.standoff_ratio)
        return out


def configure(scene: GraspScene, data: mujoco.MjData, physics: Physics, timestep: float) -> None:
    """Write the trial's settings into the cached model, always from the compiled values."""
    model = scene.model
    model.opt.timestep = timestep
    model.opt.cone = CONES[physics.cone]
    model.opt.impratio = physics.impratio
    model.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_ENERGY
    if scene.hand_geoms:
        model.geom_solref[list(scene.hand_geoms), 0] = physics.hand_solref_timeconst
    if scene.actuator_forcerange:
        model.actuator_forcerange[:] = physics.force_scale * np.array(scene.actuator_forcerange)
    if scene.object_mass > 0:
        mass = physics.mass_override_kg or scene.object_mass
        model.body_mass[scene.object_body] = mass
        model.body_inertia[scene.object_body] = np.array(scene.object_inertia) * (mass / scene.object_mass)
    mujoco.mj_setConst(model, data)


def finger_reach(scene: GraspScene) -> float:
    """The longest finger's length, base to fingertip: the scale of `standoff_ratio`."""
    return scene.hand.reach()


def resting_vertices(scene: GraspScene) -> np.ndarray:
    """The object's model vertices in the world frame as it rests before a trial."""
    obj = scene.obj
    rot = quat_to_matrix(obj.rest_quat)
    return obj.model.mesh.vertices @ np.asarray(rot).T + np.array([0.0, 0.0, obj.rest_height])


@dataclass(frozen=True)
class Approach:
    """Where the hand starts. `side`: palm normal horizontal, towards the object's vertical axis
    from `azimuth`, palm centre at `height`; the open hand slides along its palm normal until its
    nearest geom is `standoff` metres from the object, and rises if its open fingers would touch
    the ground (a power grasp follows). `top` (objects too low for the side approach, e.g. a marker
    lying down): palm normal down, the palm's +y along the object's long horizontal axis turned by
    `azimuth`, centred `offset` metres along that axis; the fingers are pre-shaped along their
    closing path so that their lowest points sit at the object's mid-height (not below the ground
    clearance) and the nearest geom is `standoff` metres from the object: a fingertip pinch
    across the long axis follows (`Rollout.place_for_pinch`)."""

    azimuth: float
    height: float
    standoff: float
    mode: str = "side"
    offset: float = 0.0

    @staticmethod
    def sample(
        rng: np.random.Generator, scene: GraspScene, ratio: tuple[float, float] = (0.025, 0.10)
    ) -> Approach:
        standoff = float(rng.uniform(*ratio)) * finger_reach(scene)
        # The palm's lower edge must clear the ground: a wide palm holds a short object higher up.
        floor = scene.hand.palm_half[1] + GROUND_CLEARANCE_M + scene.hand.grasp_centre[1]
        if floor > SIDE_MAX_FRACTION * scene.obj.height:
            axis = long_axis(scene)
            half_length = float(np.ptp(resting_vertices(scene)[:, :2] @ axis)) / 2
            return Approach(
                azimuth=math.atan2(axis[1], axis[0]) + float(rng.uniform(-TOP_YAW_JITTER, TOP_YAW_JITTER)),
                height=scene.obj.height,
                standoff=standoff,
                mode="top",
                offset=float(rng.uniform(-1.0, 1.0)) * TOP_OFFSET_FRACTION * half_length,
            )
        low, high = (max(fraction * scene.obj.height, floor) for fraction in HEIGHT_FRACTION)
        height = float(rng.uniform(low, high))
        # The graspable side: one the fingers can wrap, i.e. whose width across the closing
        # direction is at most a finger's length (a cracker box's 158 mm face is not). The
        # narrowest of AZIMUTH_TRIES draws when none is.
        band = height_band(resting_vertices(scene), height, scene.hand.palm_half[1])
        reach = finger_reach(scene)
        best = (math.inf, 0.0)
        for _ in range(AZIMUTH_TRIES):
            azimuth = float(rng.uniform(0.0, 2.0 * math.pi))
            across = np.array([-math.sin(azimuth), math.cos(azimuth)])
            width = float(np.ptp(band[:, :2] @ across))
            best = min(best, (width, azimuth))
            if width <= reach:
                break
        return Approach(azimuth=best[1], height=height, standoff=standoff)


def height_band(points: np.ndarray, height: float, half: float) -> np.ndarray:
    """The points within `half` of `height`; all of them when the band holds too few to span a
    shape (a box's mesh has vertices only at its corners)."""
    band = points[np.abs(points[:, 2] - height) <= half]
    return band if len(band) >= 3 else points


def long_axis(scene: GraspScene) -> np.ndarray:
    """Unit horizontal direction along which the resting object is longest (principal axis)."""
    xy = resting_vertices(scene)[:, :2]
    xy = xy - xy.mean(axis=0)
    _, vectors = np.linalg.eigh(xy.T @ xy)
    axis = vectors[:, -1]
    return axis * (1.0 if axis[0] + 1e-12 * axis[1] >= 0 else -1.0)


def palm_pose(scene: GraspScene, approach: Approach) -> tuple[np.ndarray, np.ndarray]:
    """Palm position and rotation (palm → world) for `approach`, before any ground clearance."""
    dims = scene.hand
    points = resting_vertices(scene)
    if approach.mode == "top":
        axis = np.array([math.cos(approach.azimuth), math.sin(approach.azimuth), 0.0])
        rot = palm_frame_facing(np.array([0.0, 0.0, -1.0]), axis)
        target = np.array([*(approach.offset * axis[:2]), approach.height + approach.standoff])
        face = dims.palm_half[2]
        return target + face * np.array([0.0, 0.0, 1.0]) - rot @ np.array([*dims.grasp_centre, 0.0]), rot
    toward_axis = -np.array([math.cos(approach.azimuth), math.sin(approach.azimuth), 0.0])
    rot = palm_frame_facing(toward_axis, np.array([0.0, 0.0, 1.0]))
    # The object's extent towards the hand, over the band of heights the palm covers: a box's face
    # or corner, a drill's handle — not its largest reach in any direction.
    near = height_band(points, approach.height, dims.palm_half[1])
    extent = float((near[:, :2] @ -toward_axis[:2]).max())
    back_off = extent + approach.standoff + dims.palm_half[2]
    centre = rot @ np.array([*dims.grasp_centre, 0.0])
    return np.array([0.0, 0.0, approach.height]) - back_off * toward_axis - centre, rot


class TrialRejected(Exception):
    """The trial ran but its grasp is not kept; `reason` says why."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


class Unstable(TrialRejected):
    """The simulation itself went wrong (divergence, NaN, deep penetration, an energy blow-up):
    worth a rerun with a smaller timestep."""


@dataclass
class Stability:
    """What the stability monitor saw over one attempt (the last one is recorded)."""

    timestep_used: float
    retries: int = 0
    max_penetration_m: float = 0.0
    max_object_speed_mps: float = 0.0
    max_kinetic_energy_j: float = 0.0
    warnings: dict[str, int] = field(default_factory=dict)
    retry_reasons: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def run_trial(
    scene: GraspScene,
    data: mujoco.MjData,
    physics: Physics,
    skin: Skin,
    grasp_index: int,
    seed: int,
) -> dict:
    """Simulate one trial and return its JSON record (accepted or with a rejection reason)."""
    approach = Approach.sample(np.random.default_rng(seed), scene, physics.standoff_ratio)
    record: dict[str, Any] = {
        "grasp_index": grasp_index,
        "seed": seed,
        "accepted": False,
        "reason": None,
        "approach": asdict(approach),
    }
    timestep, reasons = physics.timestep, []
    while True:
        rollout = Rollout(scene, data, physics, timestep=timestep)
        try:
            outcome = attempt(rollout, approach, skin)
            reason = None
        except Unstable as trouble:
            smaller = timestep / 2
            if len(reasons) < physics.max_retries and smaller >= physics.min_timestep * (1 - 1e-9):
                reasons.append(trouble.reason)
                timestep = smaller
                continue
            reason = trouble.reason
        except TrialRejected as rejection:
            reason = rejection.reason
        break
    stability = replace(rollout.stability, retries=len(reasons), retry_reasons=reasons)
    record["stability"] = stability.to_json()
    if reason is not None:
        record["reason"] = reason
        record["steps"] = rollout.steps
        return record
    record.update(accepted=True, **outcome)
    return record


def attempt(rollout: Rollout, approach: Approach, skin: Skin) -> dict[str, Any]:
    """One rollout of the procedure; raises `TrialRejected` (or `Unstable`) on failure."""
    scene, data, physics = rollout.scene, rollout.data, rollout.physics
    rollout.check_timestep()
    if approach.mode == "top":
        check_pinchable(scene)
    rollout.place(approach)
    rollout.close_fingers()
    if not finger_contacts(scene, data):
        raise TrialRejected("no_contact")
    hold = rollout.lift_and_hold()
    if hold["drop_m"] >= physics.max_drop_m:
        raise TrialRejected("dropped")
    if physics.shake.enabled:
        hold["shake_slip_m"] = rollout.shake()
        if hold["shake_slip_m"] >= physics.max_drop_m:
            raise TrialRejected("dropped: shake")
    contacts = finger_contacts(scene, data)
    if not contacts:
        raise TrialRejected("no_contact")
    touch = skin.read(data, held_contacts(scene, data, skin.params.contact_steps, finger_contacts))
    if touch["active_count"] < skin.params.min_active_taxels:
        raise TrialRejected("no_touch")
    return {**readout(scene, data), "contacts": contacts, "hold": hold, "touch": touch}


def check_pinchable(scene: GraspScene) -> None:
    """Reject an object too thin for a fingertip pinch from the table. A round fingertip of radius
    r resting on the ground meets an object of height h at most h above the ground, where its
    surface normal leans arcsin((r - h) / r) from the horizontal; beyond the friction cone
    (45° at the skin's friction 1) the squeeze pushes the object down instead of holding it.
    A 1.5 mm stirring stick under 10–12 mm fingertips is such an object: a hand would have to
    slide a nail under it."""
    radius = scene.hand.fingertip_radius()
    cone = math.atan(float(SKIN["friction"][0]))
    needed = radius * (1.0 - math.cos(cone))
    if scene.obj.height < needed:
        raise TrialRejected(
            f"too_thin: {1e3 * scene.obj.height:.3g} mm high, fingertips of radius {1e3 * radius:.3g} mm"
            f" pinch from {1e3 * needed:.3g} mm"
        )


class Rollout:
    """Steps one trial through its phases, watching the simulation's health as it goes."""

    def __init__(
        self, scene: GraspScene, data: mujoco.MjData, physics: Physics, timestep: float | None = None
    ) -> None:
        self.scene, self.data, self.physics = scene, data, physics
        self.timestep = physics.timestep if timestep is None else timestep
        self.steps = 0
        self.dims = scene.hand
        self.ctrl = np.array([scene.joint_ctrl[j] for j in self.dims.joint_names()])
        self.qadr = np.array([scene.joint_qpos[j] for j in self.dims.joint_names()])
        self.open = np.array(self.dims.open_pose())
        self.closed = np.array(self.dims.closed_pose())
        # Proximal joints lead and distal ones follow, so a finger wraps the object instead of
        # hooking it with its tip: along the closing path s in [0, 1], joint k of a finger ramps
        # over [lead_k, lead_k + 1 - STAGGER].
        self.lead = STAGGER * np.array(self.dims.close_phases())
        self.preshape = 0.0  # where on the closing path the fingers start (`place_for_pinch`)
        tips = {scene.link_bodies[link] for link in self.dims.fingertips()}
        self.tip_geoms = [g for g in scene.hand_geoms if int(scene.model.geom_bodyid[g]) in tips]
        self.stability = Stability(timestep_used=self.timestep)
        model = scene.model
        self.object_dof = int(model.jnt_dofadr[model.body_jntadr[scene.object_body]])
        # Kinetic energy bound: every body of the scene moving at the object speed limit.
        self.max_kinetic = 0.5 * float(model.body_mass.sum()) * physics.max_object_speed_mps**2

    def check_timestep(self) -> None:
        """MuJoCo silently clamps a contact time constant below two timesteps (softening the
        skin): treat it as a timestep that is too coarse."""
        if self.physics.hand_solref_timeconst < 2 * self.timestep * (1 - 1e-9):
            raise Unstable(
                f"timestep: hand contact time constant {1e3 * self.physics.hand_solref_timeconst:.3g} ms"
                f" needs a timestep <= {0.5e3 * self.physics.hand_solref_timeconst:.3g} ms,"
                f" got {1e3 * self.timestep:.3g} ms"
            )

    def closing_pose(self, s: float) -> np.ndarray:
        """Finger joint targets at `s` along the closing path (0: open, 1: closed)."""
        progress = np.clip((s - self.lead) / (1.0 - STAGGER), 0.0, 1.0)
        return self.open + progress * (self.closed - self.open)

    def place(self, approach: Approach) -> None:
        scene, data, model = self.scene, self.data, self.scene.model
        mujoco.mj_resetData(model, data)
        configure(scene, data, self.physics, self.timestep)
        obj = scene.obj
        data.qpos[scene.object_qpos : scene.object_qpos + 7] = [0, 0, obj.rest_height, *obj.rest_quat]
        palm_pos, rot = palm_pose(scene, approach)
        quat = matrix_to_quat(rot)
        self.preshape = 0.0
        if approach.mode == "top" and self.place_for_pinch(approach, palm_pos, quat):
            data.ctrl[self.ctrl] = self.closing_pose(self.preshape)
            self.run(SETTLE_S)
            return
        data.qpos[self.qadr] = self.open
        self._set_palm(palm_pos, quat)
        # The standoff is the gap between the whole open hand and the object, not only the palm
        # centre's: open fingers wider than the palm must not start inside a wide box. Slide the
        # hand along its normal until the nearest hand–object gap is the standoff.
        normal = rot[:, 2]
        for _ in range(STANDOFF_ITERATIONS):
            error = approach.standoff - self.hand_object_gap(approach.standoff)
            if abs(error) < STANDOFF_TOLERANCE_M:
                break
            palm_pos = palm_pos - error * normal
            self._set_palm(palm_pos, quat)
        # Open fingers reaching below the ground (a top approach with fingers along the palm
        # normal) lift the hand until they clear it.
        lift = GROUND_CLEARANCE_M - self.lowest_hand_point()
        if lift > 0:
            self._set_palm(palm_pos + np.array([0.0, 0.0, lift]), quat)
        data.ctrl[self.ctrl] = self.open
        self.run(SETTLE_S)

    def place_for_pinch(self, approach: Approach, palm_pos: np.ndarray, quat: np.ndarray) -> bool:
        """Pre-shape the fingers for a fingertip pinch of a low object: the end of the first
        stretch of the closing path on which the hand, lowered until its fingertips' lowest point
        is at the object's mid-height less the fingertip radius (at least PINCH_CLEARANCE_M above
        the ground), clears the ground and is at least `standoff` from the object. Then, up to
        PINCH_ALIGNMENTS times, the palm is tilted about its +y (the object's long axis, by at
        most PINCH_MAX_TILT) so that the fingertips on either side are level — a shorter thumb
        would otherwise meet a lying cylinder above its equator and squeeze it out — and shifted
        along its +x so that they straddle the object's centre, and the pre-shape is searched
        again. Sets `preshape`, the joints and the palm; False when no point of the path fits
        (the hand then starts open, as for a side approach)."""
        tip = self.dims.fingertip_radius()
        floor = max(PINCH_CLEARANCE_M, self.scene.obj.height / 2 - tip)

        def fits(s: float, pos: np.ndarray, quat: np.ndarray) -> bool:
            self.data.qpos[self.qadr] = self.closing_pose(s)
            self._set_palm(pos, quat)
            self._set_palm(pos - np.array([0.0, 0.0, self.lowest_hand_point(self.tip_geoms) - floor]), quat)
            return (
                self.lowest_hand_point() >= 0.0
                and self.hand_object_gap(approach.standoff) >= approach.standoff
            )

        def search(pos: np.ndarray, quat: np.ndarray) -> float | None:
            low: float | None = None
            for s in np.linspace(0.0, 1.0, PRESHAPE_STEPS + 1):
                if fits(float(s), pos, quat):
                    low = float(s)
                elif low is not None:
                    break
            if low is None:
                return None
            high = min(1.0, low + 1.0 / PRESHAPE_STEPS)
            for _ in range(PRESHAPE_BISECTIONS if high > low else 0):
                middle = 0.5 * (low + high)
                low, high = (middle, high) if fits(middle, pos, quat) else (low, middle)
            fits(low, pos, quat)
            return low

        found = search(palm_pos, quat)
        if found is None:
            return False
        for _ in range(PINCH_ALIGNMENTS):
            alignment = self.pinch_alignment()
            if alignment is None:
                break
            tilt, shift = alignment
            turned = np.zeros(4)
            mujoco.mju_mulQuat(turned, quat, tilt)
            moved = palm_pos + shift
            again = search(moved, turned)
            if again is None:
                break
            found, palm_pos, quat = again, moved, turned
        fits(found, palm_pos, quat)
        self.preshape = found
        return True

    def pinch_alignment(self) -> tuple[np.ndarray, np.ndarray] | None:
        """How to level and centre the fingertips over the object: a rotation about the palm's +y
        (a quaternion in the palm frame) that makes the straight line through the fingertips'
        lowest points (height against palm x) horizontal, and a horizontal shift that puts the
        middle of their palm-x span over the object's centre. None when they all lie at one palm x."""
        data, scene = self.data, self.scene
        rot = data.xmat[scene.palm_body].reshape(3, 3)
        lowest: dict[int, np.ndarray] = {}
        for geom in self.tip_geoms:
            body = int(scene.model.geom_bodyid[geom])
            if body not in lowest or data.geom_xpos[geom][2] < lowest[body][2]:
                lowest[body] = data.geom_xpos[geom].copy()
        points = np.array(list(lowest.values()))
        across = rot[:, 0] - rot[2, 0] * np.array([0.0, 0.0, 1.0])
        across /= np.linalg.norm(across)
        xs = (points - data.xpos[scene.object_body]) @ across
        if np.ptp(xs) < 1e-3:
            return None
        slope = float(np.polyfit(xs, points[:, 2], 1)[0])
        # With the palm normal down, turning the palm by +a about its +y lowers points at palm
        # +x; the palm's +x is `across` or its opposite.
        sign = 1.0 if rot[:, 0] @ across > 0 else -1.0
        angle = -sign * math.atan(slope) * (1.0 if rot[2, 2] < 0 else -1.0)
        angle = min(PINCH_MAX_TILT, max(-PINCH_MAX_TILT, angle))
        tilt = np.array([math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0])
        return tilt, -0.5 * (xs.max() + xs.min()) * across

    def _set_palm(self, pos: np.ndarray, quat: np.ndarray) -> None:
        scene, data = self.scene, self.data
        data.qpos[scene.palm_qpos : scene.palm_qpos + 7] = [*pos, *quat]
        data.mocap_pos[scene.mocap] = pos
        data.mocap_quat[scene.mocap] = quat
        mujoco.mj_forward(scene.model, data)

    def hand_object_gap(self, standoff: float) -> float:
        """Smallest signed distance between the hand's geoms and the object's (negative inside)."""
        model, data = self.scene.model, self.data
        cap = max(0.0, standoff) + GAP_SEARCH_M
        return min(
            mujoco.mj_geomDistance(model, data, hand, obj, cap, None)
            for hand in self.scene.hand_geoms
            for obj in self.scene.object_geoms
        )

    def lowest_hand_point(self, geoms: Iterable[int] | None = None) -> float:
        """Height of the lowest point of the hand's geoms (or of `geoms`)."""
        model, data = self.scene.model, self.data
        lowest = math.inf
        for geom in self.scene.hand_geoms if geoms is None else geoms:
            kind, size = model.geom_type[geom], model.geom_size[geom]
            centre, axis = data.geom_xpos[geom], data.geom_xmat[geom].reshape(3, 3)
            if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
                z = centre[2] - abs(axis[2, 2]) * size[1] - size[0]
            elif kind == mujoco.mjtGeom.mjGEOM_SPHERE:
                z = centre[2] - size[0]
            else:
                z = centre[2] - float(np.abs(axis[2, :3]) @ size[:3])
            lowest = min(lowest, float(z))
        return lowest

    def close_fingers(self) -> None:
        """Follow the closing path from the pre-shape (0 unless pinching) to the closed pose,
        then squeeze."""
        start = self.preshape

        def close(s: float) -> None:
            self.data.ctrl[self.ctrl] = self.closing_pose(start + s * (1.0 - start))

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

    def shake(self) -> float:
        """Shake the hand (see `Shake`); returns how far the object moved relative to the palm."""
        scene, data, shake = self.scene, self.data, self.physics.shake
        centre = data.mocap_pos[scene.mocap].copy()
        before = self.object_in_palm()
        period = shake.duration_s / shake.directions
        omega = 2.0 * math.pi / period
        amplitude = shake.accel_mps2 / omega**2  # x = A sin(ωt) peaks at A ω² acceleration
        for direction in shake.unit_vectors():

            def move(s: float, direction: np.ndarray = direction) -> None:
                data.mocap_pos[scene.mocap] = centre + amplitude * math.sin(2.0 * math.pi * s) * direction

            self.ramp(period, move)
        data.mocap_pos[scene.mocap] = centre
        return float(np.linalg.norm(self.object_in_palm() - before))

    def object_minus_palm_z(self) -> float:
        xpos = self.data.xpos
        return float(xpos[self.scene.object_body][2] - xpos[self.scene.palm_body][2])

    def object_in_palm(self) -> np.ndarray:
        xpos, xmat = self.data.xpos, self.data.xmat
        palm = self.scene.palm_body
        return xmat[palm].reshape(3, 3).T @ (xpos[self.scene.object_body] - xpos[palm])

    def run(self, seconds: float) -> int:
        steps = round(seconds / self.timestep)
        done = 0
        while done < steps:
            chunk = min(CHECK_EVERY, steps - done)
            mujoco.mj_step(self.scene.model, self.data, nstep=chunk)
            done += chunk
            self.monitor()
        self.steps += steps
        self.check()
        return steps

    def ramp(self, seconds: float, apply: Callable[[float], None]) -> None:
        """Step for `seconds`, calling apply(s) with s rising from 0 to 1 before each step."""
        steps = max(1, round(seconds / self.timestep))
        for k in range(steps):
            apply((k + 1) / steps)
            mujoco.mj_step(self.scene.model, self.data)
            if k % CHECK_EVERY == CHECK_EVERY - 1:
                self.monitor()
        self.steps += steps
        self.check()

    def monitor(self) -> None:
        """Track penetration, object speed and kinetic energy; reject a blow-up at once."""
        data, stability, physics = self.data, self.stability, self.physics
        self.check()
        if data.ncon:
            depth = -float(data.contact.dist[: data.ncon].min())
            stability.max_penetration_m = max(stability.max_penetration_m, depth)
        speed = float(np.linalg.norm(data.qvel[self.object_dof : self.object_dof + 3]))
        stability.max_object_speed_mps = max(stability.max_object_speed_mps, speed)
        kinetic = float(data.energy[1])
        stability.max_kinetic_energy_j = max(stability.max_kinetic_energy_j, kinetic)
        if stability.max_penetration_m > physics.max_penetration_m:
            raise Unstable(f"penetration: {1e3 * stability.max_penetration_m:.2f} mm")
        if speed > physics.max_object_speed_mps:
            raise Unstable(f"energy: object speed {speed:.3g} m/s")
        if not math.isfinite(kinetic) or kinetic > self.max_kinetic:
            raise Unstable(f"energy: kinetic {kinetic:.3g} J")

    def check(self) -> None:
        data = self.data
        counts = data.warning.number  # one array read: iterating the warning structs costs ~90 µs
        self.stability.warnings = (
            {mujoco.mjtWarning(i).name: int(n) for i, n in enumerate(counts) if n > 0} if counts.any() else {}
        )
        if not (np.isfinite(data.qpos).all() and np.isfinite(data.qvel).all()):
            raise Unstable("nan_state")
        if self.stability.warnings:
            raise Unstable(f"diverged: {next(iter(self.stability.warnings))}")


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
