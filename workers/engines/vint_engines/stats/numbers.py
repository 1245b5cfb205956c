"""The dataset's statistics as plain numbers (the content of `stats.json`): histograms, summaries
and coverage computed from a `Dataset`'s records, with every bin rule written here once so the
plots and the table show the same counts.

Bins are closed on the left: bin k holds `edges[k] <= x < edges[k + 1]`, and the last bin also
holds its right edge. Occlusion bins are found as `min(floor(10 * occlusion), 9)` rather than by
comparing with rounded edges, so 0.3 falls in the 30–40 % bin however 0.3 is stored.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from vint_engines.stats import hand
from vint_engines.stats.dataset import Array, Dataset, Grasp, Pair, View
from vint_engines.stats.summaries import DECIMALS, histogram, summary

OCCLUSION_BINS = 10  # 10 % each, as the paper reports occlusion (10–90 %)
# The viewing direction's sphere in equal-area cells: 12 azimuth sectors of 30° × 6 bands of equal
# height in sin(elevation) (Archimedes: a band's area is proportional to its height), so every cell
# covers 4π/72 sr and an even spread of views gives an even map.
AZIMUTH_BINS = 12
SIN_ELEVATION_BINS = 6
# Distance bins: the finest of these widths (metres) that spans the data in at most 20 bins.
DISTANCE_WIDTHS = (0.01, 0.02, 0.025, 0.05, 0.1, 0.2, 0.25, 0.5, 1.0, 2.0, 5.0)
DISTANCE_MAX_BINS = 20
EDGE_SLACK = 1e-9
REGION_ORDER = ("tip", "pulp", "palm")  # the taxel layout's regions (grasp/taxels.py), finger first


def compute(dataset: Dataset) -> dict[str, Any]:
    views, grasps = dataset.views, dataset.grasps
    objects = sorted({v.object for v in views} | {g.object for g in grasps})
    hands = sorted({v.hand for v in views} | {g.hand for g in grasps})
    return {
        "layout": dataset.layout,
        "counts": {
            "samples": len(views),
            "grasps": len(grasps),
            "objects": len(objects),
            "hands": len(hands),
        },
        "objects": objects,
        "hands": hands,
        "occlusion": occlusion_stats(views, hands, objects),
        "distance_m": distance_stats(views, hands),
        "orientation": orientation_stats(views, objects),
        "taxels": taxel_stats(grasps, hands),
        "pairs": None if dataset.pairs is None else pair_stats(dataset.pairs),
        "in_hand": hand.in_hand_stats(grasps, hands, objects),
        "camera_palm": hand.camera_stats(views, hands),
        "grasp_types": grasp_type_stats(grasps, hands),
        "per_object": object_counts(views, grasps, hands, objects),
        "per_environment": environment_counts(views, hands),
    }


def occlusion_bin(occlusion: float) -> int:
    return min(max(math.floor(OCCLUSION_BINS * occlusion), 0), OCCLUSION_BINS - 1)


def occlusion_stats(views: Sequence[View], hands: Sequence[str], objects: Sequence[str]) -> dict[str, Any]:
    def counts(selected: Iterable[View]) -> list[int]:
        tally = Counter(occlusion_bin(v.occlusion) for v in selected)
        return [tally[k] for k in range(OCCLUSION_BINS)]

    pairs = sorted({(v.object, v.hand) for v in views})
    return {
        "edges": [k / OCCLUSION_BINS for k in range(OCCLUSION_BINS + 1)],
        "counts": counts(views),
        "by_hand": {h: counts(v for v in views if v.hand == h) for h in hands},
        "by_object": {o: counts(v for v in views if v.object == o) for o in objects},
        "summary": summary([v.occlusion for v in views]),
        "by_pair": [
            {
                "object": o,
                "hand": h,
                "summary": summary([v.occlusion for v in views if (v.object, v.hand) == (o, h)]),
            }
            for o, h in pairs
        ],
    }


def distance(view: View) -> float:
    """Camera centre to the object frame's origin, metres."""
    return float(np.linalg.norm(view.t_m2c))


def distance_edges(values: Sequence[float]) -> list[float]:
    """Edges on multiples of the width, from the one at or below the nearest view to the one above
    the farthest (a value within 1e-9 of a multiple counts as on it: 0.35 / 0.01 is 34.999…)."""
    low, high = min(values), max(values)
    for width in DISTANCE_WIDTHS:
        start = math.floor(low / width + EDGE_SLACK)
        bins = max(math.floor(high / width + EDGE_SLACK) - start + 1, 1)
        if bins <= DISTANCE_MAX_BINS:
            return [round((start + k) * width, DECIMALS) for k in range(bins + 1)]
    width = DISTANCE_WIDTHS[-1]
    return [round(k * width, DECIMALS) for k in range(math.ceil(high / width) + 1)]


def distance_stats(views: Sequence[View], hands: Sequence[str]) -> dict[str, Any]:
    distances = [distance(v) for v in views]
    edges = distance_edges(distances)
    return {
        "edges": edges,
        "counts": histogram(distances, edges),
        "by_hand": {
            h: histogram([d for d, v in zip(distances, views, strict=True) if v.hand == h], edges)
            for h in hands
        },
        "summary": summary(distances),
    }


def viewing_direction(view: View) -> Array:
    """Unit vector from the object's origin towards the camera, in the object frame: the camera
    centre is -R_m2c^T t_m2c there. Which side of the object a view shows, whatever the hand."""
    centre = -view.R_m2c.T @ view.t_m2c
    return centre / np.linalg.norm(centre)


def azimuth_elevation_deg(direction: Array) -> tuple[float, float]:
    x, y, z = (float(c) for c in direction)
    return math.degrees(math.atan2(y, x)), math.degrees(math.asin(max(-1.0, min(1.0, z))))


def orientation_cell(direction: Array) -> tuple[int, int]:
    """(band, sector) of the equal-area grid: band by sin(elevation) = z from -1 up, sector by
    azimuth from -180°."""
    azimuth, _ = azimuth_elevation_deg(direction)
    sector = math.floor((azimuth + 180.0) / (360.0 / AZIMUTH_BINS))
    band = math.floor((float(direction[2]) + 1.0) * SIN_ELEVATION_BINS / 2.0)
    return min(max(band, 0), SIN_ELEVATION_BINS - 1), min(max(sector, 0), AZIMUTH_BINS - 1)


def orientation_stats(views: Sequence[View], objects: Sequence[str]) -> dict[str, Any]:
    directions = [viewing_direction(v) for v in views]
    cells = [orientation_cell(d) for d in directions]
    grid = [[0] * AZIMUTH_BINS for _ in range(SIN_ELEVATION_BINS)]
    for band, sector in cells:
        grid[band][sector] += 1
    total = AZIMUTH_BINS * SIN_ELEVATION_BINS

    def coverage(selected: set[tuple[int, int]]) -> dict[str, Any]:
        return {"cells_seen": len(selected), "coverage": round(len(selected) / total, DECIMALS)}

    angles = [azimuth_elevation_deg(d) for d in directions]
    return {
        "direction": "object origin to camera centre, object frame (-R_m2c^T t_m2c, normalised)",
        "azimuth_edges_deg": [-180.0 + k * 360.0 / AZIMUTH_BINS for k in range(AZIMUTH_BINS + 1)],
        "sin_elevation_edges": [
            round(-1.0 + 2.0 * k / SIN_ELEVATION_BINS, DECIMALS) for k in range(SIN_ELEVATION_BINS + 1)
        ],
        "counts": grid,
        "cells": total,
        **coverage(set(cells)),
        "by_object": {
            o: {
                "samples": sum(1 for v in views if v.object == o),
                **coverage({c for c, v in zip(cells, views, strict=True) if v.object == o}),
            }
            for o in objects
        },
        "elevation_deg": summary([e for _, e in angles]),
    }


def regions_of(grasps: Sequence[Grasp]) -> list[str]:
    """The layout's regions, all of them even when no taxel there fired, then any others seen."""
    seen = {r for g in grasps for r in g.active_regions}
    return [*REGION_ORDER, *sorted(seen - set(REGION_ORDER))]


def taxel_stats(grasps: Sequence[Grasp], hands: Sequence[str]) -> dict[str, Any]:
    regions = regions_of(grasps)
    by_hand = {}
    for h in hands:
        mine = [active_counts(g, regions) for g in grasps if g.hand == h]
        by_hand[h] = {
            "grasps": len(mine),
            "active": summary([m["active"] for m in mine]),
            "regions": {
                r: {
                    "total": sum(m["regions"][r] for m in mine),
                    "grasps_touching": sum(1 for m in mine if m["regions"][r] > 0),
                    "per_grasp": summary([m["regions"][r] for m in mine]),
                }
                for r in regions
            },
        }
    return {"regions": regions, "by_hand": by_hand}


def active_counts(grasp: Grasp, regions: Sequence[str]) -> dict[str, Any]:
    """A grasp's active taxels: in all and per region."""
    return {
        "active": len(grasp.active_regions),
        "regions": {r: grasp.active_regions.count(r) for r in regions},
    }


def pair_stats(pairs: Sequence[Pair]) -> dict[str, Any]:
    reasons = sorted({r for p in pairs for r in p.rejected})
    rows = [
        {
            "object": p.object,
            "hand": p.hand,
            "trials": p.trials,
            "accepted": p.accepted,
            "acceptance": round(p.accepted / p.trials, DECIMALS) if p.trials else None,
            "rejected": {r: p.rejected.get(r, 0) for r in reasons},
        }
        for p in sorted(pairs, key=lambda p: (p.object, p.hand))
    ]
    trials = sum(p.trials for p in pairs)
    accepted = sum(p.accepted for p in pairs)
    return {
        "reasons": reasons,
        "pairs": rows,
        "total": {
            "trials": trials,
            "accepted": accepted,
            "acceptance": round(accepted / trials, DECIMALS) if trials else None,
            "rejected": {r: sum(p.rejected.get(r, 0) for p in pairs) for r in reasons},
        },
    }


def grasp_type_stats(grasps: Sequence[Grasp], hands: Sequence[str]) -> dict[str, Any] | None:
    """Accepted grasps per grasp type (grasp.json `trial.grasp.type`; "unknown" for a record from
    before types), in all and per hand. None when the layout does not carry types (BOP)."""
    typed = [g for g in grasps if g.grasp_type is not None]
    if not typed:
        return None
    types = sorted({str(g.grasp_type) for g in typed})

    def tally(selected: Iterable[Grasp]) -> dict[str, int]:
        counted = Counter(g.grasp_type for g in selected)
        return {t: counted[t] for t in types}

    return {
        "types": types,
        "counts": tally(typed),
        "by_hand": {h: tally(g for g in typed if g.hand == h) for h in hands},
    }


def object_counts(
    views: Sequence[View], grasps: Sequence[Grasp], hands: Sequence[str], objects: Sequence[str]
) -> dict[str, Any]:
    """Accepted grasps and samples per object, and per hand within it."""

    def counts(obj: str, hand_name: str | None) -> dict[str, int]:
        def mine(item: View | Grasp) -> bool:
            return item.object == obj and (hand_name is None or item.hand == hand_name)

        return {"grasps": sum(1 for g in grasps if mine(g)), "samples": sum(1 for v in views if mine(v))}

    return {o: {**counts(o, None), "by_hand": {h: counts(o, h) for h in hands}} for o in objects}


def environment_counts(views: Sequence[View], hands: Sequence[str]) -> dict[str, Any]:
    """Samples per environment (the HDRI's name, "unknown" where a record names none), and per hand
    within it."""
    environments = sorted({v.environment for v in views})
    return {
        e: {
            "samples": sum(1 for v in views if v.environment == e),
            "by_hand": {h: sum(1 for v in views if (v.environment, v.hand) == (e, h)) for h in hands},
        }
        for e in environments
    }
