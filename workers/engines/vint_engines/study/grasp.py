"""Grasp physics: error against run time for the timestep and the contact solver's settings.

The same trials (same hands, objects and seeds) run under each `SolverConfig`; every trial is
compared with the fine reference (0.25 ms, Newton, 100 iterations, elliptic cone) on what a
dataset keeps: the object's pose in the palm frame after the hold, the success label and the set
of active taxels, plus the deepest contact penetration seen during the rollout. Cost is wall and
CPU time per accepted grasp (`time.perf_counter` / `time.process_time` around each trial).

Each trial runs twice: once timed and untouched, once with a MuJoCo control callback that tracks
the deepest penetration at every step (the callback would distort the timing). The second run must
reproduce the first (`replay_match`), which checks the study's own determinism.

Randomness comes only from `numpy.random.default_rng(seed)`: the trial seeds, and the trials'
own sampling inside `run_trial`. Everything except the timings is deterministic.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from vint_engines.grasp.hands import HANDS as HANDS_KNOWN
from vint_engines.grasp.hands import HandDims, hand_dims
from vint_engines.grasp.hands.catalog import read_hand_catalog
from vint_engines.grasp.scene import GraspScene, build_scene
from vint_engines.grasp.taxels import TaxelLayout, parse_layout
from vint_engines.grasp.touch import Skin, TouchParams
from vint_engines.grasp.trial import Physics, run_trial
from vint_engines.objects import Symmetries, load_catalog
from vint_engines.poses import quat_to_matrix
from vint_engines.study import report

STUDY_SEED = 20261122
HANDS = ("trx3", "allegro")
OBJECTS = ("tomato_soup_can", "mustard_bottle", "mug")

SOLVERS = {"newton": mujoco.mjtSolver.mjSOL_NEWTON, "cg": mujoco.mjtSolver.mjSOL_CG}
CONES = {"elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC, "pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL}


@dataclass(frozen=True)
class SolverConfig:
    """One physics setting: the timestep, the constraint solver's options, whether the engine may
    rerun an unstable trial at half the timestep (`retries`; 0 measures the timestep as it is) and
    the hand's contact time constant (`skin_timeconst_s`; None: the engine's default)."""

    timestep: float
    solver: str = "newton"
    iterations: int = 100
    cone: str = "elliptic"
    retries: int = 0
    skin_timeconst_s: float | None = None

    @property
    def name(self) -> str:
        parts = [f"dt{1e3 * self.timestep:g}ms"]
        parts += [self.solver] if self.solver != "newton" else []
        parts += [f"it{self.iterations}"] if self.iterations != 100 else []
        parts += [self.cone] if self.cone != "elliptic" else []
        parts += [f"retry{self.retries}"] if self.retries else []
        parts += [f"tc{1e3 * self.skin_timeconst_s:g}ms"] if self.skin_timeconst_s is not None else []
        return "-".join(parts)

    def apply(self, model: mujoco.MjModel) -> None:
        """Set the solver options on a compiled model (`run_trial` sets the timestep and cone)."""
        model.opt.solver = SOLVERS[self.solver]
        model.opt.iterations = self.iterations
        model.opt.cone = CONES[self.cone]

    def physics(self) -> Physics:
        """The engine's default physics with this configuration's changes (those the engine's
        `Physics` has: the grasp engine is still growing options)."""
        base = Physics.parse({})
        known = {f.name for f in dataclasses.fields(Physics)}
        changes: dict[str, Any] = {"timestep": self.timestep, "cone": self.cone, "max_retries": self.retries}
        if self.skin_timeconst_s is not None:
            changes["hand_solref_timeconst"] = self.skin_timeconst_s
        return dataclasses.replace(base, **{k: v for k, v in changes.items() if k in known})


REFERENCE = SolverConfig(timestep=0.00025)
# The engine as it runs by default: 1 ms, Newton, elliptic cone, up to 2 reruns at half the step.
DEFAULT = SolverConfig(timestep=0.001, retries=2)
# The engine refuses a timestep above half the hand's contact time constant (5 ms): coarser steps
# are studied with the softer skin MuJoCo itself would clamp the time constant to (2 timesteps).
COARSEST = SolverConfig(0.008, skin_timeconst_s=0.016)
FULL_CONFIGS = (
    REFERENCE,
    SolverConfig(0.0005),
    SolverConfig(0.001),
    DEFAULT,
    SolverConfig(0.002),
    SolverConfig(0.002, retries=2),
    SolverConfig(0.0025),
    SolverConfig(0.004, skin_timeconst_s=0.008),
    COARSEST,
    SolverConfig(0.002, solver="cg"),
    SolverConfig(0.002, iterations=50),
    SolverConfig(0.002, iterations=10),
    SolverConfig(0.002, cone="pyramidal"),
    SolverConfig(0.001, cone="pyramidal"),
)
QUICK_CONFIGS = (REFERENCE, DEFAULT, SolverConfig(0.002), COARSEST, SolverConfig(0.002, solver="cg"))


@dataclass(frozen=True)
class TrialOutcome:
    """What the study keeps of one trial."""

    accepted: bool
    reason: str | None
    object_in_palm: tuple[np.ndarray, np.ndarray] | None  # (position m, rotation matrix)
    active: frozenset[int]
    max_penetration_m: float
    timestep_used: float
    retries: int
    steps: int
    wall_s: float
    cpu_s: float


def trial_seeds(count: int, seed: int = STUDY_SEED) -> list[int]:
    return [int(s) for s in np.random.default_rng(seed).integers(0, 2**63 - 1, size=count)]


def object_in_palm(record: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """The object's pose in the palm frame from a trial's world poses."""
    palm_r = quat_to_matrix(record["hand_pose"]["q"])
    obj_r = quat_to_matrix(record["object_pose"]["q"])
    offset = np.asarray(record["object_pose"]["p"]) - np.asarray(record["hand_pose"]["p"])
    return palm_r.T @ offset, palm_r.T @ obj_r


class PenetrationProbe:
    """A MuJoCo control callback recording the deepest contact (m) over every simulated step, and
    how many steps it saw: the physics work of a trial, the cost a coarser timestep saves.

    MuJoCo calls it from `mj_forward` too, which the trial uses at time 0 to try out hand
    placements before simulating: only states after the first step (time > 0) count."""

    def __init__(self) -> None:
        self.deepest = 0.0
        self.steps = 0

    def __call__(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        if data.time > 0.0:
            self.steps += 1
            if data.ncon:
                self.deepest = max(self.deepest, -float(np.min(data.contact.dist)))


def run_one(scene: GraspScene, data: mujoco.MjData, physics: Physics, skin: Skin, seed: int) -> TrialOutcome:
    """Run a trial timed, then again under the penetration probe; the two must agree."""
    wall, cpu = time.perf_counter(), time.process_time()
    record = run_trial(scene, data, physics, skin, 0, seed)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    probe = PenetrationProbe()
    mujoco.set_mjcb_control(probe)
    try:
        replay = run_trial(scene, data, physics, skin, 0, seed)
    finally:
        mujoco.set_mjcb_control(None)
    if replay != record:
        raise RuntimeError(f"trial seed {seed} did not replay identically under {scene.model.opt}")
    accepted = bool(record["accepted"])
    stability = record.get("stability", {})
    return TrialOutcome(
        accepted=accepted,
        reason=record["reason"],
        object_in_palm=object_in_palm(record) if accepted else None,
        active=frozenset(t["taxel"] for t in record["touch"]["active"]) if accepted else frozenset(),
        max_penetration_m=max(probe.deepest, 0.0),
        timestep_used=float(stability.get("timestep_used", physics.timestep)),
        retries=int(stability.get("retries", 0)),
        steps=probe.steps,
        wall_s=wall,
        cpu_s=cpu,
    )


NO_SYMMETRY = Symmetries()


def rotation_error_deg(r: np.ndarray, r0: np.ndarray, symmetries: Symmetries = NO_SYMMETRY) -> float:
    """Angle between two object orientations up to the textured object's symmetries (as BOP's
    ADD-S treats them): with a continuous axis only where that axis points counts (after any of the
    discrete flips); otherwise the smallest angle over the discrete symmetries and the identity.
    Computed from differences (not `acos` of a dot product), so equal orientations give exactly 0."""
    flips = [np.eye(3)] + [np.array(m).reshape(4, 4)[:3, :3] for m in symmetries.discrete]
    if symmetries.continuous:
        axis = np.array(symmetries.continuous[0][0])
        b = r0 @ axis
        return min(
            math.degrees(
                math.atan2(float(np.linalg.norm(np.cross(r @ g @ axis, b))), float(r @ g @ axis @ b))
            )
            for g in flips
        )
    # ||R - R0||_F = 2·sqrt(2)·sin(θ/2) for rotations R, R0 at angle θ.
    chords = (float(np.linalg.norm(r @ g - r0)) / (2.0 * math.sqrt(2.0)) for g in flips)
    return min(math.degrees(2.0 * math.asin(min(1.0, chord))) for chord in chords)


def compare(
    outcome: TrialOutcome, reference: TrialOutcome, symmetries: Symmetries = NO_SYMMETRY
) -> dict[str, float | None]:
    """Errors of a trial against the reference run of the same seed; pose and taxel errors only
    where both grasps were accepted."""
    errors: dict[str, float | None] = {
        "label_agrees": float(outcome.accepted == reference.accepted),
        "pos_err_mm": None,
        "rot_err_deg": None,
        "taxel_iou": None,
    }
    if outcome.object_in_palm is not None and reference.object_in_palm is not None:
        (p, r), (p0, r0) = outcome.object_in_palm, reference.object_in_palm
        union = outcome.active | reference.active
        errors.update(
            pos_err_mm=1e3 * float(np.linalg.norm(p - p0)),
            rot_err_deg=rotation_error_deg(r, r0, symmetries),
            taxel_iou=len(outcome.active & reference.active) / len(union) if union else 1.0,
        )
    return errors


def run_study(
    hands: Sequence[str], objects: Sequence[str], seeds: Sequence[int], configs: Sequence[SolverConfig]
) -> Iterator[dict[str, Any]]:
    """One row per configuration × hand × object × seed, the reference configuration first."""
    if configs[0] != REFERENCE:
        raise ValueError("the first configuration must be the reference")
    catalog = load_catalog()
    for hand_name in hands:
        hand = hand_dims(hand_name)
        layout = taxel_layout(hand)
        for object_name in objects:
            spec = catalog[object_name]
            scene = build_scene(hand, spec)  # the study's own: its options change
            data = mujoco.MjData(scene.model)
            skin = Skin(scene, layout, TouchParams.parse({}))
            references: dict[int, TrialOutcome] = {}
            for config in configs:
                config.apply(scene.model)
                physics = config.physics()
                for seed in seeds:
                    outcome = run_one(scene, data, physics, skin, seed)
                    references.setdefault(seed, outcome)
                    errors = compare(outcome, references[seed], spec.symmetries)
                    yield row(config, hand_name, object_name, seed, outcome, errors)


def taxel_layout(hand: HandDims) -> TaxelLayout:
    """The hand's taxel layout as the catalog names it (as the grasp engine reads it)."""
    path = read_hand_catalog()[hand.name].taxels_path()
    return parse_layout(path.read_text(encoding="utf-8"), hand.link_names(), str(path))


def row(
    config: SolverConfig, hand: str, obj: str, seed: int, outcome: TrialOutcome, errors: dict[str, Any]
) -> dict[str, Any]:
    return {
        "config": config.name,
        "timestep_ms": 1e3 * config.timestep,
        "solver": config.solver,
        "iterations": config.iterations,
        "cone": config.cone,
        "skin_timeconst_ms": "" if config.skin_timeconst_s is None else 1e3 * config.skin_timeconst_s,
        "max_retries": config.retries,
        "hand": hand,
        "object": obj,
        "seed": seed,
        "accepted": int(outcome.accepted),
        "reason": outcome.reason or "",
        "active_taxels": len(outcome.active),
        **errors,
        "max_penetration_mm": 1e3 * outcome.max_penetration_m,
        "timestep_used_ms": 1e3 * outcome.timestep_used,
        "retries": outcome.retries,
        "steps": outcome.steps,
        "wall_s": outcome.wall_s,
        "cpu_s": outcome.cpu_s,
    }


def main(out: Path, quick: bool, hands: Sequence[str], objects: Sequence[str], seeds: int | None) -> int:
    configs = QUICK_CONFIGS if quick else FULL_CONFIGS
    unknown = [h for h in hands if h not in HANDS_KNOWN] + [o for o in objects if o not in load_catalog()]
    if unknown:
        print(f"study grasp: unknown hands or objects {unknown}", file=sys.stderr)
        return 2
    seed_list = trial_seeds(seeds if seeds is not None else (2 if quick else 8))
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    rows = []
    for r in run_study(hands, objects, seed_list, configs):
        rows.append(r)
        print(
            f"{r['config']:>22} {r['hand']:>8} {r['object']:>16} accepted={r['accepted']} "
            f"pos_err_mm={r['pos_err_mm']} wall_s={r['wall_s']:.3f}",
            flush=True,
        )
    written = report.write_all(out, rows, [c.name for c in configs], REFERENCE.name, DEFAULT.name)
    print(f"study done in {time.perf_counter() - started:.1f} s: " + ", ".join(str(p) for p in written))
    return 0
