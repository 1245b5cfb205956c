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
from vint_engines.stats.numbers import viewing_direction

OCCLUSION_PNG = "occlusion.png"
ORIENTATION_PNG = "orientation.png"
DISTANCE_PNG = "distance.png"
TAXELS_PNG = "taxels.png"
ACCEPTANCE_PNG = "acceptance.png"
PNGS = (OCCLUSION_PNG, ORIENTATION_PNG, DISTANCE_PNG, TAXELS_PNG, ACCEPTANCE_PNG)

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
