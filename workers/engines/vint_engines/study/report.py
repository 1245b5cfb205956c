"""Writing a grasp study: per-trial CSV, per-configuration summary CSV, log–log plot, markdown.

Plain functions over the study's rows (dicts); the only place matplotlib is imported (Agg backend,
so no display is needed).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

TRIALS_CSV = "grasp_study.csv"
SUMMARY_CSV = "grasp_study_summary.csv"
PLOT_PNG = "grasp_study.png"
TABLE_MD = "grasp_study.md"

TRIAL_COLUMNS = (
    "config",
    "timestep_ms",
    "solver",
    "iterations",
    "cone",
    "skin_timeconst_ms",
    "max_retries",
    "hand",
    "object",
    "seed",
    "accepted",
    "reason",
    "active_taxels",
    "label_agrees",
    "pos_err_mm",
    "rot_err_deg",
    "taxel_iou",
    "max_penetration_mm",
    "timestep_used_ms",
    "retries",
    "steps",
    "wall_s",
    "cpu_s",
)
SUMMARY_COLUMNS = (
    "config",
    "hand",
    "timestep_ms",
    "solver",
    "iterations",
    "cone",
    "skin_timeconst_ms",
    "max_retries",
    "trials",
    "accepted",
    "unstable",
    "refused",
    "retried",
    "label_agreement_pct",
    "pos_err_mm_median",
    "pos_err_mm_p90",
    "rot_err_deg_median",
    "rot_err_deg_p90",
    "taxel_iou_mean",
    "max_penetration_mm",
    "wall_ms_per_accepted",
    "cpu_ms_per_accepted",
    "within_tolerance",
)

# Rejection reasons of numerical trouble (the engine's stability monitor and MuJoCo's warnings).
UNSTABLE = ("diverged", "nan_state", "penetration", "energy")

# What "as good as the reference" means for a dataset: the same labels, the object where the
# reference holds it to within a couple of millimetres and degrees (up to its symmetry), mostly the
# same taxels, contacts sinking at most 1 mm deeper than in the reference, and no more numerical
# trouble than the reference itself had. Checked for all hands together and for each hand.
TOLERANCE = {
    "label_agreement_pct": 90.0,  # at least
    "pos_err_mm_median": 2.0,  # at most
    "rot_err_deg_median": 2.0,
    "taxel_iou_mean": 0.8,  # at least
}
EXTRA_PENETRATION_MM = 1.0


def summarize(rows: Sequence[dict[str, Any]], configs: Sequence[str]) -> list[dict[str, Any]]:
    """One row per configuration and hand, plus `hand = all`, in the configurations' order; the
    first configuration is the reference the tolerances compare with."""
    hands = ["all", *dict.fromkeys(r["hand"] for r in rows)]
    summary = []
    for config in configs:
        for hand in hands:
            group = [r for r in rows if r["config"] == config and hand in ("all", r["hand"])]
            if group:
                summary.append(summarize_group(config, hand, group))
    reference = {s["hand"]: s for s in summary if s["config"] == configs[0]}
    for s in summary:
        s["within_tolerance"] = int(within_tolerance(s, reference[s["hand"]]))
    return summary


def summarize_group(config: str, hand: str, group: Sequence[dict[str, Any]]) -> dict[str, Any]:
    def values(key: str) -> np.ndarray:
        return np.array([r[key] for r in group if r[key] is not None], dtype=float)

    def stat(key: str, q: float) -> float | None:
        v = values(key)
        return float(np.percentile(v, q)) if len(v) else None

    accepted = sum(r["accepted"] for r in group)
    wall, cpu = sum(r["wall_s"] for r in group), sum(r["cpu_s"] for r in group)
    first = group[0]
    out: dict[str, Any] = {
        "config": config,
        "hand": hand,
        **{k: first[k] for k in ("timestep_ms", "solver", "iterations", "cone", "skin_timeconst_ms")},
        "max_retries": first["max_retries"],
        "trials": len(group),
        "accepted": accepted,
        "unstable": sum(r["reason"].startswith(UNSTABLE) for r in group),
        "refused": sum(r["reason"].startswith("timestep") for r in group),
        "retried": sum(r["retries"] > 0 for r in group),
        "label_agreement_pct": 100.0 * float(values("label_agrees").mean()),
        "pos_err_mm_median": stat("pos_err_mm", 50),
        "pos_err_mm_p90": stat("pos_err_mm", 90),
        "rot_err_deg_median": stat("rot_err_deg", 50),
        "rot_err_deg_p90": stat("rot_err_deg", 90),
        "taxel_iou_mean": float(values("taxel_iou").mean()) if len(values("taxel_iou")) else None,
        "max_penetration_mm": float(values("max_penetration_mm").max()),
        "wall_ms_per_accepted": 1e3 * wall / accepted if accepted else None,
        "cpu_ms_per_accepted": 1e3 * cpu / accepted if accepted else None,
    }
    return out


def within_tolerance(summary: dict[str, Any], reference: dict[str, Any]) -> bool:
    checks = [
        summary["unstable"] <= reference["unstable"] and summary["refused"] == 0,
        summary["wall_ms_per_accepted"] is not None,
        summary["max_penetration_mm"] <= reference["max_penetration_mm"] + EXTRA_PENETRATION_MM,
    ]
    for key, limit in TOLERANCE.items():
        value = summary[key]
        at_least = key in ("label_agreement_pct", "taxel_iou_mean")
        checks.append(value is not None and (value >= limit if at_least else value <= limit))
    return all(checks)


def write_csv(path: Path, rows: Sequence[dict[str, Any]], columns: Sequence[str]) -> None:
    def cell(value: Any) -> Any:
        if value is None:
            return ""
        return f"{value:.6g}" if isinstance(value, float) else value

    with path.open("w", newline="", encoding="utf-8") as file:
        writer = csv.writer(file, lineterminator="\n")
        writer.writerow(columns)
        writer.writerows([[cell(r[c]) for c in columns] for r in rows])


def plot(path: Path, summary: Sequence[dict[str, Any]], reference: str) -> None:
    """Log–log: error against wall time per accepted grasp, one marker per configuration (all hands).
    Zero errors (the reference) sit on the axis floor."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    rows = [s for s in summary if s["hand"] == "all" and s["wall_ms_per_accepted"] is not None]
    panels = (
        ("pos_err_mm_median", "median object position error in palm (mm)", 1e-3),
        ("rot_err_deg_median", "median object rotation error (deg)", 1e-3),
        ("taxel_iou_mean", "1 - mean active-taxel IoU", 1e-4),
    )
    fig, axes = plt.subplots(1, len(panels), figsize=(15, 4.8), constrained_layout=True)
    for ax, (key, label, floor) in zip(axes, panels, strict=True):
        for s in rows:
            value = s[key]
            if value is None:
                continue
            error = 1.0 - value if key == "taxel_iou_mean" else value
            marker = "*" if s["config"] == reference else ("o" if s["solver"] == "newton" else "s")
            ax.loglog(s["wall_ms_per_accepted"], max(error, floor), marker, markersize=9)
            ax.annotate(s["config"], (s["wall_ms_per_accepted"], max(error, floor)), fontsize=7)
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("wall time per accepted grasp (ms)")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
    fig.suptitle(
        f"Grasp physics: error against the {reference} reference (drawn on the axis floor) vs cost, "
        "all hands and objects"
    )
    fig.savefig(path, dpi=110)
    plt.close(fig)


def good_rows(summary: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """`hand = all` rows of the configurations within tolerance for all hands and for each hand."""
    failing = {s["config"] for s in summary if not s["within_tolerance"]}
    return [
        s
        for s in summary
        if s["hand"] == "all" and s["config"] not in failing and s["cpu_ms_per_accepted"] is not None
    ]


def describe(s: dict[str, Any], fmt: Any) -> str:
    return (
        f"**{s['config']}** ({fmt(s['cpu_ms_per_accepted'], 1)} CPU ms per accepted grasp, label "
        f"agreement {fmt(s['label_agreement_pct'], 1)} %, median position error "
        f"{fmt(s['pos_err_mm_median'])} mm, median rotation error {fmt(s['rot_err_deg_median'])}°, "
        f"taxel IoU {fmt(s['taxel_iou_mean'], 3)}, max penetration {fmt(s['max_penetration_mm'])} mm)"
    )


def recommend(
    summary: Sequence[dict[str, Any]], default: str
) -> tuple[dict[str, Any] | None, dict[str, Any]]:
    """The cheapest configuration within tolerance for all hands together and for each hand, and
    the default's summary."""
    good = good_rows(summary)
    best = min(good, key=lambda s: s["cpu_ms_per_accepted"]) if good else None
    return best, next(s for s in summary if s["hand"] == "all" and s["config"] == default)


def markdown(summary: Sequence[dict[str, Any]], reference: str, default: str, trials: int) -> str:
    def fmt(value: Any, digits: int = 2) -> str:
        if value is None:
            return "–"
        if isinstance(value, float):
            return f"{value:.{digits}f}" if math.isfinite(value) else "–"
        return str(value)

    columns = [
        "config",
        "hand",
        "accepted",
        "unstable / refused / retried",
        "label agree %",
        "pos err mm (med / p90)",
        "rot err ° (med / p90)",
        "taxel IoU",
        "max pen. mm",
        "wall ms / accepted",
        "CPU ms / accepted",
        "ok",
    ]
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    for s in summary:
        lines.append(
            f"| {s['config']} | {s['hand']} | {s['accepted']}/{s['trials']} | "
            f"{s['unstable']} / {s['refused']} / {s['retried']} | "
            f"{fmt(s['label_agreement_pct'], 1)} | "
            f"{fmt(s['pos_err_mm_median'])} / {fmt(s['pos_err_mm_p90'])} | "
            f"{fmt(s['rot_err_deg_median'])} / {fmt(s['rot_err_deg_p90'])} | {fmt(s['taxel_iou_mean'], 3)} | "
            f"{fmt(s['max_penetration_mm'])} | {fmt(s['wall_ms_per_accepted'], 1)} | "
            f"{fmt(s['cpu_ms_per_accepted'], 1)} | {'yes' if s['within_tolerance'] else 'no'} |"
        )
    best, base = recommend(summary, default)
    tolerance = (
        f"label agreement ≥ {TOLERANCE['label_agreement_pct']:g} %, median position error ≤ "
        f"{TOLERANCE['pos_err_mm_median']:g} mm, median rotation error ≤ "
        f"{TOLERANCE['rot_err_deg_median']:g}°, "
        f"mean taxel IoU ≥ {TOLERANCE['taxel_iou_mean']:g}, max penetration at most "
        f"{EXTRA_PENETRATION_MM:g} mm deeper than the reference's, no more trials rejected as unstable "
        "than the reference and none refused for its timestep; for all hands together and for each hand"
    )
    if best is None:
        verdict = "No configuration other than the reference meets all tolerances."
    else:
        verdict = f"The cheapest configuration within tolerance is {describe(best, fmt)}."
        same_model = min(
            (s for s in good_rows(summary) if s["skin_timeconst_ms"] == ""),
            key=lambda s: s["cpu_ms_per_accepted"],
            default=None,
        )
        if best["skin_timeconst_ms"] != "" and same_model is not None:
            verdict += (
                " It softens the hand's contact (a different contact model, not only a coarser step); "
                f"keeping the engine's contact model, the cheapest is {describe(same_model, fmt)}."
            )
    default_line = (
        f"The engine's default, **{default}** (Newton, 100 iterations, elliptic cone), costs "
        f"{fmt(base['cpu_ms_per_accepted'], 1)} CPU ms per accepted grasp with label agreement "
        f"{fmt(base['label_agreement_pct'], 1)} %, median position error {fmt(base['pos_err_mm_median'])} mm "
        f"(p90 {fmt(base['pos_err_mm_p90'])}), median rotation error {fmt(base['rot_err_deg_median'])}°, "
        f"taxel IoU {fmt(base['taxel_iou_mean'], 3)}, max penetration {fmt(base['max_penetration_mm'])} mm: "
        f"{'within' if base['within_tolerance'] else 'outside'} tolerance."
    )
    return "\n".join(
        [
            "# Grasp physics: error against run time",
            "",
            f"Generated by `python -m vint_engines study grasp`; {trials} trials per configuration, each "
            f"compared with the same seed under the reference **{reference}** (Newton, 100 iterations, "
            "elliptic cone). Pose errors are of the object in the palm frame after the hold, over trials "
            "both runs accepted (rotation up to the object's symmetry: for a can only the tilt of its "
            "axis counts); penetration is the deepest contact over the whole rollout; times are per "
            "accepted grasp, summed over all trials of the configuration (rejections cost time too).",
            "",
            *lines,
            "",
            "## Recommendation",
            "",
            f"Tolerances: {tolerance}.",
            verdict,
            default_line,
            "",
            f"![error vs time]({PLOT_PNG})",
            "",
        ]
    )


def write_all(
    out: Path, rows: Sequence[dict[str, Any]], configs: Sequence[str], reference: str, default: str
) -> list[Path]:
    summary = summarize(rows, configs)
    paths = [out / TRIALS_CSV, out / SUMMARY_CSV, out / PLOT_PNG, out / TABLE_MD]
    write_csv(paths[0], rows, TRIAL_COLUMNS)
    write_csv(paths[1], summary, SUMMARY_COLUMNS)
    plot(paths[2], summary, reference)
    trials = len([r for r in rows if r["config"] == reference])
    paths[3].write_text(markdown(summary, reference, default, trials), encoding="utf-8")
    return paths
