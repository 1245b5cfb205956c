"""Whole-hand touch at capture time: which taxels feel the object, and what each one reads.

The model follows VinT-6D ("Simulating Touch", App. A.1.2): each taxel is a piezoresistive force
sensor that fires on contact, with a non-linear, monotone response to the normal force on it,
taxel-to-taxel gain differences from manufacturing, and aging ("over time, a greater force is
required for the same level of activation"). The force comes from the contacts MuJoCo resolves;
docs/touch.md gives the equations, the sources of the constants and the measured behaviour.

1. Contacts. The hand–object contacts of the captured state, and of the steps after it within
   `contact_window_s` (`window_steps`: round(window / timestep) samples, at least the capture; the
   steps are simulated on a copy of the state, so the capture is untouched: MuJoCo's contact
   forces jitter from step to step, and a single contact point per geom pair wanders over the
   contact patch), each as (link, point in the link's frame, normal force F_c); the record keeps
   them as `contact_samples` and their number as `contact_steps`.
2. Touching taxels: every taxel of a link in contact at the capture that lies within
   `contact_margin_m` (m) of the object's surface (signed distance d_i < m, negative inside): each
   taxel is its own contact element (VinT-6D: "upon contact the simulation generates a touch
   signal"), so a palm or a phalanx lying along the object touches with every taxel it covers,
   not only where MuJoCo put its one or few contact points.
3. Local force. A link's normal force (the sum of its contacts' forces, averaged over the samples)
   is shared by its touching taxels in proportion to their interference with the object,
       f_i = F_link · (m - d_i) / Σ_j (m - d_j),
   an elastic foundation (pressure grows with the skin's compression). Force is conserved per
   link; the force of a link in contact with no touching taxel (a finger's side or back, where no
   taxel is) is recorded as `unsensed_force_n`.
   Dorsal contact: a contact no taxel of its link faces — none within the link's taxel reach
   (`DORSAL_REACH` times the layout's widest taxel spacing on that link) has its outward normal
   within `DORSAL_CONE_DEG` of the contact normal — presses the link's unsensorised side (the back
   or the far side of a finger, the back or an edge of the palm); its force, averaged over the
   samples per link, is recorded as `dorsal_force_n` (the grasp trial rejects a grasp above the
   activation force: `trial.py`).
4. Reading (a force-sensing resistor in a voltage divider, Interlink's FSR 400 integration):
       r_i = g_i · x^n / (1 + x^n),   x = aging · f_i / f_half,   n = `response_exponent`,
   when aging · f_i >= f_on (`activation_force_n`), else 0: monotone, saturating at g_i, and an
   aged taxel (`aging` < 1) needs more force for the same reading and to fire at all.
   Gains g_i = exp(σ·z_i), z_i ~ N(0, 1) from `numpy.random.default_rng(gain_seed)`, one per taxel
   of the layout; a physical sensor's gains do not change between grasps, so the seed is the
   hand's (the Rust side derives it from the job seed and the hand). Aging is drawn per grasp,
   uniformly from the range `aging` = [min, max], from the trial's seed on a stream of its own
   (`trial_aging`): a dataset's grasps are taken over the sensor's life.
5. Placement deviations (VinT-6D: "slight deviations exist in each sensor's tactile element
   distribution due to manufacturing precision constraints"): each taxel of the layout is moved
   once per hand instance in its surface's tangent plane, N(0, σ²) along each of two tangent axes,
   σ = `position_sigma_m`, rounded to whole micrometres (the layout file's digit), from the hand's
   `gain_seed` on a stream of its own (`taxel_offsets`), so the gains' draws do not shift. The skin
   is a sheet laid on the link: a misplaced taxel still lies on the surface, so it is not moved
   along the normal (on the built-in hands' ≥ 7 mm radii a 0.3 mm tangent step leaves the surface
   by < 7 µm, and its normal tilts by < 3°, both ignored). Everything the skin does (which taxels
   touch, the local forces, the dorsal test, the recorded positions) uses the moved positions.

A taxel is active when its reading is positive. Distances come from MuJoCo (`scene.geom_distance`
between a tiny probe sphere placed on the taxel and each of the object's geoms), so every geom type
an object may be built from works. Only the taxels of links in contact are evaluated, only at the
capture: nothing runs during the rollout.
"""

from __future__ import annotations

import copy
import hashlib
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import mujoco
import numpy as np
import numpy.typing as npt

from vint_engines import contract
from vint_engines.grasp.hand import TOUCH_PROBE, TOUCH_PROBE_RADIUS
from vint_engines.grasp.scene import GraspScene, geom_distance
from vint_engines.grasp.taxels import DECIMALS, TaxelLayout
from vint_engines.protocol import BadInput

Array = npt.NDArray[np.float64]

# Distances are measured exactly up to the margin plus this much (a taxel further does not touch).
DISTANCE_SLACK_M = 1e-3
# A contact is on the sensorised skin when a taxel of its link within DORSAL_REACH × the link's
# widest taxel spacing (the largest nearest-neighbour distance among its taxels: 6-11 mm on the
# built-in hands) faces it, its outward normal within DORSAL_CONE_DEG of the contact normal. The
# built-in layouts cover each finger link's palmar half up to ~10° short of its sides; 30° more
# lets a contact on a link's side count as sensed and flags one past ~110° from the palmar
# direction (docs/touch.md, "Dorsal contact").
DORSAL_REACH = 1.5
DORSAL_CONE_DEG = 30.0
# numpy `SeedSequence` spawn keys of the skin's streams beside a seed's own (the gains draw from
# `default_rng(gain_seed)`, a trial's approach from `default_rng(seed)`; these never shift them).
POSITION_STREAM = 1  # of the hand's gain_seed: the taxels' placement deviations
AGING_STREAM = 1  # of a trial's seed: the grasp's aging
MICROMETRES_PER_M = 10**DECIMALS  # offsets are whole units of the layout file's last digit


@dataclass(frozen=True)
class TouchParams:
    contact_margin_m: float
    contact_window_s: float
    activation_force_n: float
    half_force_n: float
    response_exponent: float
    gain_sigma: float
    aging: tuple[float, float]
    position_sigma_m: float
    gain_seed: int
    min_active_taxels: int

    @staticmethod
    def parse(obj: Any, where: str = "params.touch") -> TouchParams:
        """A grasp task's `touch`: fields, bounds and defaults are `GraspTouch` in the stage
        contract; `parse({})` gives the defaults."""
        fields = contract.validated_part("GraspTouch", obj, where)
        low, high = fields["aging"]
        if low > high:
            raise BadInput(f"{where}.aging: must be [min, max] with min <= max, got {[low, high]}")
        return TouchParams(**{**fields, "aging": (float(low), float(high))})

    def to_json(self) -> dict[str, Any]:
        return {**asdict(self), "aging": list(self.aging)}


@dataclass(frozen=True)
class LinkContact:
    """One hand–object contact as the skin needs it: the link, the point and the contact normal
    (from the link into the object, unit) in the link's frame (m), and the normal force (N)."""

    link: str
    point: Array
    force_n: float
    normal: Array


def taxel_gains(count: int, sigma: float, seed: int) -> Array:
    """Per-taxel gains: log-normal with median 1 and log-spread `sigma`."""
    return np.random.default_rng(seed).lognormal(mean=0.0, sigma=sigma, size=count)


def taxel_offsets(normals: Array, sigma: float, seed: int) -> npt.NDArray[np.int64]:
    """Each taxel's placement deviation (whole micrometres, link frame): N(0, sigma²) along each
    of two orthonormal axes of the tangent plane of its unit normal, none along the normal; drawn
    from `seed` (the hand's) on the POSITION_STREAM, two normals per taxel in layout order."""
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(POSITION_STREAM,)))
    draws = rng.standard_normal((len(normals), 2))
    # A helper axis per taxel: the coordinate axis least aligned with its normal.
    helper = np.eye(3)[np.argmin(np.abs(normals), axis=1)]
    first = np.cross(normals, helper)
    first /= np.linalg.norm(first, axis=1, keepdims=True)
    second = np.cross(normals, first)
    offsets = sigma * (draws[:, :1] * first + draws[:, 1:] * second)
    return np.rint(offsets * MICROMETRES_PER_M).astype(np.int64)


def deviated_layout(layout: TaxelLayout, offsets_um: npt.NDArray[np.int64]) -> TaxelLayout:
    """The hand instance's layout: `layout` with each taxel moved by its offset (µm)."""
    positions = layout.positions + offsets_um / MICROMETRES_PER_M
    return TaxelLayout(layout.links, positions, layout.normals, layout.regions)


def trial_aging(aging: tuple[float, float], seed: int) -> float:
    """A grasp's aging: uniform in `aging` = [min, max], from the trial's `seed` on the
    AGING_STREAM; exactly `min` when the range is one value."""
    low, high = aging
    if low == high:
        return low
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(AGING_STREAM,)))
    return float(rng.uniform(low, high))


def response(force: Array, gains: Array, params: TouchParams, aging: float) -> Array:
    """Taxel readings for local normal forces (N): `gain · x^n / (1 + x^n)` with
    `x = aging · force / half_force_n`, and 0 where `aging · force` is below the activation force
    or not positive. Finite for every finite force (written as a logistic in log-force)."""
    felt = aging * np.asarray(force, dtype=np.float64)
    fires = (felt > 0.0) & (felt >= params.activation_force_n)
    log_ratio = np.log(np.where(fires, felt, 1.0)) - np.log(params.half_force_n)
    # x^n / (1 + x^n) = 1 / (1 + exp(-n ln x)); the clip keeps exp finite for forces near zero.
    share = 1.0 / (1.0 + np.exp(np.minimum(-params.response_exponent * log_ratio, 700.0)))
    return np.where(fires, gains * share, 0.0)


def shared_force(interference: Array, force: float) -> Array:
    """A link's normal force `force` (N) shared among its touching taxels in proportion to their
    `interference` with the object (m, > 0): an elastic foundation, pressure ∝ compression."""
    return force * interference / interference.sum()


def link_frame_contacts(
    scene: GraspScene, data: mujoco.MjData, contacts: list[dict[str, Any]]
) -> list[LinkContact]:
    """`finger_contacts` records (world frame) moved into their links' frames."""
    moved = []
    for contact in contacts:
        body = scene.link_bodies[contact["link"]]
        rotation = data.xmat[body].reshape(3, 3)
        local = rotation.T @ (np.asarray(contact["p"]) - data.xpos[body])
        normal = rotation.T @ np.asarray(contact["normal"])
        moved.append(LinkContact(contact["link"], local, float(contact["force"]), normal))
    return moved


def widest_spacing(points: Array) -> float:
    """The largest distance from a taxel to its nearest neighbour among `points` (m); 0 for one."""
    if len(points) < 2:
        return 0.0
    apart = np.linalg.norm(points[:, None] - points[None], axis=2)
    np.fill_diagonal(apart, np.inf)
    return float(apart.min(axis=1).max())


def window_steps(window_s: float, timestep: float) -> int:
    """Contact samples a window of `window_s` seconds takes at `timestep`: the capture and the
    steps after it, at least the capture alone."""
    return max(1, round(window_s / timestep))


def held_contacts(
    scene: GraspScene,
    data: mujoco.MjData,
    steps: int,
    contacts_of: Callable[[GraspScene, mujoco.MjData], list[dict[str, Any]]],
) -> list[list[LinkContact]]:
    """The hand–object contacts of the captured state and of the `steps - 1` simulation steps after
    it, with the controls held. The steps run on a copy of `data`, so the capture is untouched;
    sampling stops early if the copy reports a MuJoCo warning or a non-finite state."""
    samples = [link_frame_contacts(scene, data, contacts_of(scene, data))]
    if steps <= 1:
        return samples
    scratch = copy.copy(data)
    warnings = scratch.warning.number.copy()
    for _ in range(steps - 1):
        mujoco.mj_step(scene.model, scratch)
        if (scratch.warning.number != warnings).any() or not np.isfinite(scratch.qacc).all():
            break
        samples.append(link_frame_contacts(scene, scratch, contacts_of(scene, scratch)))
    return samples


class Skin:
    """A hand instance's taxels bound to a compiled scene: the layout's taxels moved by their
    placement deviations (`layout`; `offsets_um` from the nominal one), with the sensor's gains.
    `elapsed_s` adds up the time spent reading (a metric; it never enters an output)."""

    def __init__(self, scene: GraspScene, layout: TaxelLayout, params: TouchParams) -> None:
        model = scene.model
        unknown = set(layout.links) - set(scene.link_bodies)
        if unknown:
            raise BadInput(f"taxel layout names links the hand lacks: {sorted(unknown)}")
        self.offsets_um = taxel_offsets(layout.normals, params.position_sigma_m, params.gain_seed)
        layout = deviated_layout(layout, self.offsets_um)
        self.scene, self.layout, self.params = scene, layout, params
        self.gains = taxel_gains(len(layout), params.gain_sigma, params.gain_seed)
        self.by_link = layout.indices_by_link()
        self.taxel_body = np.array([scene.link_bodies[link] for link in layout.links], dtype=np.intp)
        self.object_geoms = list(scene.object_geoms)
        self.probe = model.geom(TOUCH_PROBE).id
        self.reach = {
            link: DORSAL_REACH * widest_spacing(layout.positions[rows]) for link, rows in self.by_link.items()
        }
        self.elapsed_s = 0.0

    def deviation(self) -> dict[str, Any]:
        """How this hand instance's taxels deviate from the layout, for `hand.taxels`: σ, the seed
        and stream they were drawn from, and the SHA-256 of the moved layout written as a layout
        file (`TaxelLayout.to_csv`: the nominal layout plus each trial's `position_offsets_um`)."""
        return {
            "position_sigma_m": self.params.position_sigma_m,
            "seed": self.params.gain_seed,
            "stream": f"numpy SeedSequence(seed, spawn_key=({POSITION_STREAM},))",
            "sha256": hashlib.sha256(self.layout.to_csv().encode("utf-8")).hexdigest(),
        }

    def faces_skin(self, contact: LinkContact) -> bool:
        """Whether a taxel of the contact's link faces it (see DORSAL_REACH): a link with no
        taxels has no sensorised side."""
        rows = self.by_link.get(contact.link)
        if rows is None:
            return False
        near = np.linalg.norm(self.layout.positions[rows] - contact.point, axis=1) <= self.reach[contact.link]
        facing = self.layout.normals[rows] @ contact.normal >= np.cos(np.radians(DORSAL_CONE_DEG))
        return bool((near & facing).any())

    def dorsal_forces(self, samples: list[list[LinkContact]]) -> dict[str, float]:
        """Per link, the mean normal force (N) over `samples` of its contacts no taxel faces."""
        forces: dict[str, float] = {}
        for contact in (c for contacts in samples for c in contacts if not self.faces_skin(c)):
            forces[contact.link] = forces.get(contact.link, 0.0) + contact.force_n / len(samples)
        return dict(sorted(forces.items()))

    def read(self, data: mujoco.MjData, samples: list[list[LinkContact]], aging: float) -> dict[str, Any]:
        """The `touch` record of the captured state `data`; `samples` are the contacts of the
        capture (first) and of the steps averaged with it (`held_contacts`); `aging` the grasp's
        (`trial_aging`)."""
        started = time.perf_counter()
        params = self.params
        in_contact = {c.link for c in samples[0] if c.force_n > 0.0} & set(self.by_link)
        links = [link for link in self.by_link if link in in_contact]
        indices = np.concatenate([self.by_link[link] for link in links] or [np.zeros(0, np.intp)])
        indices = np.sort(indices)
        world = self._to_world(data, indices, self.layout.positions, points=True)
        cap = params.contact_margin_m + DISTANCE_SLACK_M
        distance = object_distances(self.scene.model, data, self.probe, self.object_geoms, world, cap)
        touching = distance < params.contact_margin_m
        indices, distance = indices[touching], distance[touching]
        force, contact_force, unsensed = self._local_forces(
            indices, params.contact_margin_m - distance, samples
        )
        readings = np.zeros(len(self.layout))
        readings[indices] = response(force, self.gains[indices], params, aging)
        active = readings[indices] > 0.0
        indices, distance, force = indices[active], distance[active], force[active]
        record = {
            "contact_margin_m": params.contact_margin_m,
            "aging": aging,
            "position_offsets_um": self.offsets_um.tolist(),
            "contact_steps": len(samples),
            "contact_force_n": contact_force,
            "unsensed_force_n": unsensed,
            "dorsal_force_n": self.dorsal_forces(samples),
            "contact_samples": [
                [
                    {
                        "link": c.link,
                        "p_link": c.point.tolist(),
                        "n_link": c.normal.tolist(),
                        "force_n": c.force_n,
                    }
                    for c in contacts
                ]
                for contacts in samples
            ],
            "active": self._active_json(data, indices, distance, force, readings),
            "readings": readings.tolist(),
            "active_count": len(indices),
        }
        self.elapsed_s += time.perf_counter() - started
        return record

    def _local_forces(
        self, indices: npt.NDArray[np.intp], interference: Array, samples: list[list[LinkContact]]
    ) -> tuple[Array, float, float]:
        """Each touching taxel's force, the mean total contact force on the skin's links, and the
        part of it on links with no touching taxel (N); forces are averaged over the samples."""
        force = np.zeros(len(indices))
        total = unsensed = 0.0
        link_force: dict[str, float] = {}
        for contact in (c for contacts in samples for c in contacts if c.link in self.by_link):
            link_force[contact.link] = link_force.get(contact.link, 0.0) + contact.force_n / len(samples)
        for link in sorted(link_force):  # a fixed order of sums
            row = np.flatnonzero(np.isin(indices, self.by_link[link]))
            total += link_force[link]
            if len(row):
                force[row] = shared_force(interference[row], link_force[link])
            else:
                unsensed += link_force[link]
        return force, total, unsensed

    def _to_world(
        self, data: mujoco.MjData, indices: npt.NDArray[np.intp], vectors: Array, *, points: bool
    ) -> Array:
        """Link-frame taxel points (or directions) to the world frame."""
        body = self.taxel_body[indices]
        world = np.einsum("nij,nj->ni", data.xmat[body].reshape(-1, 3, 3), vectors[indices])
        return world + data.xpos[body] if points else world

    def _active_json(
        self,
        data: mujoco.MjData,
        indices: npt.NDArray[np.intp],
        distance: Array,
        force: Array,
        readings: Array,
    ) -> list[dict[str, Any]]:
        palm = self.scene.palm_body
        to_palm = data.xmat[palm].reshape(3, 3)  # rows @ to_palm == R_palm^T @ row
        p_palm = (
            self._to_world(data, indices, self.layout.positions, points=True) - data.xpos[palm]
        ) @ to_palm
        n_palm = self._to_world(data, indices, self.layout.normals, points=False) @ to_palm
        return [
            {
                "taxel": i,
                "link": self.layout.links[i],
                "region": self.layout.regions[i],
                "p_palm": p,
                "n_palm": n,
                "reading": r,
                "force_n": f,
                "distance_m": d,
            }
            for i, d, f, p, n, r in zip(
                indices.tolist(),
                distance.tolist(),
                force.tolist(),
                p_palm.tolist(),
                n_palm.tolist(),
                readings[indices].tolist(),
                strict=True,
            )
        ]


def object_distances(
    model: mujoco.MjModel, data: mujoco.MjData, probe: int, geoms: list[int], points: Array, cap: float
) -> Array:
    """Signed distance (m, negative inside) from each world point to the union of `geoms`, exact
    below `cap` and `>= cap` otherwise. Points whose distance to a geom's bounding box (which holds
    the geom) is at least `cap` are not queried; the others are measured with `geom_distance`
    from the `probe` sphere placed on the point (its centre distance is the result plus its radius)."""
    distance = np.full(len(points), np.inf)
    for geom in geoms:
        aabb = model.geom_aabb[geom]
        local = (points - data.geom_xpos[geom]) @ data.geom_xmat[geom].reshape(3, 3) - aabb[:3]
        outside = np.maximum(np.abs(local) - aabb[3:], 0.0)
        for k in np.flatnonzero((outside**2).sum(axis=1) < cap**2):
            data.geom_xpos[probe] = points[k]
            measured = geom_distance(model, data, probe, geom, cap) + TOUCH_PROBE_RADIUS
            distance[k] = min(distance[k], measured)
    return distance
