"""Whole-hand touch at capture time: which taxels feel the object, and what each one reads.

The model follows VinT-6D ("Simulating Touch"): what a dataset needs from touch is *where* the
hand feels the object (active taxels as a point cloud in the palm frame), plus readings with the
real sensor's character — a non-linear, monotone response to pressure, taxel-to-taxel gain
differences from manufacturing, and aging ("over time, a greater force is required for the same
level of activation").

- Active: a taxel is active when the object's surface is closer than the sensing depth d_s
  (`sensing_depth_m`): its signed distance d to the object (negative inside) is < d_s. The link's
  collision surface stands for the skin fully compressed; the skin's free surface — the compliant
  cover and the taxel domes (the paper's taxels are small cylinders topped by hemispheres) — lies
  d_s outside it, and a taxel fires when the object indents it. The default, 3 mm, is the order of
  a curved piezoresistive skin's thickness; it makes a power grasp of a can press 100-170 taxels
  (a flat palm against a 66 mm can is within 3 mm over a ~28 mm wide band) rather than the few
  that MuJoCo's contact points alone would mark.
- Reading: with indentation δ = d_s - d > 0,
      r = gain_i · (1 - exp(-aging · δ / δ0)),   δ0 = `response_depth_m`,
  monotone and saturating at gain_i; `aging` in (0, 1] is the sensitivity left (1: new sensor),
  so an aged sensor needs a deeper indentation — more force — for the same reading. Inactive
  taxels read 0.
- Gains: gain_i = exp(σ·z_i), z_i ~ N(0, 1) drawn by `numpy.random.default_rng(gain_seed)`, one
  per taxel of the layout, σ = `gain_sigma`; a physical sensor's gains do not change between
  grasps, so the seed is the hand's (the Rust side derives it from the job seed and the hand).

Distances come from MuJoCo (`mj_geomDistance` between a tiny probe sphere placed on the taxel and
each of the object's geoms), so every geom type the object may be built from — primitives,
compounds, convex mesh pieces — works. Only links that touch the object (a MuJoCo contact) or come
within d_s of it are evaluated, and only once, on the captured state: nothing runs during the
rollout.
"""

from __future__ import annotations

import time
from collections.abc import Set
from dataclasses import asdict, dataclass
from typing import Any

import mujoco
import numpy as np
import numpy.typing as npt

from vint_engines import contract
from vint_engines.grasp.hand import TOUCH_PROBE, TOUCH_PROBE_RADIUS
from vint_engines.grasp.scene import GraspScene
from vint_engines.grasp.taxels import TaxelLayout
from vint_engines.protocol import BadInput

Array = npt.NDArray[np.float64]


@dataclass(frozen=True)
class TouchParams:
    sensing_depth_m: float
    response_depth_m: float
    gain_sigma: float
    aging: float
    gain_seed: int
    min_active_taxels: int

    @staticmethod
    def parse(obj: Any, where: str = "params.touch") -> TouchParams:
        """A grasp task's `touch`: fields, bounds and defaults are `GraspTouch` in the stage
        contract; `parse({})` gives the defaults."""
        return TouchParams(**contract.validated_part("GraspTouch", obj, where))

    def to_json(self) -> dict[str, float | int]:
        return asdict(self)


def taxel_gains(count: int, sigma: float, seed: int) -> Array:
    """Per-taxel gains: log-normal with median 1 and log-spread `sigma`."""
    return np.random.default_rng(seed).lognormal(mean=0.0, sigma=sigma, size=count)


def response(indentation: Array, gains: Array, params: TouchParams) -> Array:
    """Taxel readings for indentations (m, > 0 when active); 0 where the indentation is <= 0."""
    pressed = np.maximum(indentation, 0.0)
    return gains * -np.expm1(-params.aging * pressed / params.response_depth_m)


class Skin:
    """A hand's taxels bound to a compiled scene, with the sensor's gains. `elapsed_s` adds up the
    time spent reading (a metric; it never enters an output)."""

    def __init__(self, scene: GraspScene, layout: TaxelLayout, params: TouchParams) -> None:
        model = scene.model
        unknown = set(layout.links) - set(scene.link_bodies)
        if unknown:
            raise BadInput(f"taxel layout names links the hand lacks: {sorted(unknown)}")
        self.scene, self.layout, self.params = scene, layout, params
        self.gains = taxel_gains(len(layout), params.gain_sigma, params.gain_seed)
        self.by_link = layout.indices_by_link()
        self.taxel_body = np.array([scene.link_bodies[link] for link in layout.links], dtype=np.intp)
        self.object_geoms = list(scene.object_geoms)
        self.link_geoms = {
            link: [int(g) for g in np.flatnonzero((model.geom_bodyid == body) & (model.geom_contype != 0))]
            for link, body in scene.link_bodies.items()
        }
        self.probe = model.geom(TOUCH_PROBE).id
        self.elapsed_s = 0.0

    def read(self, data: mujoco.MjData, contact_links: Set[str]) -> dict[str, Any]:
        """The `touch` record of the current state; `contact_links` are the links MuJoCo reports in
        contact with the object."""
        started = time.perf_counter()
        depth = self.params.sensing_depth_m
        links = [link for link in self.by_link if link in contact_links or self._near(data, link)]
        indices = np.sort(np.concatenate([self.by_link[link] for link in links] or [np.zeros(0, np.intp)]))
        world = self._to_world(data, indices, self.layout.positions, points=True)
        distance = object_distances(self.scene.model, data, self.probe, self.object_geoms, world, depth)
        active = distance < depth
        indices, distance = indices[active], distance[active]
        readings = np.zeros(len(self.layout))
        readings[indices] = response(depth - distance, self.gains[indices], self.params)
        record = {
            "sensing_depth_m": depth,
            "active": self._active_json(data, indices, distance, readings),
            "readings": readings.tolist(),
            "active_count": len(indices),
        }
        self.elapsed_s += time.perf_counter() - started
        return record

    def _near(self, data: mujoco.MjData, link: str) -> bool:
        """Whether a link without contacts still comes within the sensing depth of the object."""
        depth = self.params.sensing_depth_m
        model = self.scene.model
        return any(
            mujoco.mj_geomDistance(model, data, g, o, depth, None) < depth
            for g in self.link_geoms[link]
            for o in self.object_geoms
        )

    def _to_world(
        self, data: mujoco.MjData, indices: npt.NDArray[np.intp], vectors: Array, *, points: bool
    ) -> Array:
        """Link-frame taxel points (or directions) to the world frame."""
        body = self.taxel_body[indices]
        world = np.einsum("nij,nj->ni", data.xmat[body].reshape(-1, 3, 3), vectors[indices])
        return world + data.xpos[body] if points else world

    def _active_json(
        self, data: mujoco.MjData, indices: npt.NDArray[np.intp], distance: Array, readings: Array
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
                "distance_m": d,
            }
            for i, d, p, n, r in zip(
                indices.tolist(),
                distance.tolist(),
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
    the geom) is at least `cap` are not queried; the others are measured with `mj_geomDistance`
    from the `probe` sphere placed on the point (its centre distance is the result plus its radius)."""
    distance = np.full(len(points), np.inf)
    for geom in geoms:
        aabb = model.geom_aabb[geom]
        local = (points - data.geom_xpos[geom]) @ data.geom_xmat[geom].reshape(3, 3) - aabb[:3]
        outside = np.maximum(np.abs(local) - aabb[3:], 0.0)
        for k in np.flatnonzero((outside**2).sum(axis=1) < cap**2):
            data.geom_xpos[probe] = points[k]
            measured = mujoco.mj_geomDistance(model, data, probe, geom, cap, None) + TOUCH_PROBE_RADIUS
            distance[k] = min(distance[k], measured)
    return distance
