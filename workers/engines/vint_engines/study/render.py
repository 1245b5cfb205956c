"""The render study: image error against render time, for Cycles sample counts with and without the
denoiser, against a high-sample reference of the same views, at the recipe's 640×480.

`python -m vint_engines study render --out DIR [--quick]` (or `vintctl study render`). Grasps come
from the real grasp engine; every view is rendered through `RenderEngine.run`, the code path a
worker uses, on one warm engine with the default scene (table, arm flange), so the times are
per-view render times without start-up. Per view and configuration it records the RGB error
against the reference on the whole image and on the foreground alone — the object, hand and arm
pixels of the segmentation, where a pose network looks and where fireflies land — as RMSE on
[0, 1] sRGB, PSNR in dB and SSIM, counts isolated bright pixels on the foreground, and checks that
depth, masks and segmentation are exactly the reference's (they come from the first hit and must
not depend on sample count or denoising).

The ceiling: for the first view of each scene, each configuration's RGB scene is saved as a
.blend and rendered again by a fresh Blender process that only opens it and calls
`bpy.ops.render.render` (a warm-up render, then a timed one), with Cycles' own denoiser where the
configuration denoises: what bare bpy needs for the same image, with none of the engine's work
around it (geometry passes, pass files, its own denoiser call, sensor, files, records).

Writes `render_study.csv` (one row per configuration × scene × view), `render_study_summary.csv`
(medians per configuration), a log–log plot of foreground error against time (`render_study.png`)
and a markdown table (`render_study.md`) that names the cheapest configuration reaching the PSNR
target on the foreground.
"""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from vint_engines import depth_file
from vint_engines.protocol import TaskRequest
from vint_engines.render.fireflies import spike_mask
from vint_engines.study.grasped import GraspedScene, grasp

ROWS_CSV = "render_study.csv"
SUMMARY_CSV = "render_study_summary.csv"
PLOT_PNG = "render_study.png"
TABLE_MD = "render_study.md"

# A configuration is good enough when its median PSNR against the reference reaches this: at
# 35 dB the RMS error is under 1.8 % of full scale, below the 8-bit quantisation of most textures'
# visible noise and well below the sensor noise of the RGB cameras VinT-6D's real half was shot with.
TARGET_PSNR_DB = 35.0

SCENES = (("allegro", "mustard_bottle", (11, 12, 13, 14)), ("trx3", "wine_glass", tuple(range(201, 209))))
ENVIRONMENTS = ("studio", "forest")
SPIKE = 0.3  # a firefly: brighter than all 8 neighbours by this share of full scale
# Segmentation labels that make up the foreground.
FOREGROUND = ("object", "hand/", "arm/")


@dataclass(frozen=True)
class Config:
    samples: int
    denoise: bool

    @property
    def name(self) -> str:
        return f"{self.samples}spp{'+denoise' if self.denoise else ''}"


@dataclass(frozen=True)
class Plan:
    configs: tuple[Config, ...]
    reference: Config
    size: tuple[int, int]
    views: int
    scenes: tuple[tuple[str, str, tuple[int, ...]], ...]
    fov_deg: float = 60.0
    radius_m: tuple[float, float] = (0.5, 0.65)
    ceiling: bool = True


FULL = Plan(
    configs=tuple(Config(s, d) for s in (8, 16, 32, 64) for d in (False, True)),
    reference=Config(512, False),
    size=(640, 480),
    views=2,
    scenes=SCENES,
)
QUICK = Plan(
    configs=(Config(4, False), Config(4, True), Config(16, False)),
    reference=Config(256, False),
    size=(64, 48),
    views=1,
    scenes=SCENES[:1],
    radius_m=(0.4, 0.5),
)


@dataclass(frozen=True)
class ViewImages:
    rgb: np.ndarray
    exact: dict[str, np.ndarray]  # depth, masks, segmentation: must equal the reference's
    foreground: np.ndarray  # object, hand and arm pixels (from the segmentation and its id map)


def render_params(scene: GraspedScene, view: int, plan: Plan, config: Config) -> dict[str, Any]:
    width, height = plan.size
    environment = ENVIRONMENTS[view % len(ENVIRONMENTS)]
    return {
        "grasp_index": scene.accepted[0],
        "render": {
            "width": width,
            "height": height,
            "samples": config.samples,
            "denoise": config.denoise,
            "fov_deg": plan.fov_deg,
            "environment": environment,
            "radius_m": list(plan.radius_m),
            "elevation_deg": [15.0, 75.0],
            "sensor": {"enabled": False},  # the renderer's error alone, not the camera's noise
            "despeckle": 0.0,  # raw configurations as Cycles renders them: their fireflies are counted
        },
        "views": [{"view_index": view, "seed": 7000 + 31 * view, "environment": environment}],
    }


def read_view(out_dir: Path, view: int) -> ViewImages:
    prefix = out_dir / f"v{view:02d}"
    rgb = cv2.imread(f"{prefix}_rgb.png", cv2.IMREAD_COLOR)
    if rgb is None:
        raise RuntimeError(f"no RGB image at {prefix}_rgb.png")
    depth = depth_file.find(out_dir, f"v{view:02d}_depth")
    if depth is None:
        raise RuntimeError(f"no depth image at {prefix}_depth.png or .npy")
    exact = {"depth": depth_file.read(depth)}
    for png in sorted(out_dir.glob(f"v{view:02d}_*.png")):
        kind = png.stem.split("_", 1)[1]
        if kind not in ("rgb", "depth"):
            exact[kind] = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
    labels = json.loads(Path(f"{prefix}_camera.json").read_text())["segmentation"]
    ids = [int(k) for k, name in labels.items() if name.startswith(FOREGROUND)]
    foreground = np.isin(exact["segmentation"], ids)
    return ViewImages(rgb.astype(np.float64) / 255.0, exact, foreground)


def psnr(rmse: float) -> float:
    return math.inf if rmse == 0.0 else 20.0 * math.log10(1.0 / rmse)


def ssim_map(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per-pixel SSIM of two grey images in [0, 1] (Wang et al. 2004: 11×11 Gaussian window,
    σ 1.5, K1 0.01, K2 0.03)."""
    c1, c2 = 0.01**2, 0.03**2
    blur = lambda x: cv2.GaussianBlur(x, (11, 11), 1.5)  # noqa: E731
    mu_a, mu_b = blur(a), blur(b)
    var_a = blur(a * a) - mu_a**2
    var_b = blur(b * b) - mu_b**2
    cov = blur(a * b) - mu_a * mu_b
    return ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a**2 + mu_b**2 + c1) * (var_a + var_b + c2))


def compare(images: ViewImages, reference: ViewImages) -> dict[str, Any]:
    error = (images.rgb - reference.rgb) ** 2
    rmse = float(np.sqrt(np.mean(error)))
    fg = reference.foreground
    fg_rmse = float(np.sqrt(np.mean(error[fg]))) if fg.any() else 0.0
    grey = lambda x: cv2.cvtColor(x.astype(np.float32), cv2.COLOR_BGR2GRAY).astype(np.float64)  # noqa: E731
    ssim = ssim_map(grey(images.rgb), grey(reference.rgb))
    differing = {
        kind: int(np.count_nonzero(images.exact[kind] != reference.exact[kind]))
        for kind in reference.exact
        if kind in images.exact
    }
    return {
        "rmse": rmse,
        "psnr_db": psnr(rmse),
        "fg_px": int(fg.sum()),
        "fg_rmse": fg_rmse,
        "fg_psnr_db": psnr(fg_rmse),
        "fg_ssim": float(ssim[fg].mean()) if fg.any() else 1.0,
        "fg_spikes": int((spike_mask(np.rint(images.rgb * 255.0).astype(np.uint8), SPIKE) & fg).sum()),
        "exact_pixels_differing": sum(differing.values()),
        "exact_outputs": "+".join(sorted(differing)),
    }


def run_study(plan: Plan, work: Path) -> list[dict[str, Any]]:
    from vint_engines.render.engine import RenderEngine

    engine = RenderEngine()
    scenes = [grasp(hand, obj, work / f"grasp_{hand}_{obj}", list(seeds)) for hand, obj, seeds in plan.scenes]
    rows = []
    try:
        for scene in scenes:
            for view in range(plan.views):
                reference, _ = render(engine, scene, view, plan, plan.reference, work, warm=False)
                warmed: set[bool] = set()
                for config in plan.configs:
                    # One untimed render per view and denoiser setting: the scene and kernels
                    # stay loaded between configurations, which differ only in samples.
                    warm = config.denoise not in warmed
                    warmed.add(config.denoise)
                    images, seconds = render(engine, scene, view, plan, config, work, warm)
                    bare = bare_bpy_seconds(work) if plan.ceiling and view == 0 else math.nan
                    rows.append(
                        {
                            "config": config.name,
                            "samples": config.samples,
                            "denoise": int(config.denoise),
                            "hand": scene.hand,
                            "object": scene.object,
                            "view": view,
                            **compare(images, reference),
                            "wall_ms": 1e3 * seconds,
                            "bare_bpy_ms": 1e3 * bare,
                        }
                    )
                    print(
                        f"{config.name:>16} {scene.object:>16} v{view} "
                        f"fg psnr={rows[-1]['fg_psnr_db']:.2f} dB "
                        f"fg ssim={rows[-1]['fg_ssim']:.4f} spikes={rows[-1]['fg_spikes']} "
                        f"wall={rows[-1]['wall_ms']:.0f} ms bare={rows[-1]['bare_bpy_ms']:.0f} ms",
                        flush=True,
                    )
    finally:
        engine.close()
    return rows


def render(
    engine: Any, scene: GraspedScene, view: int, plan: Plan, config: Config, work: Path, warm: bool = True
) -> tuple[ViewImages, float]:
    """Render one view under `config` (with `warm`, after one untimed render of the same view, so
    the timed render finds the scene, environment, kernels and denoiser loaded) and read it back."""
    out_dir = work / "views" / f"{scene.object}_{config.name}_v{view}"
    params = render_params(scene, view, plan, config)
    if warm:
        engine.run(TaskRequest("study-untimed", params, scene.inputs(), _fresh(work / "untimed")))
    started = time.perf_counter()
    engine.run(TaskRequest("study", params, scene.inputs(), _fresh(out_dir)))
    return read_view(out_dir, view), time.perf_counter() - started


BARE_RENDER = """
import sys
import time
import bpy
import addon_utils
addon_utils.enable("cycles")
bpy.ops.wm.open_mainfile(filepath=sys.argv[-1])
scene = bpy.data.scenes["vint_rgb"]
# Path tracing alone, no pass files; a denoised configuration (its render stores the guides) is
# denoised by Cycles' own OpenImageDenoise call, guided the same way.
scene.compositing_node_group = None
cycles = scene.cycles
cycles.use_denoising = scene.view_layers[0].cycles.denoising_store_passes
cycles.denoiser = "OPENIMAGEDENOISE"
cycles.denoising_input_passes = "RGB_ALBEDO_NORMAL"
bpy.ops.render.render(scene=scene.name)  # warm: kernels, BVH, the HDRI's importance map
started = time.perf_counter()
bpy.ops.render.render(scene=scene.name)
print("BARE_SECONDS", time.perf_counter() - started)
"""


def bare_bpy_seconds(work: Path) -> float:
    """Seconds bare bpy takes to render the RGB scene the engine has just rendered: the scene is
    saved as a .blend, a fresh Blender process opens it, renders once to warm up, then once timed."""
    import bpy

    blend = work / "ceiling.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True, check_existing=False)
    run = subprocess.run(
        [sys.executable, "-c", BARE_RENDER, str(blend)],
        capture_output=True,
        text=True,
        timeout=3600,
        check=True,
    )
    line = next(line for line in run.stdout.splitlines() if line.startswith("BARE_SECONDS"))
    return float(line.split()[1])


def _fresh(directory: Path) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    for path in directory.iterdir():
        path.unlink()
    return directory


def summarize(rows: Sequence[dict[str, Any]], configs: Sequence[Config]) -> list[dict[str, Any]]:
    summary = []
    for config in configs:
        group = [r for r in rows if r["config"] == config.name]
        if not group:
            continue
        summary.append(
            {
                "config": config.name,
                "samples": config.samples,
                "denoise": int(config.denoise),
                "views": len(group),
                "median_rmse": statistics_median([r["rmse"] for r in group]),
                "median_psnr_db": statistics_median([r["psnr_db"] for r in group]),
                "min_psnr_db": min(r["psnr_db"] for r in group),
                "median_fg_rmse": statistics_median([r["fg_rmse"] for r in group]),
                "median_fg_psnr_db": statistics_median([r["fg_psnr_db"] for r in group]),
                "min_fg_psnr_db": min(r["fg_psnr_db"] for r in group),
                "median_fg_ssim": statistics_median([r["fg_ssim"] for r in group]),
                "fg_spikes": sum(r["fg_spikes"] for r in group),
                "median_wall_ms": statistics_median([r["wall_ms"] for r in group]),
                "median_bare_bpy_ms": statistics_median(
                    [r["bare_bpy_ms"] for r in group if not math.isnan(r["bare_bpy_ms"])] or [math.nan]
                ),
                "exact_pixels_differing": sum(r["exact_pixels_differing"] for r in group),
            }
        )
    return summary


def statistics_median(values: Sequence[float]) -> float:
    return float(np.median(np.asarray(values, dtype=np.float64)))


def recommend(summary: Sequence[dict[str, Any]]) -> dict[str, Any] | None:
    """The fastest configuration whose median foreground PSNR reaches the target with no firefly
    on the foreground, if any."""
    good = [s for s in summary if s["median_fg_psnr_db"] >= TARGET_PSNR_DB and s["fg_spikes"] == 0]
    return min(good, key=lambda s: s["median_wall_ms"]) if good else None


def write_csv(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        for row in rows:
            writer.writerow({k: round(v, 6) if isinstance(v, float) else v for k, v in row.items()})


def plot(path: Path, summary: Sequence[dict[str, Any]], reference: Config) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(6.4, 4.4), dpi=120)
    for denoise, marker in ((0, "o"), (1, "s")):
        points = sorted((s for s in summary if s["denoise"] == denoise), key=lambda s: s["samples"])
        if not points:
            continue
        axes.plot(
            [s["median_wall_ms"] for s in points],
            [max(s["median_fg_rmse"], 1e-6) for s in points],
            marker=marker,
            label="denoised" if denoise else "raw",
        )
        for s in points:
            axes.annotate(
                f"{s['samples']}", (s["median_wall_ms"], max(s["median_fg_rmse"], 1e-6)), fontsize=7
            )
        bare = [s for s in points if not math.isnan(s["median_bare_bpy_ms"])]
        if bare:
            axes.plot(
                [s["median_bare_bpy_ms"] for s in bare],
                [max(s["median_fg_rmse"], 1e-6) for s in bare],
                marker=marker,
                linestyle=":",
                color="grey",
                label=f"bare bpy ({'denoised' if denoise else 'raw'})",
            )
    target_rmse = 10 ** (-TARGET_PSNR_DB / 20)
    axes.axhline(
        target_rmse, color="grey", linestyle="--", linewidth=0.8, label=f"{TARGET_PSNR_DB:.0f} dB target"
    )
    axes.set_xscale("log")
    axes.set_yscale("log")
    axes.set_xlabel("render time per view (ms, median)")
    axes.set_ylabel(f"foreground RGB RMSE against {reference.name} (median)")
    axes.set_title("Cycles: foreground error against render time")
    axes.legend()
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)


def per_object(rows: Sequence[dict[str, Any]], configs: Sequence[Config]) -> dict[str, list[dict[str, Any]]]:
    """`summarize` for each object's rows alone: an opaque object and a glass one need very
    different sample counts, which one median over both hides."""
    objects = sorted({r["object"] for r in rows})
    return {obj: summarize([r for r in rows if r["object"] == obj], configs) for obj in objects}


def object_lines(by_object: dict[str, list[dict[str, Any]]]) -> list[str]:
    lines = ["", "## Per object", ""]
    for obj, summary in by_object.items():
        best = recommend(summary)
        lines += [
            f"**{obj}**: "
            + (
                f"fastest configuration reaching {TARGET_PSNR_DB:.0f} dB median foreground PSNR with no "
                f"foreground firefly: **{best['config']}** ({best['median_fg_psnr_db']:.1f} dB, "
                f"{best['median_wall_ms']:.0f} ms per view)."
                if best
                else f"no configuration reaches {TARGET_PSNR_DB:.0f} dB median foreground PSNR."
            ),
            "",
            "| configuration | fg PSNR (dB) median | fg PSNR min | fg SSIM median | fg spikes | ms / view |",
            "|---|---:|---:|---:|---:|---:|",
        ]
        for s in summary:
            lines.append(
                f"| {s['config']} | {s['median_fg_psnr_db']:.2f} | {s['min_fg_psnr_db']:.2f} "
                f"| {s['median_fg_ssim']:.4f} | {s['fg_spikes']} | {s['median_wall_ms']:.0f} |"
            )
        lines.append("")
    return lines


def markdown(
    summary: Sequence[dict[str, Any]],
    plan: Plan,
    best: dict[str, Any] | None,
    by_object: dict[str, list[dict[str, Any]]] | None = None,
) -> str:
    width, height = plan.size
    objects = ", ".join(f"{hand} × {obj}" for hand, obj, _ in plan.scenes)
    lines = [
        "# Render study: RGB error against render time",
        "",
        f"Scenes: {objects}, with the default scene (table, arm flange); {plan.views} views each at "
        f"{width}×{height} under {', '.join(ENVIRONMENTS)}; reference {plan.reference.name}. One warm engine "
        "on one CPU thread; *ms / view* is the engine's median time for a whole view (geometry passes, "
        "RGB, files); *bare bpy* is a fresh Blender process rendering the same saved RGB scene with "
        "`bpy.ops.render.render` alone (first view of each scene): the ceiling for the engine.",
        "*fg* is the foreground: the object, hand and arm pixels. *spikes*: foreground pixels brighter "
        f"than all 8 neighbours by more than {SPIKE}. Depth, masks and segmentation must equal the "
        "reference at every configuration (column *exact px differing*).",
        "",
        "| configuration | fg PSNR (dB) median | fg PSNR min | fg SSIM median | fg spikes "
        "| image PSNR median | ms / view | bare bpy ms | engine / bare | exact px differing |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for s in summary:
        ratio = s["median_wall_ms"] / s["median_bare_bpy_ms"] if s["median_bare_bpy_ms"] > 0 else math.nan
        lines.append(
            f"| {s['config']} | {s['median_fg_psnr_db']:.2f} | {s['min_fg_psnr_db']:.2f} "
            f"| {s['median_fg_ssim']:.4f} | {s['fg_spikes']} | {s['median_psnr_db']:.2f} "
            f"| {s['median_wall_ms']:.0f} | {s['median_bare_bpy_ms']:.0f} | {ratio:.2f} "
            f"| {s['exact_pixels_differing']} |"
        )
    lines.append("")
    if best is None:
        lines.append(f"No configuration reaches {TARGET_PSNR_DB:.0f} dB foreground PSNR without fireflies.")
    else:
        lines.append(
            f"Fastest configuration reaching {TARGET_PSNR_DB:.0f} dB median foreground PSNR with no "
            f"foreground firefly: **{best['config']}** ({best['median_fg_psnr_db']:.1f} dB, "
            f"{best['median_wall_ms']:.0f} ms per view)."
        )
    if by_object:
        lines += object_lines(by_object)
    return "\n".join(lines) + "\n"


def main(out: Path, quick: bool) -> int:
    plan = QUICK if quick else FULL
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="vint-render-study-") as tmp:
        rows = run_study(plan, Path(tmp))
    summary = summarize(rows, plan.configs)
    best = recommend(summary)
    write_csv(out / ROWS_CSV, rows)
    write_csv(out / SUMMARY_CSV, summary)
    plot(out / PLOT_PNG, summary, plan.reference)
    (out / TABLE_MD).write_text(markdown(summary, plan, best, per_object(rows, plan.configs)))
    inexact = sum(s["exact_pixels_differing"] for s in summary)
    print(f"study done in {time.perf_counter() - started:.1f} s: {out / TABLE_MD}")
    if inexact:
        print(
            f"study render: {inexact} depth/mask/segmentation pixels differ from the reference",
            file=sys.stderr,
        )
        return 1
    return 0
