"""`stats.md`: the numbers of `numbers.compute` as markdown tables, next to the figures that draw
them. Formats only; computes nothing that stats.json does not hold."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from vint_engines.stats import plots

SUMMARY_COLUMNS = ("count", "mean", "min", "p10", "p25", "p50", "p75", "p90", "max")


def markdown(stats: dict[str, Any]) -> str:
    sections = [
        header(stats),
        occlusion(stats),
        distance(stats),
        orientation(stats),
        taxels(stats),
        acceptance(stats),
        in_hand(stats),
        camera_palm(stats),
        counts(stats),
    ]
    return "\n\n".join(sections) + "\n"


def table(columns: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    lines = ["| " + " | ".join(columns) + " |", "|" + "|".join("---" for _ in columns) + "|"]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def cell(value: Any) -> str:
    if value is None:
        return "–"
    if isinstance(value, float):
        return f"{value:.3f}"
    return str(value)


def summary_row(s: dict[str, Any], scale: float = 1.0) -> list[Any]:
    return [s["count"], *(None if s[c] is None else s[c] * scale for c in SUMMARY_COLUMNS[1:])]


def percent(part: int, whole: int) -> str:
    return "–" if whole == 0 else f"{100 * part / whole:.1f} %"


def header(stats: dict[str, Any]) -> str:
    c = stats["counts"]
    return (
        f"# Dataset statistics\n\n"
        f"{c['samples']} samples of {c['grasps']} grasps; {c['objects']} objects "
        f"({', '.join(stats['objects'])}) × {c['hands']} hands ({', '.join(stats['hands'])}); "
        f"read from the {stats['layout']} layout. Figures: "
        + ", ".join(f"`{name}`" for name in plots.PNGS)
        + "; every number here is in `stats.json`."
    )


def occlusion(stats: dict[str, Any]) -> str:
    occ = stats["occlusion"]
    hands = stats["hands"]
    total = stats["counts"]["samples"]
    bins = []
    for k, n in enumerate(occ["counts"]):
        low, high = round(100 * occ["edges"][k]), round(100 * occ["edges"][k + 1])
        closing = "]" if k == len(occ["counts"]) - 1 else ")"
        bins.append(
            [f"[{low}, {high}{closing}", n, percent(n, total), *(occ["by_hand"][h][k] for h in hands)]
        )
    pairs = [[p["object"], p["hand"], *summary_row(p["summary"], 100.0)] for p in occ["by_pair"]]
    return (
        f"## Occlusion (`{plots.OCCLUSION_PNG}`)\n\n"
        "Share of the object the hand hides: 1 - visible / full object pixels (1 when out of view).\n\n"
        + table(["occlusion (%)", "samples", "share", *hands], bins)
        + "\n\nPer pair, in %:\n\n"
        + table(
            ["object", "hand", *SUMMARY_COLUMNS],
            [*pairs, ["all", "all", *summary_row(occ["summary"], 100.0)]],
        )
    )


def distance(stats: dict[str, Any]) -> str:
    dist = stats["distance_m"]
    hands = stats["hands"]
    edges = dist["edges"]
    rows = [
        [f"[{edges[k]:.3f}, {edges[k + 1]:.3f})", n, *(dist["by_hand"][h][k] for h in hands)]
        for k, n in enumerate(dist["counts"])
    ]
    return (
        f"## Camera–object distance (`{plots.DISTANCE_PNG}`)\n\n"
        "`|t_m2c|`: from the camera centre to the object frame's origin, metres.\n\n"
        + table(["distance (m)", "samples", *hands], rows)
        + "\n\n"
        + table(SUMMARY_COLUMNS, [summary_row(dist["summary"])])
    )


def orientation(stats: dict[str, Any]) -> str:
    orient = stats["orientation"]
    rows = [
        [o, s["samples"], s["cells_seen"], f"{100 * s['coverage']:.0f} %"]
        for o, s in orient["by_object"].items()
    ]
    rows.append(
        ["all", stats["counts"]["samples"], orient["cells_seen"], f"{100 * orient['coverage']:.0f} %"]
    )
    return (
        f"## Viewing direction in the object frame (`{plots.ORIENTATION_PNG}`)\n\n"
        f"The direction from the object's origin to the camera, in the object frame, binned on "
        f"{orient['cells']} equal-area cells of the sphere (12 azimuth sectors × 6 bands of equal "
        "sin(elevation)); coverage is the share of cells at least one view falls in.\n\n"
        + table(["object", "samples", "cells seen", "coverage"], rows)
        + "\n\nElevation of the viewing direction above the object's xy plane (°; the azimuth is "
        "circular, so it has no meaningful mean: the map shows it):\n\n"
        + table(SUMMARY_COLUMNS, [summary_row(orient["elevation_deg"])])
    )


def taxels(stats: dict[str, Any]) -> str:
    tax = stats["taxels"]
    per_hand = [[h, *summary_row(s["active"])] for h, s in tax["by_hand"].items()]
    per_region = [
        [h, r, s["regions"][r]["total"], touching(s, r), *summary_row(s["regions"][r]["per_grasp"])[1:]]
        for h, s in tax["by_hand"].items()
        for r in tax["regions"]
    ]
    return (
        f"## Active taxels per grasp (`{plots.TAXELS_PNG}`)\n\n"
        "Per accepted grasp (one touch reading, shared by its views), by hand:\n\n"
        + table(["hand", "grasps", *SUMMARY_COLUMNS[1:]], per_hand)
        + "\n\nBy region of the hand's taxel layout:\n\n"
        + table(["hand", "region", "total", "grasps touching", *SUMMARY_COLUMNS[1:]], per_region)
    )


def touching(hand: dict[str, Any], region: str) -> str:
    return f"{hand['regions'][region]['grasps_touching']}/{hand['grasps']}"


def acceptance(stats: dict[str, Any]) -> str:
    title = f"## Grasp acceptance (`{plots.ACCEPTANCE_PNG}`)\n\n"
    pairs = stats["pairs"]
    if pairs is None:
        return title + "No `dataset.json`: this dataset does not record its grasp trials."
    reasons = pairs["reasons"]
    rows = [
        [p["object"], p["hand"], p["trials"], p["accepted"], percent(p["accepted"], p["trials"])]
        + [p["rejected"][r] for r in reasons]
        for p in pairs["pairs"]
    ]
    t = pairs["total"]
    rows.append(["all", "all", t["trials"], t["accepted"], percent(t["accepted"], t["trials"])])
    rows[-1] += [t["rejected"][r] for r in reasons]
    return (
        title
        + "Trials per (object, hand) pair from `dataset.json`, and why the rejected ones were rejected.\n\n"
        + table(
            ["object", "hand", "trials", "accepted", "acceptance", *(f"rejected: {r}" for r in reasons)], rows
        )
    )


def in_hand(stats: dict[str, Any]) -> str:
    title = f"## Object pose in the palm frame (`{plots.IN_HAND_PNG}`)\n\n"
    pose = stats["in_hand"]
    if pose is None:
        return title + "Unavailable: the dataset's records carry no palm pose."

    def row(name: str, s: dict[str, Any]) -> list[Any]:
        return [
            name,
            s["grasps"],
            s["x_mm"]["mean"],
            s["y_mm"]["mean"],
            s["z_mm"]["mean"],
            s["z_mm"]["min"],
            s["z_mm"]["max"],
            s["distance_mm"]["p50"],
            s["object_z_cos"]["p50"],
        ]

    columns = [
        "",
        "grasps",
        "mean x",
        "mean y",
        "mean z",
        "min z",
        "max z",
        "median distance",
        "median cos z",
    ]
    rows = [row(f"hand {h}", s) for h, s in pose["by_hand"].items()]
    rows += [row(f"object {o}", s) for o, s in pose["by_object"].items()]
    rows += [row(f"{p['object']} / {p['hand']}", p) for p in pose["by_pair"]]
    rows.append(row("all", pose["all"]))
    return (
        title + "Per accepted grasp, the object frame's origin in the palm frame (mm; +z the palm normal, "
        "+y up across the palm), its distance from the palm frame's origin (mm), and the cosine "
        "between the object's +z axis and the palm normal.\n\n" + table(columns, rows)
    )


def camera_palm(stats: dict[str, Any]) -> str:
    title = f"## Camera relative to the palm (`{plots.CAMERA_PALM_PNG}`)\n\n"
    cam = stats["camera_palm"]
    if cam is None:
        return title + "Unavailable: the dataset's records carry no palm pose."
    groups = [*((h, s) for h, s in cam["by_hand"].items()), ("all", cam["all"])]
    rows = [
        [
            name,
            s["samples"],
            s["front"],
            s["back"],
            percent(s["back"], s["samples"]),
            s["palm_facing"]["p50"],
            s["elevation_deg"]["min"],
            s["elevation_deg"]["p50"],
            s["elevation_deg"]["max"],
        ]
        for name, s in groups
    ]
    edges = cam["edges"]
    bins = [
        [
            f"[{edges[k]:.1f}, {edges[k + 1]:.1f}{']' if k == len(edges) - 2 else ')'}",
            *(s["counts"][k] for _, s in groups),
        ]
        for k in range(len(edges) - 1)
    ]
    return (
        title + "Per view, palm_facing: the cosine between the palm normal and the direction from the palm "
        "frame's origin to the camera (= sin of the camera's elevation above the palm plane; < 0 "
        "looks at the back of the palm).\n\n"
        + table(
            [
                "hand",
                "samples",
                "front",
                "back",
                "back share",
                "median palm_facing",
                "min elev.",
                "median elev.",
                "max elev.",
            ],
            rows,
        )
        + "\n\n"
        + table(["palm_facing", *(name for name, _ in groups)], bins)
    )


def counts(stats: dict[str, Any]) -> str:
    hands = stats["hands"]
    objects = [
        [
            o,
            s["grasps"],
            s["samples"],
            *(f"{s['by_hand'][h]['grasps']} / {s['by_hand'][h]['samples']}" for h in hands),
        ]
        for o, s in stats["per_object"].items()
    ]
    environments = [
        [e, s["samples"], *(s["by_hand"][h] for h in hands)] for e, s in stats["per_environment"].items()
    ]
    types = stats["grasp_types"]
    if types is None:
        type_table = "Unavailable: this layout does not carry the grasp type (only grasp.json does)."
    else:
        type_table = table(
            ["grasp type", "accepted grasps", *hands],
            [[t, types["counts"][t], *(types["by_hand"][h][t] for h in hands)] for t in types["types"]],
        )
    return (
        f"## Counts (`{plots.COUNTS_PNG}`)\n\n"
        "Accepted grasps and samples per object (per hand: grasps / samples):\n\n"
        + table(["object", "grasps", "samples", *hands], objects)
        + "\n\nSamples per environment (the HDRI of the view's render):\n\n"
        + table(["environment", "samples", *hands], environments)
        + "\n\nAccepted grasps per grasp type (grasp.json `trial.grasp.type`; `unknown`: a record "
        "from before grasp types):\n\n" + type_table
    )
