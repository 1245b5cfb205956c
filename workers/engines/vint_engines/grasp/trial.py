"""One grasp trial, after VinT-6D's procedure: hold the object in free space at a random
orientation, pick a point on its graspable surface, align the open palm tangentially to it at a
standoff, close the fingers until they touch, squeeze (power grasp), release the object to the
hand, lift, hold, optionally shake, judge, read out (`docs/physics.md`, "The grasp procedure").

A trial depends only on the scene, the physics parameters, the hand's skin and its seed; `data` is
reset fully at the start and the model's per-trial settings (`configure`) are rewritten from the
compiled values every time, so trials can run in any order on one `MjData`. A grasp is kept when the
hand lifted and held the object with tactile contact and is ready for manipulation:

- held: it fell less than `max_drop_m` relative to the palm over the lift and hold (`dropped`);
- steady (readiness, VinT-6D §3.1.2): over the hold, and over the shake, the object moved less
  than MAX_SLIP_M and turned less than MAX_TURN_DEG in the palm's frame (`moved_in_hand`);
- felt: at least `touch.min_active_taxels` taxels active on the captured state (`no_touch`);
- no dorsal contact: no link presses the object with its unsensorised side (the back of a finger;
  `touch.Skin.dorsal_forces`) harder than the activation force (`dorsal_contact`);
- of its type (`judge_type`): a power grasp (whose palm is brought to the object before the
  fingers close, `Rollout.approach_palm`) touches with the palm (`no_palm_contact`) and holds the
  object's centre within POWER_CENTRE_RATIO of its bounding radius of the palm (`far_from_palm`);
  a precision grasp touches with fingertips only, of two fingers at least (`not_fingertips`).

Numerical trouble is never accepted silently: the rollout watches MuJoCo's warning counters (the
default autoreset hides a divergence), NaN/Inf, the deepest contact penetration and the object's
speed and the system's kinetic energy. On trouble the trial is rerun with half the timestep (up to
`max_retries` times, not below `min_timestep`), then rejected with the reason. Every trial records
what it took in `stability`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import mujoco
import numpy as np
import numpy.typing as npt

from vint_engines import contract
from vint_engines.grasp.scene import GraspScene, geom_distance
from vint_engines.grasp.surface import palm_axes, random_rotation
from vint_engines.grasp.touch import Skin, held_contacts, trial_aging, window_steps
from vint_engines.poses import matrix_to_quat, pose_json, quat_to_matrix
from vint_engines.protocol import BadInput

# Phase durations (s) before the hold; the hold itself comes from params.
SETTLE_S = 0.05
CLOSE_S = 0.40
SQUEEZE_S = 0.20
STAGGER = 0.5
LIFT_S = 0.60
# After the release, before the lift: the object settles into the still hand.
SETTLE_IN_HAND_S = 0.20

# Approach sampling: surface draws per trial (the first whose width the fingers can wrap is kept).
SURFACE_DRAWS = 16
# Setting the standoff: the open hand starts this far beyond a finger length from the object, then
# slides along its normal at most STANDOFF_ITERATIONS times to within STANDOFF_TOLERANCE_M of the
# standoff; gaps are measured up to the standoff plus GAP_SEARCH_M (a farther hand is moved in by
# that much at once).
START_MARGIN_M = 0.01
STANDOFF_ITERATIONS = 8
STANDOFF_TOLERANCE_M = 2e-4
GAP_SEARCH_M = 0.1

# While the fixture holds it, an object lighter than this is given this mass: MuJoCo softens a
# contact with a light body (its regularisation scales with the lighter body's inverse weight), so
# fingers closing on a fixed 16 g marker sank 21 mm into it; a free object yields instead.
FIXTURE_MASS_KG = 1.0
# Released, an object lighter than FULL_GRIP_KG is squeezed with a proportional share of the
# fingers' force limits, at least MIN_GRIP (`grip_fraction`).
FULL_GRIP_KG = 0.1
MIN_GRIP = 0.01

# The stability monitor looks at the state every CHECK_EVERY steps.
CHECK_EVERY = 5

# Readiness: how far the object may move and turn in the palm's frame over the hold (and over the
# shake) of a kept grasp; docs/physics.md, "Grasp types and readiness", has the measurement.
MAX_SLIP_M = 0.005
MAX_TURN_DEG = 5.0
# A power grasp brings the palm to the object before the fingers close: the hand moves along its
# normal by the palm's gap plus PALM_PRESS_M over PALM_APPROACH_S (the fingers, open, give way).
PALM_PRESS_M = 0.002
PALM_APPROACH_S = 0.2
# A power grasp holds the object's centre (its bounding box's) at most this fraction of its
# bounding radius from the palm's palmar face. See docs/physics.md, "Grasp types and readiness".
POWER_CENTRE_RATIO = 0.8
GRASP_TYPES = ("power", "precision", "any")

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
    grasp_type: str

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
    set_object_mass(scene, data, object_mass(scene, physics))


def object_mass(scene: GraspScene, physics: Physics) -> float:
    return physics.mass_override_kg or scene.object_mass


def grip_fraction(mass: float) -> float:
    """The fraction of the fingers' force limits that holds a released object of `mass` kg: all
    of it from FULL_GRIP_KG up, proportionally less for lighter objects (not below MIN_GRIP), as
    a hand controller grips a light object gently. The full squeeze of a 16 g marker sank the
    fingers 13-21 mm into it (MuJoCo's contact regularisation scales with the lighter body)."""
    return min(1.0, max(MIN_GRIP, mass / FULL_GRIP_KG))


def set_object_mass(scene: GraspScene, scratch: mujoco.MjData, mass: float) -> None:
    """Give the object `mass` (its inertia scaled alike) and recompute the model's constants
    (MuJoCo's contact softness depends on the bodies' masses through `body_invweight0`).
    `mj_setConst` overwrites the state of `scratch`."""
    model = scene.model
    if scene.object_mass > 0:
        model.body_mass[scene.object_body] = mass
        model.body_inertia[scene.object_body] = np.array(scene.object_inertia) * (mass / scene.object_mass)
    mujoco.mj_setConst(model, scratch)


def finger_reach(scene: GraspScene) -> float:
    """The longest finger's length, base to fingertip: the scale of `standoff_ratio`."""
    return scene.hand.reach()


@dataclass(frozen=True)
class Approach:
    """Where the object is held and where the hand starts, after VinT-Sim: the object sits at the
    world origin in orientation `object_quat` (w, x, y, z; uniform over rotations); the palm faces
    the surface point `point` (object frame) whose outward normal is `normal`: palm +z = -normal,
    turned by `palm_angle` about it (`surface.palm_axes`), the hand's grasp centre over the point.
    The open hand (its finger spread `spread` in [0, 1] set, `GraspHand.spread_ranges`) then slides
    along its normal until its nearest geom is `standoff` m from the object. `width` is the
    object's extent across the fingers' closing direction (palm +x) over the band the palm covers;
    `redraws` counts the surface draws rejected (facing into the object, or a width beyond the
    finger length; SURFACE_DRAWS when all were: the narrowest outward one was kept)."""

    object_quat: tuple[float, float, float, float]
    point: tuple[float, float, float]
    normal: tuple[float, float, float]
    palm_angle: float
    standoff: float
    spread: float
    width: float
    redraws: int = 0

    @staticmethod
    def sample(
        rng: np.random.Generator, scene: GraspScene, ratio: tuple[float, float] = (0.025, 0.10)
    ) -> Approach:
        """Draw, in this order: the object's orientation, the standoff ratio, the finger spread,
        then up to SURFACE_DRAWS times a surface point and a palm angle, keeping the first that
        faces outwards (`ObjectSurface.faces_outward`) and whose width the fingers can wrap (at
        most the finger length). When none does, the narrowest outward draw (or the first draw)
        is kept with `redraws` = SURFACE_DRAWS."""
        object_quat = random_rotation(rng)
        standoff = float(rng.uniform(*ratio)) * finger_reach(scene)
        spread = float(rng.uniform())
        reach = finger_reach(scene)
        best: Approach | None = None
        first: Approach | None = None
        for draw in range(SURFACE_DRAWS):
            point, normal = scene.obj.surface.sample(rng)
            angle = float(rng.uniform(0.0, 2.0 * math.pi))
            candidate = Approach.facing(object_quat, point, normal, angle, standoff, spread, scene, draw)
            first = first or candidate
            # Inside a mug or on the inner side of a handle, no palm can face the point.
            if not scene.obj.surface.faces_outward(point, normal):
                continue
            if candidate.width <= reach:
                return candidate
            if best is None or candidate.width < best.width:
                best = candidate
        chosen = best or first
        assert chosen is not None
        return replace(chosen, redraws=SURFACE_DRAWS)

    @staticmethod
    def facing(
        object_quat: npt.ArrayLike,
        point: npt.ArrayLike,
        normal: npt.ArrayLike,
        palm_angle: float,
        standoff: float,
        spread: float,
        scene: GraspScene,
        redraws: int = 0,
    ) -> Approach:
        """The approach to `point` (object frame) with its width measured; also how tests pose
        the hand exactly."""
        point, normal = np.asarray(point, dtype=float), np.asarray(normal, dtype=float)
        normal = normal / np.linalg.norm(normal)
        axes = palm_axes(normal, palm_angle)
        width = scene.obj.surface.width_across(point, axes[:, 0], axes[:, 1], scene.hand.palm_half[1])
        return Approach(
            object_quat=tuple(float(v) for v in object_quat),  # type: ignore[arg-type]
            point=tuple(float(v) for v in point),  # type: ignore[arg-type]
            normal=tuple(float(v) for v in normal),  # type: ignore[arg-type]
            palm_angle=float(palm_angle),
            standoff=float(standoff),
            spread=float(spread),
            width=width,
            redraws=redraws,
        )

    def object_rotation(self) -> np.ndarray:
        return quat_to_matrix(self.object_quat)

    def palm_rotation(self) -> np.ndarray:
        """Palm → world."""
        return self.object_rotation() @ palm_axes(np.array(self.normal), self.palm_angle)

    def to_json(self) -> dict[str, Any]:
        """The record's `approach`: the fields, plus the palm normal in the world frame."""
        return {**asdict(self), "palm_normal_world": [float(v) for v in self.palm_rotation()[:, 2]]}


def start_pose(scene: GraspScene, approach: Approach) -> tuple[np.ndarray, np.ndarray]:
    """Palm position and rotation (palm → world) before the slide to the standoff: the grasp
    centre on the palmar face over the surface point, beyond everything of the object on that
    side by a finger length (open fingers can stand out of the palm by that much)."""
    obj_rot = approach.object_rotation()
    rot = approach.palm_rotation()
    point_world = obj_rot @ np.array(approach.point)
    outward = -rot[:, 2]
    beyond = float(((scene.obj.surface.vertices @ obj_rot.T - point_world) @ outward).max())
    distance = beyond + finger_reach(scene) + max(approach.standoff, 0.0) + START_MARGIN_M
    dims = scene.hand
    face = np.array([*dims.grasp_centre, dims.palm_half[2]])
    return point_world + distance * outward - rot @ face, rot


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
    approach: Approach | None = None,
) -> dict:
    """Simulate one trial and return its JSON record (accepted or with a rejection reason). The
    approach is drawn from `seed` unless given (tests pose the hand exactly)."""
    if approach is None:
        approach = Approach.sample(np.random.default_rng(seed), scene, physics.standoff_ratio)
    record: dict[str, Any] = {
        "grasp_index": grasp_index,
        "seed": seed,
        "accepted": False,
        "reason": None,
        "approach": approach.to_json(),
    }
    timestep, reasons = physics.timestep, []
    while True:
        rollout = Rollout(scene, data, physics, timestep=timestep)
        try:
            outcome = attempt(rollout, approach, skin, trial_aging(skin.params.aging, seed))
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


def attempt(rollout: Rollout, approach: Approach, skin: Skin, aging: float) -> dict[str, Any]:
    """One rollout of the procedure, its touch read with the grasp's `aging`; raises
    `TrialRejected` (or `Unstable`) on failure."""
    scene, data, physics = rollout.scene, rollout.data, rollout.physics
    rollout.check_timestep()
    rollout.place(approach)
    if physics.grasp_type == "power":
        rollout.approach_palm()
    rollout.close_fingers()
    if not finger_contacts(scene, data):
        raise TrialRejected("no_contact")
    hold = rollout.lift_and_hold()
    if hold["drop_m"] >= physics.max_drop_m:
        raise TrialRejected("dropped")
    check_steady(hold["slip_m"], hold["turn_deg"], "")
    if physics.shake.enabled:
        hold["shake_slip_m"], hold["shake_turn_deg"] = rollout.shake()
        if hold["shake_slip_m"] >= physics.max_drop_m:
            raise TrialRejected("dropped: shake")
        check_steady(hold["shake_slip_m"], hold["shake_turn_deg"], "shake, ")
    contacts = finger_contacts(scene, data)
    if not contacts:
        raise TrialRejected("no_contact")
    steps = window_steps(skin.params.contact_window_s, rollout.timestep)
    touch = skin.read(data, held_contacts(scene, data, steps, finger_contacts), aging)
    if touch["active_count"] < skin.params.min_active_taxels:
        raise TrialRejected("no_touch")
    check_dorsal(touch["dorsal_force_n"], skin.params.activation_force_n)
    grasp = judge_type(physics.grasp_type, scene, data, touch["active"])
    return {**readout(scene, data), "contacts": contacts, "hold": hold, "touch": touch, "grasp": grasp}


def check_steady(slip_m: float, turn_deg: float, during: str) -> None:
    """Readiness: reject an object that moved `slip_m` or turned `turn_deg` in the hand."""
    if slip_m >= MAX_SLIP_M:
        raise TrialRejected(f"moved_in_hand: {during}slipped {1e3 * slip_m:.3g} mm")
    if turn_deg >= MAX_TURN_DEG:
        raise TrialRejected(f"moved_in_hand: {during}turned {turn_deg:.3g}°")


def check_dorsal(forces: dict[str, float], activation_n: float) -> None:
    """Reject a grasp that presses the object with a link's unsensorised side (`forces`: per
    link, N) harder than a taxel's activation force."""
    if forces:
        link = max(forces, key=lambda name: forces[name])
        if forces[link] > activation_n:
            raise TrialRejected(f"dorsal_contact: {link} {forces[link]:.3g} N")


def object_centre(scene: GraspScene) -> tuple[np.ndarray, float]:
    """The object's centre (its model's bounding-box centre, object frame) and its bounding
    radius about that centre (m)."""
    vertices = scene.obj.surface.vertices
    centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    return centre, float(np.linalg.norm(vertices - centre, axis=1).max())


def centre_above_palm(scene: GraspScene, data: mujoco.MjData, centre: np.ndarray) -> float:
    """Height (m) of the object-frame point `centre` above the palm's palmar face (palm +z)."""
    body, palm = scene.object_body, scene.palm_body
    world = data.xmat[body].reshape(3, 3) @ centre + data.xpos[body]
    local = data.xmat[palm].reshape(3, 3).T @ (world - data.xpos[palm])
    return float(local[2]) - scene.hand.palm_half[2]


def judge_type(
    grasp_type: str, scene: GraspScene, data: mujoco.MjData, active: list[dict[str, Any]]
) -> dict[str, Any]:
    """The record's `grasp`: the type and what it was judged by; rejects a grasp not of
    `grasp_type` (see the module's doc)."""
    centre, radius = object_centre(scene)
    height = centre_above_palm(scene, data, centre)
    palm = sum(1 for taxel in active if taxel["region"] == "palm")
    tips = {taxel["link"] for taxel in active if taxel["region"] == "tip"}
    off_tips = sum(1 for taxel in active if taxel["region"] != "tip")
    limit = POWER_CENTRE_RATIO * radius
    if grasp_type == "power":
        if palm == 0:
            raise TrialRejected("no_palm_contact")
        if height > limit:
            raise TrialRejected(
                f"far_from_palm: centre {1e3 * height:.3g} mm from the palm, limit {1e3 * limit:.3g} mm"
            )
    elif grasp_type == "precision":
        if off_tips:
            raise TrialRejected(f"not_fingertips: {off_tips} active taxels off the fingertips")
        if len(tips) < 2:
            raise TrialRejected(f"not_fingertips: {len(tips)} fingertip touching")
    return {
        "type": grasp_type,
        "palm_active": palm,
        "fingertips_touching": len(tips),
        "centre_to_palm_m": height,
        "centre_limit_m": limit,
    }


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
        self.open = np.array(self.dims.pregrasp_pose())
        self.closed = np.array(self.dims.closed_pose())
        self.spread_ranges = self.dims.spread_ranges()
        # Proximal joints lead and distal ones follow, so a finger wraps the object instead of
        # hooking it with its tip: along the closing path s in [0, 1], joint k of a finger ramps
        # over [lead_k, lead_k + 1 - STAGGER].
        self.lead = STAGGER * np.array(self.dims.close_phases())
        # The object's pose while it is held fixed (`place` to `release`), else None.
        self.fixture: np.ndarray | None = None
        # Once released: where the object sat in the palm frame, how far it may move from there
        # before it is out of the hand (a finger length), and the reason a drop is rejected with.
        self.in_palm_at_release: np.ndarray | None = None
        self.drop_reason = "dropped"
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

    def set_spread(self, spread: float) -> None:
        """Hold every spread joint (`GraspHand.spread_ranges`) at `spread` of its range, open and
        closed alike."""
        for k, span in enumerate(self.spread_ranges):
            if span is not None:
                self.open[k] = self.closed[k] = span[0] + spread * (span[1] - span[0])

    def place(self, approach: Approach) -> None:
        """Hold the object at the origin in its orientation, then put the open hand at its start
        pose and slide it along its normal until the nearest hand–object gap is the standoff (the
        whole open hand's gap, not only the palm centre's: open fingers wider than the palm must
        not start inside a wide box)."""
        scene, data, model = self.scene, self.data, self.scene.model
        mujoco.mj_resetData(model, data)
        configure(scene, data, self.physics, self.timestep)
        self.fixture = np.array([0.0, 0.0, 0.0, *approach.object_quat])
        mass = object_mass(scene, self.physics)
        if mass < FIXTURE_MASS_KG:
            set_object_mass(scene, data, FIXTURE_MASS_KG)
        data.qpos[scene.object_qpos : scene.object_qpos + 7] = self.fixture
        self.set_spread(approach.spread)
        data.qpos[self.qadr] = self.open
        palm_pos, rot = start_pose(scene, approach)
        quat = matrix_to_quat(rot)
        self._set_palm(palm_pos, quat)
        normal = rot[:, 2]
        for _ in range(STANDOFF_ITERATIONS):
            error = approach.standoff - self.hand_object_gap(approach.standoff)
            if abs(error) < STANDOFF_TOLERANCE_M:
                break
            palm_pos = palm_pos - error * normal
            self._set_palm(palm_pos, quat)
        data.ctrl[self.ctrl] = self.open
        self.run(SETTLE_S)

    def release(self) -> None:
        """Let the object go: from now on only the hand holds it against gravity."""
        self.fixture = None
        self.in_palm_at_release = self.object_in_palm()
        scene, physics = self.scene, self.physics
        mass = object_mass(scene, physics)
        if mass < FIXTURE_MASS_KG:
            set_object_mass(scene, mujoco.MjData(scene.model), mass)
        if scene.actuator_forcerange:
            grip = physics.force_scale * grip_fraction(mass)
            scene.model.actuator_forcerange[:] = grip * np.array(scene.actuator_forcerange)

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
        hand, obj = np.array(self.scene.hand_geoms), np.array(self.scene.object_geoms)
        # Bounding spheres bound every pair's distance from below: only pairs that could be
        # nearer than the best so far are asked (a wine glass has 132 hulls).
        centres = np.linalg.norm(data.geom_xpos[hand][:, None] - data.geom_xpos[obj][None], axis=2)
        bound = centres - model.geom_rbound[hand][:, None] - model.geom_rbound[obj][None]
        best = cap
        for flat in np.argsort(bound, axis=None, kind="stable"):
            i, j = divmod(int(flat), len(obj))
            if bound[i, j] >= best:
                break
            best = min(best, geom_distance(model, data, int(hand[i]), int(obj[j]), cap))
        return best

    def approach_palm(self) -> None:
        """Move the open hand along its normal until its palm presses the (fixed) object by
        PALM_PRESS_M: a power grasp closes the fingers around an object lying on the palm."""
        scene, data, model = self.scene, self.data, self.scene.model
        palm = [g for g in scene.hand_geoms if model.geom_bodyid[g] == scene.palm_body]
        cap = self.dims.reach() + GAP_SEARCH_M
        gap = min(geom_distance(model, data, g, o, cap) for g in palm for o in scene.object_geoms)
        start = data.mocap_pos[scene.mocap].copy()
        normal = data.xmat[scene.palm_body].reshape(3, 3)[:, 2].copy()
        travel = max(0.0, gap) + PALM_PRESS_M

        def advance(s: float) -> None:
            data.mocap_pos[scene.mocap] = start + (0.5 - 0.5 * math.cos(math.pi * s)) * travel * normal

        self.ramp(PALM_APPROACH_S, advance)

    def close_fingers(self) -> None:
        """Follow the closing path from the open to the closed pose, then squeeze: position servos
        whose targets lie beyond contact, so each finger stops where it touches the (fixed)
        object and presses with its force limit."""

        def close(s: float) -> None:
            self.data.ctrl[self.ctrl] = self.closing_pose(s)

        self.ramp(CLOSE_S, close)
        self.run(SQUEEZE_S)

    def lift_and_hold(self) -> dict[str, float]:
        """Release the object and let it settle in the still hand (SETTLE_IN_HAND_S: it falls
        from a fingertip hold onto an upturned palm, say), then lift the hand and hold; the drop
        is measured from the settled state, as it was from the object resting on the ground
        before. `settle_m` is how far the object moved in the palm frame while settling."""
        scene, data = self.scene, self.data
        start = data.mocap_pos[scene.mocap].copy()
        self.release()
        self.run(SETTLE_IN_HAND_S)
        assert self.in_palm_at_release is not None
        settle = float(np.linalg.norm(self.object_in_palm() - self.in_palm_at_release))
        offset_before = self.object_minus_palm_z()
        object_z0 = float(data.xpos[scene.object_body][2])

        def raise_hand(s: float) -> None:
            smooth = 0.5 - 0.5 * math.cos(math.pi * s)
            data.mocap_pos[scene.mocap] = start + np.array([0.0, 0.0, smooth * self.physics.lift_height])

        self.ramp(LIFT_S, raise_hand)
        lifted = self.object_pose_in_palm()
        hold_steps = self.run(self.physics.hold_s)
        slip, turn = self.moved_since(lifted)
        return {
            "drop_m": offset_before - self.object_minus_palm_z(),
            "object_rise_m": float(data.xpos[scene.object_body][2]) - object_z0,
            "settle_m": settle,
            "slip_m": slip,
            "turn_deg": turn,
            "steps": hold_steps,
        }

    def shake(self) -> tuple[float, float]:
        """Shake the hand (see `Shake`); returns how far the object moved (m) and turned (°)
        relative to the palm."""
        scene, data, shake = self.scene, self.data, self.physics.shake
        centre = data.mocap_pos[scene.mocap].copy()
        before = self.object_pose_in_palm()
        self.drop_reason = "dropped: shake"
        period = shake.duration_s / shake.directions
        omega = 2.0 * math.pi / period
        amplitude = shake.accel_mps2 / omega**2  # x = A sin(ωt) peaks at A ω² acceleration
        for direction in shake.unit_vectors():

            def move(s: float, direction: np.ndarray = direction) -> None:
                data.mocap_pos[scene.mocap] = centre + amplitude * math.sin(2.0 * math.pi * s) * direction

            self.ramp(period, move)
        data.mocap_pos[scene.mocap] = centre
        return self.moved_since(before)

    def object_pose_in_palm(self) -> tuple[np.ndarray, np.ndarray]:
        """The object's position and rotation in the palm's frame."""
        palm = self.scene.palm_body
        rotation = self.data.xmat[palm].reshape(3, 3).T @ self.data.xmat[self.scene.object_body].reshape(3, 3)
        return self.object_in_palm(), rotation

    def moved_since(self, before: tuple[np.ndarray, np.ndarray]) -> tuple[float, float]:
        """How far (m) and by what angle (°) the object moved in the palm's frame since `before`."""
        position, rotation = self.object_pose_in_palm()
        turn = rotation @ before[1].T
        cos = np.clip((np.trace(turn) - 1.0) / 2.0, -1.0, 1.0)
        return float(np.linalg.norm(position - before[0])), float(np.degrees(np.arccos(cos)))

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
            self.step(chunk)
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
            self.step(1)
            if k % CHECK_EVERY == CHECK_EVERY - 1:
                self.monitor()
        self.steps += steps
        self.check()

    def step(self, count: int) -> None:
        """Advance `count` steps; a fixed object is put back in its pose, at rest, around every
        step (kinematically, like a mocap body: exact for any object mass, where a weld
        constraint would give way to the fingers' squeeze by an amount that grows as the object
        gets lighter)."""
        model, data = self.scene.model, self.data
        if self.fixture is None:
            mujoco.mj_step(model, data, nstep=count)
            return
        adr, dof = self.scene.object_qpos, self.object_dof
        for _ in range(count):
            data.qpos[adr : adr + 7] = self.fixture
            data.qvel[dof : dof + 6] = 0.0
            mujoco.mj_step(model, data)
        data.qpos[adr : adr + 7] = self.fixture
        data.qvel[dof : dof + 6] = 0.0

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
        # There is no ground to catch a dropped object: stop the trial once it left the hand.
        if self.in_palm_at_release is not None:
            moved = float(np.linalg.norm(self.object_in_palm() - self.in_palm_at_release))
            if moved > self.dims.reach():
                raise TrialRejected(self.drop_reason)

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
