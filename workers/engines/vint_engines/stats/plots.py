"""The statistics' figures: one PNG per question, drawn from the numbers of `numbers.compute` (and,
for the orientation scatter, the views themselves), so a figure never counts differently from the
table beside it.

The only place matplotlib is imported. Output is deterministic for one matplotlib build: the Agg
backend, matplotlib's default style whatever the user's matplotlibrc says, its bundled DejaVu font,
a fixed size and resolution, and no software/date metadata in the PNG.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import matplotlib as mpl
import matplotlib.style
import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from vint_engines.stats.dataset import Dataset
from vint_engines.stats.hand import object_position_mm
from vint_engines.stats.numbers import viewing_direction

OCCLUSION_PNG = "occlusion.png"
ORIENTATION_PNG = "orientation.png"
DISTANCE_PNG = "distance.png"
TAXELS_PNG = "taxels.png"
ACCEPTANCE_PNG = "acceptance.png"
IN_HAND_PNG = "in_hand.png"
CAMERA_PALM_PNG = "camera_palm.png"
COUNTS_PNG = "counts.png"
PNGS = (
    OCCLUSION_PNG,
    ORIENTATION_PNG,
    DISTANCE_PNG,
    TAXELS_PNG,
    ACCEPTANCE_PNG,
    IN_HAND_PNG,
    CAMERA_PALM_PNG,
    COUNTS_PNG,
)
HAND_MARKERS = ("o", "s", "^", "D", "v", "P")

DPI = 100
STYLE = {
    "font.family": "DejaVu Sans",  # ships with matplotlib: the same glyphs on every machine
    "font.size": 9,
    "axes.titlesize": 10,
    "figure.dpi": DPI,
    "savefig.dpi": DPI,
    "axes.grid": True,
    "grid.alpha": 0.3,
}
PNG_METADATA = {"Software": None}  # no matplotlib version stamp: same figure, same bytes
SCATTER_MAX = 3000  # views drawn as points on the orientation map; beyond, the counts alone


def write_all(out: Path, stats: dict[str, Any], dataset: Dataset) -> list[Path]:
    """Draws every figure into `out`. Figures are built without pyplot (no global figure
    registry, no GUI backend: `Figure.savefig` renders with Agg)."""
    paths = []
    with fixed_style():
        figures = {
            OCCLUSION_PNG: occlusion(stats),
            ORIENTATION_PNG: orientation(stats, dataset),
            DISTANCE_PNG: distance(stats),
            TAXELS_PNG: taxels(stats),
            ACCEPTANCE_PNG: acceptance(stats),
            IN_HAND_PNG: in_hand(stats, dataset),
            CAMERA_PALM_PNG: camera_palm(stats),
            COUNTS_PNG: counts(stats),
        }
        for name, figure in figures.items():
            path = out / name
            figure.savefig(path, metadata=PNG_METADATA)
            paths.append(path)
    return paths


@contextmanager
def fixed_style() -> Iterator[None]:
    """matplotlib's defaults plus STYLE, whatever the user's matplotlibrc says."""
    with mpl.style.context("default"), mpl.rc_context(STYLE):
        yield


def new_figure(width: float, height: float) -> Figure:
    return Figure(figsize=(width, height), layout="constrained")


def hand_colors(hands: Sequence[str]) -> dict[str, str]:
    return {h: f"C{i % 10}" for i, h in enumerate(hands)}


def stacked_bars(
    ax: Axes, lefts: Sequence[float], widths: Sequence[float], by_hand: dict[str, list[int]]
) -> None:
    """One bar per bin, a segment per hand, with each bin's total above it."""
    colors = hand_colors(list(by_hand))
    bottom = np.zeros(len(lefts))
    for hand, counts in by_hand.items():
        ax.bar(
            lefts,
            counts,
            widths,
            bottom=bottom,
            align="edge",
            color=colors[hand],
            label=hand,
            edgecolor="white",
        )
        bottom += np.asarray(counts, dtype=np.float64)
    for left, width, total in zip(lefts, widths, bottom, strict=True):
        if total > 0:
            ax.annotate(f"{int(total)}", (left + width / 2, total), ha="center", va="bottom", fontsize=8)
    ax.set_ylim(0, max(float(bottom.max()), 1.0) * 1.12)
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_ylabel("samples")
    ax.legend(title="hand")


def occlusion(stats: dict[str, Any]) -> Figure:
    occ = stats["occlusion"]
    edges = [100 * e for e in occ["edges"]]
    figure = new_figure(6.4, 4.0)
    ax = figure.subplots()
    stacked_bars(ax, edges[:-1], np.diff(edges).tolist(), occ["by_hand"])
    ax.set_xticks(edges)
    ax.set_xlim(0, 100)
    ax.set_xlabel("occlusion by the hand (%): 1 - visible / full object pixels")
    mean = occ["summary"]["mean"]
    ax.set_title(f"Occlusion — {stats['counts']['samples']} samples, mean {100 * mean:.1f} %")
    return figure


def distance(stats: dict[str, Any]) -> Figure:
    dist = stats["distance_m"]
    edges = dist["edges"]
    figure = new_figure(6.4, 4.0)
    ax = figure.subplots()
    stacked_bars(ax, edges[:-1], np.diff(edges).tolist(), dist["by_hand"])
    ax.set_xticks(edges)
    ax.tick_params(axis="x", labelrotation=45 if len(edges) > 10 else 0)
    ax.set_xlim(edges[0], edges[-1])
    ax.set_xlabel("camera–object distance (m): |t_m2c|, camera centre to the object's origin")
    s = dist["summary"]
    ax.set_title(f"Camera distance — median {s['p50']:.3f} m, range {s['min']:.3f}–{s['max']:.3f} m")
    return figure


def orientation(stats: dict[str, Any], dataset: Dataset) -> Figure:
    """Which side of the object each view shows: the camera's direction in the object frame on an
    equal-area map (azimuth against sin elevation), cells shaded by count, views as points."""
    orient = stats["orientation"]
    az_edges = orient["azimuth_edges_deg"]
    z_edges = orient["sin_elevation_edges"]
    counts = np.asarray(orient["counts"], dtype=np.float64)
    figure = new_figure(8.0, 4.6)
    ax = figure.subplots()
    shaded = np.ma.masked_equal(counts, 0)
    mesh = ax.pcolormesh(az_edges, z_edges, shaded, cmap="Blues", vmin=0, edgecolors="0.85", linewidth=0.5)
    figure.colorbar(mesh, ax=ax, label="views per cell (each cell 1/72 of the sphere)")
    if len(dataset.views) <= SCATTER_MAX:
        objects = stats["objects"]
        for i, obj in enumerate(objects):
            points = np.array([viewing_direction(v) for v in dataset.views if v.object == obj])
            azimuth = np.degrees(np.arctan2(points[:, 1], points[:, 0]))
            ax.scatter(
                azimuth, points[:, 2], s=14, color=f"C{i % 10}", edgecolors="k", linewidths=0.3, label=obj
            )
        figure.legend(title="object", loc="outside right upper", fontsize=8)
    ax.grid(False)
    ax.set_xlim(-180, 180)
    ax.set_ylim(-1, 1)
    ax.set_xticks(az_edges[::2])
    ticks = [-90, -45, -20, 0, 20, 45, 90]
    ax.set_yticks(np.sin(np.radians(ticks)), [f"{t}°" for t in ticks])
    ax.set_xlabel("azimuth of the camera about the object's z axis (°)")
    ax.set_ylabel("elevation above the object's xy plane (equal-area scale)")
    ax.set_title(
        f"Viewing direction in the object frame — {orient['cells_seen']} of {orient['cells']} "
        f"equal-area cells seen ({100 * orient['coverage']:.0f} %)"
    )
    return figure


def taxels(stats: dict[str, Any]) -> Figure:
    """Left: the spread of active taxels per grasp for each hand; right: the mean per grasp by
    region (tip, pulp, palm)."""
    tax = stats["taxels"]
    hands = [h for h in stats["hands"] if tax["by_hand"][h]["grasps"] > 0]
    regions = tax["regions"]
    colors = hand_colors(stats["hands"])
    figure = new_figure(9.6, 4.0)
    left, right = figure.subplots(1, 2)
    for i, hand in enumerate(hands):
        s = tax["by_hand"][hand]["active"]
        left.bar(i, s["p75"] - s["p25"], 0.5, bottom=s["p25"], color=colors[hand], alpha=0.5)
        left.plot([i - 0.25, i + 0.25], [s["p50"], s["p50"]], color="k")
        left.plot([i, i], [s["min"], s["max"]], color=colors[hand], marker="_", markersize=14)
        left.plot(i, s["mean"], "D", color="k", markersize=4)
    left.set_xticks(range(len(hands)), [f"{h}\n({tax['by_hand'][h]['grasps']} grasps)" for h in hands])
    left.set_xlim(-0.6, len(hands) - 0.4)
    left.set_ylim(0, None)
    left.set_ylabel("active taxels per grasp")
    left.set_title("Active taxels per grasp")
    left.set_xlabel("bar: quartiles, line: median, ◆: mean, whiskers: range")
    width = 0.8 / max(len(hands), 1)
    for i, hand in enumerate(hands):
        means = [tax["by_hand"][hand]["regions"][r]["per_grasp"]["mean"] for r in regions]
        x = np.arange(len(regions)) + (i - (len(hands) - 1) / 2) * width
        right.bar(x, means, width, color=colors[hand], label=hand)
        for xi, m in zip(x, means, strict=True):
            right.annotate(f"{m:.1f}", (xi, m), ha="center", va="bottom", fontsize=8)
    right.set_xticks(range(len(regions)), regions)
    right.set_ylabel("mean active taxels per grasp")
    right.set_title("By region of the hand's taxel layout")
    if hands:
        right.legend(title="hand")
    return figure


def acceptance(stats: dict[str, Any]) -> Figure:
    """One bar per (object, hand) pair: its trials split into accepted and each rejection reason."""
    pairs = stats["pairs"]
    if pairs is None:
        figure = new_figure(6.4, 2.0)
        ax = figure.subplots()
        ax.axis("off")
        ax.text(0.5, 0.5, "no dataset.json: this dataset does not record its trials", ha="center")
        return figure
    rows = pairs["pairs"]
    figure = new_figure(8.0, 1.2 + 0.32 * len(rows))
    ax = figure.subplots()
    y = np.arange(len(rows))[::-1]
    left = np.zeros(len(rows))
    segments = [("accepted", [r["accepted"] for r in rows], "tab:green")]
    reason_colors = ["tab:red", "tab:orange", "tab:purple", "tab:brown", "tab:pink", "tab:gray", "tab:olive"]
    for k, reason in enumerate(pairs["reasons"]):
        color = reason_colors[k % len(reason_colors)]
        segments.append((f"rejected: {reason}", [r["rejected"][reason] for r in rows], color))
    for label, values, color in segments:
        ax.barh(y, values, left=left, color=color, label=label, height=0.7)
        left += np.asarray(values, dtype=np.float64)
    for yi, row, total in zip(y, rows, left, strict=True):
        rate = "–" if row["acceptance"] is None else f"{100 * row['acceptance']:.0f} %"
        ax.annotate(f" {row['accepted']}/{row['trials']} ({rate})", (total, yi), va="center", fontsize=8)
    ax.set_yticks(y, [f"{r['object']} / {r['hand']}" for r in rows])
    ax.set_xlim(0, max(float(left.max()), 1.0) * 1.25)
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("grasp trials")
    figure.legend(loc="outside lower center", ncols=min(len(segments), 4), fontsize=8)
    total = pairs["total"]
    ax.set_title(f"Grasp acceptance per pair — {total['accepted']} of {total['trials']} trials accepted")
    return figure


def unavailable(message: str) -> Figure:
    figure = new_figure(6.4, 2.0)
    ax = figure.subplots()
    ax.axis("off")
    ax.text(0.5, 0.5, message, ha="center")
    return figure


def in_hand(stats: dict[str, Any], dataset: Dataset) -> Figure:
    """Where the object sits in the palm: each accepted grasp's object origin in the palm frame,
    seen from the side (x–z) and from the fingers' end (y–z), coloured by object, marked by hand;
    the palm plane is z = 0."""
    if stats["in_hand"] is None:
        return unavailable("the dataset's records carry no palm pose: no in-hand pose")
    objects, hands = stats["objects"], stats["hands"]
    figure = new_figure(9.6, 4.4)
    axes = figure.subplots(1, 2, sharey=True)
    for axis, label in ((0, "x"), (1, "y")):
        panel = axes[axis]
        for i, obj in enumerate(objects):
            for j, hand_name in enumerate(hands):
                grasps = [
                    g
                    for g in dataset.grasps
                    if g.object == obj and g.hand == hand_name and g.object_in_palm is not None
                ]
                if not grasps:
                    continue
                points = np.array([object_position_mm(g) for g in grasps])
                panel.scatter(
                    points[:, axis],
                    points[:, 2],
                    s=28,
                    color=f"C{i % 10}",
                    marker=HAND_MARKERS[j % len(HAND_MARKERS)],
                    edgecolors="k",
                    linewidths=0.3,
                    label=f"{obj} / {hand_name}" if axis == 0 else None,
                )
        panel.axhline(0.0, color="0.3", linewidth=1.0)
        panel.axvline(0.0, color="0.6", linewidth=0.6)
        panel.set_xlabel(f"{label} in the palm frame (mm)")
        panel.set_aspect("equal", adjustable="datalim")
    axes[0].set_ylabel("z: height above the palm plane along its normal (mm)")
    figure.legend(title="object / hand", loc="outside lower center", ncols=4, fontsize=8)
    s = stats["in_hand"]["all"]
    figure.suptitle(
        f"Object origin in the palm frame — {s['grasps']} grasps, height {s['z_mm']['min']:.0f}–"
        f"{s['z_mm']['max']:.0f} mm, median distance {s['distance_mm']['p50']:.0f} mm"
    )
    return figure


def camera_palm(stats: dict[str, Any]) -> Figure:
    """From which side of the palm the cameras look: views per tenth of palm_facing (the sine of
    the camera's elevation above the palm plane), stacked by hand; < 0 is the back of the palm."""
    cam = stats["camera_palm"]
    if cam is None:
        return unavailable("the dataset's records carry no palm pose: no camera-to-palm direction")
    edges = cam["edges"]
    figure = new_figure(6.4, 4.0)
    ax = figure.subplots()
    by_hand = {h: cam["by_hand"][h]["counts"] for h in stats["hands"]}
    stacked_bars(ax, edges[:-1], np.diff(edges).tolist(), by_hand)
    ax.axvline(0.0, color="k", linewidth=1.0)
    ax.set_xticks(edges)
    ax.set_xlim(-1, 1)
    ax.set_xlabel("palm_facing: cos(palm normal, palm→camera) = sin(elevation above the palm plane)")
    total = cam["all"]
    ax.set_title(f"Camera relative to the palm — front {total['front']}, back {total['back']} views")
    return figure


def grouped_counts(ax: Axes, labels: Sequence[str], by_hand: dict[str, list[int]], ylabel: str) -> None:
    """Stacked bars, one per label, a segment per hand."""
    colors = hand_colors(list(by_hand))
    bottom = np.zeros(len(labels))
    x = np.arange(len(labels))
    for hand_name, values in by_hand.items():
        ax.bar(x, values, 0.7, bottom=bottom, color=colors[hand_name], label=hand_name, edgecolor="white")
        bottom += np.asarray(values, dtype=np.float64)
    for xi, total in zip(x, bottom, strict=True):
        ax.annotate(f"{int(total)}", (xi, total), ha="center", va="bottom", fontsize=8)
    ax.set_xticks(
        x, labels, rotation=30 if len(labels) > 3 else 0, ha="right" if len(labels) > 3 else "center"
    )
    ax.set_ylim(0, max(float(bottom.max()) if len(labels) else 0.0, 1.0) * 1.15)
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_ylabel(ylabel)


def counts(stats: dict[str, Any]) -> Figure:
    """Samples per object and per environment, and accepted grasps per grasp type, by hand."""
    hands = stats["hands"]
    objects = stats["per_object"]
    environments = stats["per_environment"]
    types = stats["grasp_types"]
    figure = new_figure(12.0, 4.2)
    left, middle, right = figure.subplots(1, 3)
    grouped_counts(
        left,
        list(objects),
        {h: [objects[o]["by_hand"][h]["samples"] for o in objects] for h in hands},
        "samples",
    )
    left.set_title("Samples per object")
    grouped_counts(
        middle,
        list(environments),
        {h: [environments[e]["by_hand"][h] for e in environments] for h in hands},
        "samples",
    )
    middle.set_title("Samples per environment")
    if types is None:
        right.axis("off")
        right.text(0.5, 0.5, "grasp types: not in this layout", ha="center")
    else:
        grouped_counts(
            right,
            types["types"],
            {h: [types["by_hand"][h][t] for t in types["types"]] for h in hands},
            "grasps",
        )
        right.set_title("Accepted grasps per grasp type")
    left.legend(title="hand")
    return figure
