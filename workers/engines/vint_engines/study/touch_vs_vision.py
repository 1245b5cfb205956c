"""Touch against vision: does ICP on depth plus the active taxels lose less accuracy as the hand
hides more of the object than ICP on depth alone? (VinT-6D's Table 6 direction, tested with a
classical estimator on our own data.)

The study makes its dataset with vintctl itself (`vintctl run` of the spec below, into
`WORK/data`, then `vintctl convert --format bop` into `WORK/bop`), estimates every view twice
(`touch_estimate`) from the native files, writes the start poses and both variants as BOP results
CSVs (`WORK/estimates/`), scores each with `vintctl eval --json` on the BOP conversion (ADD for
asymmetric objects, ADD-S for those with declared symmetries) and reports by occlusion bucket
(`touch_report`). The dataset and the job state stay in WORK, so a second run reuses the job
instead of regenerating it.
"""

from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vint_engines.study import touch_report
from vint_engines.study.icp import Surface, sample_surface
from vint_engines.study.touch_estimate import VARIANTS, ViewEstimates, estimate_view
from vint_engines.study.touch_inputs import View, object_ids, read_model_mm, read_views

STUDY_SEED = 20261210
HANDS = ("trx3", "allegro")
# Three objects ADD scores (the paper's soup can, the mustard bottle, the mug with its handle, the
# potted-meat box) and two ADD-S scores (the tuna can, the blue bottle).
OBJECTS = ("tomato_soup_can", "mustard_bottle", "mug", "potted_meat_can", "tuna_fish_can", "blue_bottle")
QUICK_OBJECTS = ("mustard_bottle", "tuna_fish_can")
SURFACE_SAMPLES = 2000  # model-surface samples ICP matches against (≈ one per 3 mm on a can)


@dataclass(frozen=True)
class RunSize:
    objects: tuple[str, ...]
    accepted_per_pair: int
    trials_per_pair: int
    views: int


FULL = RunSize(OBJECTS, accepted_per_pair=8, trials_per_pair=32, views=16)
QUICK = RunSize(QUICK_OBJECTS, accepted_per_pair=1, trials_per_pair=4, views=6)


def spec_toml(size: RunSize, seed: int = STUDY_SEED) -> str:
    """The study's dataset spec. Only the outputs ICP needs (no rgb: nothing is path traced).
    Cameras 0.3–0.45 m away all round the hand (elevation -60…80°) and many views per grasp, so
    the hand hides 0–90 % of the object; the wide 2×2-binned mode is the Azure Kinect's one whose
    range starts before 0.3 m."""
    objects = ", ".join(f'"{o}"' for o in size.objects)
    hands = ", ".join(f'"{h}"' for h in HANDS)
    return f"""# The touch-vs-vision study's dataset (vint_engines/study/touch_vs_vision.py writes this file).
hands = [{hands}]
objects = [{objects}]

[dataset]
name = "touch_vs_vision"
seed = {seed}

[grasp]
trials_per_pair = {size.trials_per_pair}
accepted_per_pair = {size.accepted_per_pair}
chunk_size = {max(1, size.trials_per_pair // 2)}
hold_s = 0.5

[render]
resolution = [160, 160]
views_per_environment = {size.views}
environments = ["studio"]
fov_deg = 45.0
radius_m = [0.3, 0.45]
elevation_deg = [-60.0, 80.0]

[noise]
mode = "wfov_2x2binned"

[outputs]
modalities = ["depth", "depth_noisy", "mask", "pose"]
"""


def run_vintctl(vintctl: Path, *args: str | Path) -> str:
    command = [str(vintctl), *(str(a) for a in args)]
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed ({done.returncode}):\n{done.stderr[-4000:]}")
    return done.stdout


def make_dataset(vintctl: Path, spec: Path, work: Path) -> tuple[Path, Path]:
    """The study's native dataset (`WORK/data`) and its BOP conversion (`WORK/bop`, made afresh)."""
    data, bop = work / "data", work / "bop"
    print(f"study touch: generating the dataset ({spec}) into {data}", file=sys.stderr, flush=True)
    run_vintctl(vintctl, "run", spec, "--out", data, "--state", work / "state", "--workers", "2")
    if bop.exists():
        shutil.rmtree(bop)
    run_vintctl(vintctl, "convert", data, "--out", bop, "--format", "bop")
    return data, bop


def bop_scenes(bop: Path) -> dict[str, int]:
    """BOP scene id of each grasp, as the conversion numbered them (its `dataset.json`)."""
    doc = json.loads((bop / "dataset.json").read_text(encoding="utf-8"))
    return {scene["grasp_id"]: int(scene["scene_id"]) for scene in doc["bop"]["scenes"]}


def check_taxels(views: list[View], bop: Path, scenes: dict[str, int]) -> float:
    """The estimator's taxel positions (computed from the native record) against the BOP export's
    `scene_touch.json` `p_cam_mm`, computed by the exporter: two independent transforms of the same
    taxels must agree. Returns the largest difference (mm); raises beyond 0.01 mm."""
    where = {
        int(s["scene_id"]): s["split"]
        for s in json.loads((bop / "dataset.json").read_text())["bop"]["scenes"]
    }
    worst, cache = 0.0, {}
    for view in views:
        scene = scenes[view.grasp_id]
        if scene not in cache:
            path = bop / where[scene] / f"{scene:06d}" / "scene_touch.json"
            cache[scene] = json.loads(path.read_text(encoding="utf-8"))
        exported = np.asarray(
            [t["p_cam_mm"] for t in cache[scene][str(view.view)]["active"]], dtype=np.float64
        )
        if exported.shape != view.touch_mm.shape:
            raise RuntimeError(
                f"{view.sample_id}: {len(view.touch_mm)} active taxels, the BOP export has {len(exported)}"
            )
        if len(exported):
            worst = max(worst, float(np.abs(exported - view.touch_mm).max()))
    if worst > 0.01:
        raise RuntimeError(f"taxel positions differ from the BOP export's scene_touch.json by {worst:.4f} mm")
    return worst


def surfaces(data: Path, names: set[str], seed: int) -> dict[str, Surface]:
    """Each object's model-surface samples for ICP (mm), seeded per object."""
    found = {}
    for i, name in enumerate(sorted(names)):
        vertices, faces = read_model_mm(data, name)
        found[name] = sample_surface(vertices, faces, SURFACE_SAMPLES, np.random.default_rng([seed, i]))
    return found


def fit_all(views: list[View], data: Path, seed: int) -> list[ViewEstimates]:
    samples = surfaces(data, {v.object for v in views}, seed)
    fitted = []
    for i, view in enumerate(views):
        fitted.append(estimate_view(view, samples[view.object], seed))
        if (i + 1) % 100 == 0:
            print(f"study touch: {i + 1}/{len(views)} views estimated", file=sys.stderr, flush=True)
    return fitted


def write_bop_results(path: Path, rows: list[tuple[int, int, int, np.ndarray, np.ndarray, float]]) -> None:
    """A BOP results CSV: scene_id,im_id,obj_id,score,R,t,time (R row-major, t in mm, time in s)."""
    with path.open("w", newline="", encoding="utf-8") as file:
        out = csv.writer(file)
        out.writerow(["scene_id", "im_id", "obj_id", "score", "R", "t", "time"])
        for scene, im, obj, R, t, seconds in rows:
            r = " ".join(f"{v:.9f}" for v in R.reshape(-1))
            out.writerow([scene, im, obj, 1, r, " ".join(f"{v:.6f}" for v in t), f"{seconds:.6f}"])


def score(vintctl: Path, bop: Path, results: Path) -> dict[str, Any]:
    """`vintctl eval --json` of one results file; `by_image` indexes its per-estimate list."""
    report = json.loads(run_vintctl(vintctl, "eval", "--dataset", bop, "--estimates", results, "--json"))
    report["by_image"] = {(e["scene_id"], e["im_id"]): e for e in report["per_estimate"]}
    return report


def main(out: Path, quick: bool, vintctl: Path, work: Path | None) -> int:
    started = time.perf_counter()
    size = QUICK if quick else FULL
    work = work or Path(".vint") / ("study-touch-quick" if quick else "study-touch")
    work.mkdir(parents=True, exist_ok=True)
    out.mkdir(parents=True, exist_ok=True)
    spec = out / touch_report.SPEC_TOML
    spec.write_text(spec_toml(size), encoding="utf-8")
    generated = time.perf_counter()
    data, bop = make_dataset(vintctl, spec, work)
    generated = time.perf_counter() - generated
    seed = int(json.loads((data / "dataset.json").read_text(encoding="utf-8"))["seed"])
    views = list(read_views(data, noisy=True))
    scenes, ids = bop_scenes(bop), object_ids(data)
    taxel_gap = check_taxels(views, bop, scenes)
    fitted = fit_all(views, data, seed)

    estimates = work / "estimates"
    estimates.mkdir(exist_ok=True)
    keys = [(scenes[v.grasp_id], v.view, ids[v.object]) for v in views]
    poses = {"start": [(f.start_R, f.start_t, -1.0) for f in fitted]}
    for variant in VARIANTS:
        poses[variant] = [(e.R, e.t, e.wall_ms / 1000.0) for e in (f.by_variant[variant] for f in fitted)]
    scored = {}
    for name, found in poses.items():
        path = estimates / f"{name}.csv"
        write_bop_results(path, [(*key, *pose) for key, pose in zip(keys, found, strict=True)])
        scored[name] = score(vintctl, bop, path)

    rows = [
        touch_report.row(view, f.by_variant[variant], key[0], scored[variant]["by_image"][key[:2]],
                         scored["start"]["by_image"][key[:2]])
        for view, f, key in zip(views, fitted, keys, strict=True)
        for variant in VARIANTS
    ]  # fmt: skip
    run = touch_report.RunInfo(
        quick=quick, seed=seed, views=len(views), grasps=len({v.grasp_id for v in views}),
        objects=sorted({v.object for v in views}), hands=sorted({v.hand for v in views}),
        generate_s=generated, total_s=time.perf_counter() - started, taxel_gap_mm=taxel_gap,
    )  # fmt: skip
    written = touch_report.write(out, rows, scored, run)
    print(f"study done in {time.perf_counter() - started:.1f} s: " + ", ".join(str(p) for p in written))
    return 0
