"""Writing the touch-vs-vision study: per-estimate CSV, summary by occlusion bucket, plot, markdown.

Plain functions over the study's rows (dicts). The finding sentence is computed from the summary,
so the report says what this run's data shows, whichever way it falls.
"""

from __future__ import annotations

import csv
import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vint_engines.study import pose_scores
from vint_engines.study.touch_estimate import (
    MIN_POINTS,
    ROTATION_DEG,
    TAXEL_WEIGHT,
    TRANSLATION_MM,
    VARIANTS,
    VISION,
    VISION_POINTS,
    VISION_TOUCH,
    Estimate,
)
from vint_engines.study.touch_inputs import View

ROWS_CSV = "touch_vs_vision.csv"
SUMMARY_CSV = "touch_vs_vision_summary.csv"
PLOT_PNG = "touch_vs_vision.png"
TABLE_MD = "touch_vs_vision.md"
SPEC_TOML = "touch_vs_vision.toml"

ROW_COLUMNS = (
    "sample_id",
    "object",
    "obj_id",
    "symmetric",
    "hand",
    "scene_id",
    "im_id",
    "occlusion",
    "bucket",
    "variant",
    "vision_points",
    "taxels",
    "guard",
    "start_err_mm",
    "add_mm",
    "adds_mm",
    "err_mm",
    "below_01d",
    "iterations",
    "converged",
    "degenerate",
    "cpu_ms",
    "wall_ms",
)
SUMMARY_COLUMNS = (
    "variant",
    "bucket",
    "n",
    "auc",
    "adds_01d_pct",
    "err_mm_median",
    "start_auc",
    "no_taxels",
    "too_few_points",
    "degenerate",
    "cpu_ms_median",
)
BUCKETS = tuple(f"{10 * k}-{10 * (k + 1)}" for k in range(10))
# The finding compares these occlusion ranges (%): the paper's Table 6 spans 20–50 %.
LOW = (10, 30)
HIGH = (50, 90)


@dataclass(frozen=True)
class RunInfo:
    quick: bool
    seed: int
    views: int
    grasps: int
    objects: list[str]
    hands: list[str]
    generate_s: float
    total_s: float
    taxel_gap_mm: float  # largest difference from the BOP export's scene_touch.json p_cam_mm


def bucket(occlusion: float) -> str:
    return BUCKETS[min(9, max(0, math.floor(occlusion * 10.0 + 1e-9)))]


def row(
    view: View, est: Estimate, scene_id: int, scored: dict[str, Any], start: dict[str, Any]
) -> dict[str, Any]:
    """One estimate with its `vintctl eval` scores (`scored`: its per-estimate entry; `start`: the
    start pose's entry for the same image)."""
    return {
        "sample_id": view.sample_id,
        "object": view.object,
        "obj_id": scored["obj_id"],
        "symmetric": int(scored["symmetric"]),
        "hand": view.hand,
        "scene_id": scene_id,
        "im_id": view.view,
        "occlusion": round(float(scored["occlusion"]), 6),
        "bucket": bucket(float(scored["occlusion"])),
        "variant": est.variant,
        "vision_points": est.vision_points,
        "taxels": est.taxels,
        "guard": est.guard,
        "start_err_mm": round(float(start["add_s_mm"]), 4),
        "add_mm": round(float(scored["add_mm"]), 4),
        "adds_mm": round(float(scored["adds_mm"]), 4),
        "err_mm": float(scored["add_s_mm"]),
        "below_01d": int(scored["add_s_0.1d"]),
        "iterations": est.iterations,
        "converged": int(est.converged),
        "degenerate": int(est.degenerate),
        "cpu_ms": round(est.cpu_ms, 3),
        "wall_ms": round(est.wall_ms, 3),
    }


def summarize(rows: Sequence[dict[str, Any]], scored: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """Per variant, one line per occlusion bucket (empty ones too, n = 0) and one for all: eval's
    own group scores, with the study's counts beside them. The pooled AUC the report also uses
    (`pose_scores.auc` over eval's per-estimate errors) must reproduce eval's per bucket."""
    lines = []
    for variant in VARIANTS:
        mine = [r for r in rows if r["variant"] == variant]
        groups = [*scored[variant]["occlusion"], scored[variant]["overall"]]
        starts = [*scored["start"]["occlusion"], scored["start"]["overall"]]
        for name, group, start in zip((*BUCKETS, "all"), groups, starts, strict=True):
            part = [r for r in mine if name in ("all", r["bucket"])]
            if len(part) != group["n"]:
                raise RuntimeError(f"{variant} {name}: eval counts {group['n']} views, the study {len(part)}")
            pooled = pose_scores.auc([r["err_mm"] for r in part])
            if part and abs(pooled - group["add_s_auc"]) > 1e-6:
                raise RuntimeError(
                    f"{variant} {name}: pooled AUC {pooled} differs from eval's {group['add_s_auc']}"
                )
            lines.append(
                {
                    "variant": variant,
                    "bucket": name,
                    "n": group["n"],
                    "auc": _round(group["add_s_auc"], 2),
                    "adds_01d_pct": _round(group["add_s_0.1d"], 2),
                    "err_mm_median": _round(
                        statistics.median(r["err_mm"] for r in part) if part else math.nan, 3
                    ),
                    "start_auc": _round(start["add_s_auc"], 2),
                    "no_taxels": sum(r["guard"] == "no_taxels" for r in part),
                    "too_few_points": sum(r["guard"] == "too_few_points" for r in part),
                    "degenerate": sum(r["degenerate"] for r in part),
                    "cpu_ms_median": _round(_median_fitted(part, "cpu_ms"), 2),
                }
            )
    return lines


def _median_fitted(rows: Sequence[dict[str, Any]], key: str) -> float:
    """Median cost over the estimates ICP actually ran (a guard's copy or start pose cost nothing)."""
    values = [r[key] for r in rows if not r["guard"]]
    return statistics.median(values) if values else math.nan


def _round(value: float | None, digits: int) -> float:
    """eval gives null for an empty group."""
    return math.nan if value is None or math.isnan(value) else round(float(value), digits)


def in_range(rows: Sequence[dict[str, Any]], variant: str, span: tuple[int, int]) -> list[dict[str, Any]]:
    lo, hi = span
    return [r for r in rows if r["variant"] == variant and lo <= 100.0 * r["occlusion"] < hi]


def finding(rows: Sequence[dict[str, Any]]) -> tuple[str, dict[str, dict[str, float]]]:
    """The sentence the study concludes with, and the numbers behind it: each variant's ADD(S) AUC
    at low (LOW) and high (HIGH) occlusion and the drop between them."""
    numbers: dict[str, dict[str, float]] = {}
    for variant in VARIANTS:
        low, high = in_range(rows, variant, LOW), in_range(rows, variant, HIGH)
        a_low = pose_scores.auc([r["err_mm"] for r in low])
        a_high = pose_scores.auc([r["err_mm"] for r in high])
        numbers[variant] = {
            "low": a_low,
            "high": a_high,
            "drop": a_low - a_high,
            "n_low": len(low),
            "n_high": len(high),
        }
    v, vt = numbers[VISION], numbers[VISION_TOUCH]
    if any(math.isnan(x) for x in (v["drop"], vt["drop"])):
        return "Not enough views at low and high occlusion to compare the two variants.", numbers
    span = f"from {LOW[0]}–{LOW[1]} % to {HIGH[0]}–{HIGH[1]} % occlusion"
    measured = (
        f"{span}, ADD(S) AUC went from {v['low']:.1f} to {v['high']:.1f} with vision alone "
        f"({-v['drop']:+.1f} points) and from {vt['low']:.1f} to {vt['high']:.1f} with vision + touch "
        f"({-vt['drop']:+.1f}; n = {v['n_low']} and {v['n_high']} views)"
    )
    if vt["drop"] < v["drop"] - 0.5:
        verdict = "The data supports the hypothesis: vision + touch degrades less as occlusion grows"
    elif vt["drop"] > v["drop"] + 0.5:
        verdict = "The data contradicts the hypothesis: vision + touch degrades more as occlusion grows"
    else:
        verdict = "The data shows no difference in degradation (within 0.5 AUC points)"
    return f"{verdict}: {measured}.", numbers


def write(
    out: Path, rows: Sequence[dict[str, Any]], scored: dict[str, dict[str, Any]], run: RunInfo
) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    summary = summarize(rows, scored)
    paths = [out / ROWS_CSV, out / SUMMARY_CSV, out / PLOT_PNG, out / TABLE_MD]
    write_csv(paths[0], ROW_COLUMNS, rows)
    write_csv(paths[1], SUMMARY_COLUMNS, summary)
    plot(paths[2], summary, run)
    paths[3].write_text(markdown(rows, summary, run), encoding="utf-8")
    return paths


def write_csv(path: Path, columns: Sequence[str], rows: Sequence[dict[str, Any]]) -> None:
    with path.open("w", newline="", encoding="utf-8") as file:
        writer = csv.DictWriter(file, fieldnames=list(columns), extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)


def plot(path: Path, summary: Sequence[dict[str, Any]], run: RunInfo) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_auc, ax_n) = plt.subplots(
        2, 1, figsize=(7.0, 6.0), sharex=True, gridspec_kw={"height_ratios": [3, 1]}
    )
    centres = [10 * k + 5 for k in range(10)]
    styles = {VISION: ("vision (depth)", "tab:blue", "o"), VISION_TOUCH: ("vision + touch", "tab:red", "s")}
    for variant in VARIANTS:
        lines = [s for s in summary if s["variant"] == variant and s["bucket"] != "all"]
        label, colour, marker = styles[variant]
        xs = [c for c, s in zip(centres, lines, strict=True) if s["n"] > 0]
        ax_auc.plot(
            xs, [s["auc"] for s in lines if s["n"] > 0], marker=marker, color=colour, label=f"{label}: AUC"
        )
        ax_auc.plot(
            xs, [s["adds_01d_pct"] for s in lines if s["n"] > 0], marker=marker, color=colour, linestyle=":",
            alpha=0.7, label=f"{label}: ADD(S) < 0.1d",
        )  # fmt: skip
    starts = [s for s in summary if s["variant"] == VISION and s["bucket"] != "all" and s["n"] > 0]
    ax_auc.plot(
        [int(s["bucket"].split("-")[0]) + 5 for s in starts], [s["start_auc"] for s in starts], color="grey",
        linestyle="--", label="start pose: AUC",
    )  # fmt: skip
    ax_auc.set_ylabel("ADD(S) AUC ≤ 10 cm / % under 0.1d")
    ax_auc.set_ylim(0, 101)
    ax_auc.grid(True, alpha=0.3)
    ax_auc.legend(fontsize=8, loc="lower left")
    ax_auc.set_title(f"ICP from a perturbed pose, {run.views} views ({'quick' if run.quick else 'full'} run)")
    counts = [s["n"] for s in summary if s["variant"] == VISION and s["bucket"] != "all"]
    ax_n.bar(centres, counts, width=8, color="grey")
    ax_n.set_ylabel("views")
    ax_n.set_xlabel("occlusion by the hand (%)")
    ax_n.set_xticks(range(0, 101, 10))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def group_table(rows: Sequence[dict[str, Any]], key: str) -> list[str]:
    """ADD(S) AUC per object (or hand): over all views, at LOW and at HIGH occlusion, per variant."""
    spans = ((0, 101), LOW, HIGH)
    head = " | ".join(f"{variant} {lo}–{min(hi, 100)} %" for variant in VARIANTS for lo, hi in spans)
    lines = [f"| {key} | n | {head} |", "|---|---:|" + "---:|" * (len(VARIANTS) * len(spans))]
    for name in sorted({r[key] for r in rows}):
        mine = [r for r in rows if r[key] == name]
        cells = []
        for variant in VARIANTS:
            for span in spans:
                errors = [r["err_mm"] for r in in_range(mine, variant, span)]
                cells.append(f"{pose_scores.auc(errors):.1f}" if errors else "–")
        n = sum(1 for r in mine if r["variant"] == VISION)
        lines.append(f"| {name} | {n} | " + " | ".join(cells) + " |")
    return lines


def markdown(rows: Sequence[dict[str, Any]], summary: Sequence[dict[str, Any]], run: RunInfo) -> str:
    sentence, _ = finding(rows)
    n_views = run.views
    no_taxels = sum(1 for r in rows if r["variant"] == VISION_TOUCH and r["guard"] == "no_taxels")
    too_few = {
        v: sum(1 for r in rows if r["variant"] == v and r["guard"] == "too_few_points") for v in VARIANTS
    }
    degenerate = {
        v: sum(1 for r in rows if r["variant"] == v and r["degenerate"] and not r["guard"]) for v in VARIANTS
    }
    cpu = {v: _median_fitted([r for r in rows if r["variant"] == v], "cpu_ms") for v in VARIANTS}
    wall = {v: _median_fitted([r for r in rows if r["variant"] == v], "wall_ms") for v in VARIANTS}
    iters = {
        v: statistics.median([r["iterations"] for r in rows if r["variant"] == v and not r["guard"]] or [0])
        for v in VARIANTS
    }
    taxels = [r["taxels"] for r in rows if r["variant"] == VISION_TOUCH]
    lines = [
        "# Touch against vision: ICP under occlusion by the hand",
        "",
        "Written by `vintctl study touch` (`workers/engines/vint_engines/study/touch_vs_vision.py`); "
        "every number below is this run's.",
        "",
        f"**Finding.** {sentence}",
        "",
        "## Set-up",
        "",
        f"- Data: `vintctl run {SPEC_TOML}` (the spec is next to this file): hands {', '.join(run.hands)}; "
        f"objects {', '.join(run.objects)}; {run.grasps} accepted grasps, {n_views} views "
        f"(160×160, 45° FOV, cameras 0.3–0.45 m away at elevations -60…80°, noisy depth from the "
        "Azure-Kinect model in `wfov_2x2binned` mode). Job seed "
        f"{run.seed}. Generation took {run.generate_s:.0f} s (or nothing, when the job was reused).",
        f"- Start: the true pose turned {ROTATION_DEG[0]:.0f}–{ROTATION_DEG[1]:.0f}° (uniform) about a "
        f"uniformly random axis through the model origin and shifted "
        f"{TRANSLATION_MM[0]:.0f}–{TRANSLATION_MM[1]:.0f} mm "
        "(uniform) in a uniformly random direction; drawn from the job seed and the sample id "
        "(`touch_inputs.sample_rng`), the same start for both variants.",
        "- Estimator: weighted point-to-plane ICP (`study/icp.py`, numpy): nearest neighbours by brute "
        "force against 2,000 area-weighted samples of the model surface (`models/<object>.ply`), "
        "Gauss–Newton steps capped at 10° and 20 mm, depth points farther than max(5 mm, 3 × median) "
        "from the model dropped, at most 40 iterations, stopped once a step changes the residuals by "
        "< 0.01 mm RMS.",
        f"- (a) **vision**: the noisy depth (`depth_noisy.npy`: what a sensor gives) of the visible-mask "
        f"pixels, back-projected with `K`, subsampled to ≤ {VISION_POINTS} points.",
        f"- (b) **vision + touch**: the same points plus every active taxel's position in the camera frame "
        f"(`p_palm` through the palm link's pose and the camera extrinsics), each taxel weighing "
        f"{TAXEL_WEIGHT:.0f} depth points. Why: at the true pose the noisy depth lies a median 0.67 mm "
        "off the model surface (σ ≈ 1 mm) and the taxels 0.21 mm (σ ≈ 0.3 mm: the skin's 0.5 mm contact "
        "margin), so inverse-variance weighting gives (1/0.31)² ≈ 10; ~10 taxels then carry about a "
        "quarter of the cloud's weight. Taxels are never dropped as outliers (they are on the surface "
        f"by construction). Active taxels per view: median {statistics.median(taxels) if taxels else 0:.0f}, "
        f"min {min(taxels) if taxels else 0}, max {max(taxels) if taxels else 0}.",
        "- Scoring: `vintctl eval --json` (docs/metrics.md) of three BOP results CSVs (start poses, "
        "vision, vision + touch) on the study data's BOP conversion (`vintctl convert --format bop`): "
        "ADD for objects without declared symmetries, ADD-S for the others, over the model's vertices; "
        "ADD(S) AUC up to 10 cm and ADD(S) < 0.1 × the object's diameter; occlusion 1 - `visib_fract`. "
        "The pooled ranges and the per-object and per-hand tables sum eval's per-estimate errors the "
        "way eval does (`study/pose_scores.py`; the study checks it reproduces eval's bucket AUCs).",
        f"- The taxel positions the estimator computes from the native record agree with the BOP "
        f"export's `scene_touch.json` (`p_cam_mm`) within {run.taxel_gap_mm:.1e} mm.",
        "",
        "## Results by occlusion",
        "",
        "| occlusion % | n | start AUC | vision AUC | vision+touch AUC "
        "| vision < 0.1d % | vision+touch < 0.1d % |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    by = {(s["variant"], s["bucket"]): s for s in summary}
    for name in (*BUCKETS, "all"):
        v, vt = by[(VISION, name)], by[(VISION_TOUCH, name)]
        if v["n"] == 0:
            continue
        label = f"**{name}**" if name == "all" else name
        lines.append(
            f"| {label} | {v['n']} | {v['start_auc']:.1f} | {v['auc']:.1f} | {vt['auc']:.1f} | "
            f"{v['adds_01d_pct']:.1f} | {vt['adds_01d_pct']:.1f} |"
        )
    lines += ["", "ADD(S) AUC by object and by hand, over all views and at low and high occlusion:", ""]
    lines += [*group_table(rows, "object"), "", *group_table(rows, "hand")]
    lines += [
        "",
        f"![AUC against occlusion]({PLOT_PNG})",
        "",
        f"Per estimate: `{ROWS_CSV}` (one row per view and variant); per bucket: `{SUMMARY_CSV}`.",
        "",
        "## Cost",
        "",
        "| variant | ICP CPU ms per estimate (median) | wall ms (median) | iterations (median) |",
        "|---|---:|---:|---:|",
    ]
    for variant in VARIANTS:
        lines.append(f"| {variant} | {cpu[variant]:.1f} | {wall[variant]:.1f} | {iters[variant]:.0f} |")
    lines += [
        "",
        f"CPU time is the thread's (`time.thread_time`); wall time swings with the other jobs on a shared "
        f"machine. The whole study took {run.total_s:.0f} s, data generation included.",
        "",
        "## Guards",
        "",
        f"- Views whose grasp has no active taxel (vision + touch = vision): {no_taxels} of {n_views}.",
        f"- Fewer than {MIN_POINTS} usable points (the start pose is reported): vision {too_few[VISION]}, "
        f"vision + touch {too_few[VISION_TOUCH]}.",
        f"- Degenerate systems (a direction the points do not constrain, curvature < 1e-6 of the largest; "
        f"damped, not fatal): vision {degenerate[VISION]}, vision + touch {degenerate[VISION_TOUCH]}.",
        "",
        "## Caveats",
        "",
        "- One classical estimator, a local one: ICP refines a start 15–30° and 20–40 mm off; it finds no "
        "pose from scratch. Touch helps it by constraining surfaces the camera does not see; a learned "
        "estimator (the paper's) may use touch differently.",
        "- Taxel positions come from the simulated hand's exact kinematics; a real hand's joint encoders "
        "and calibration add millimetres that this study does not model.",
        "- Textured objects whose shape is symmetric (the soup can is a plain cylinder to ICP) are scored "
        "with ADD as their texture demands: neither depth nor touch can see the turn about the axis, so "
        "ICP leaves most of the start's spin in place and these objects score lowest for both variants.",
        "- Views at 90–100 % occlusion are few, and the occlusion distribution follows the spec's camera "
        "ranges, not the paper's data.",
        "- AUC is eval's VOCap sum, which exceeds the exact area under the curve by at most 100/n points "
        "(0.3 for a bucket of 300 views, 2 for one of 50).",
        "",
    ]
    return "\n".join(lines)
