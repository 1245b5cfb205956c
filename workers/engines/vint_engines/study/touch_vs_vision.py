"""Touch against vision: does ICP on depth plus the active taxels lose less accuracy as the hand
hides more of the object than ICP on depth alone? (VinT-6D's Table 6 direction, tested with a
classical estimator on our own data.)

The study makes its dataset with vintctl itself (`vintctl run` of the spec below, into
`WORK/data`), estimates every view twice (`touch_estimate`), writes both as BOP results CSVs,
scores them (`pose_scores`: ADD for asymmetric objects, ADD-S for those with declared symmetries)
and reports by occlusion bucket (`touch_report`). The dataset and the job state stay in WORK, so a
second run reuses the job instead of regenerating it.
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vint_engines.study import pose_scores, touch_report
from vint_engines.study.icp import Surface, sample_surface
from vint_engines.study.touch_estimate import VARIANTS, Estimate, estimate_view
from vint_engines.study.touch_inputs import (
    View,
    object_ids,
    read_model_mm,
    read_views,
    scene_ids,
    symmetric_objects,
)

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


def run_vintctl(vintctl: Path, *args: str | Path) -> subprocess.CompletedProcess[str]:
    command = [str(vintctl), *(str(a) for a in args)]
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed ({done.returncode}):\n{done.stderr[-4000:]}")
    return done


def make_dataset(vintctl: Path, spec: Path, work: Path) -> Path:
    data = work / "data"
    print(f"study touch: generating the dataset ({spec}) into {data}", file=sys.stderr, flush=True)
    run_vintctl(vintctl, "run", spec, "--out", data, "--state", work / "state", "--workers", "2")
    return data


def diameters_mm(data: Path) -> dict[str, float]:
    doc = json.loads((data / "dataset.json").read_text(encoding="utf-8"))
    return {entry["name"]: float(entry["diameter_mm"]) for entry in doc["objects"]}


def write_bop_results(path: Path, rows: list[tuple[int, int, int, Estimate]]) -> None:
    """A BOP results CSV: scene_id,im_id,obj_id,score,R,t,time (R row-major, t in mm, time in s;
    BOP: the same time for every estimate of an image)."""
    with path.open("w", newline="", encoding="utf-8") as file:
        out = csv.writer(file)
        out.writerow(["scene_id", "im_id", "obj_id", "score", "R", "t", "time"])
        for scene, im, obj, est in rows:
            r = " ".join(f"{v:.9f}" for v in est.R.reshape(-1))
            t = " ".join(f"{v:.6f}" for v in est.t)
            out.writerow([scene, im, obj, 1, r, t, f"{est.wall_ms / 1000.0:.6f}"])


def object_infos(
    data: Path, names: set[str], seed: int
) -> tuple[dict[str, Surface], dict[str, touch_report.ObjectInfo]]:
    """Each object's surface samples (for ICP) and what scoring needs (model vertices in mm, id,
    symmetry, diameter)."""
    ids, symmetric, diameters = object_ids(data), symmetric_objects(data), diameters_mm(data)
    samples, infos = {}, {}
    for i, name in enumerate(sorted(names)):
        vertices, faces = read_model_mm(data, name)
        samples[name] = sample_surface(vertices, faces, SURFACE_SAMPLES, np.random.default_rng([seed, i]))
        infos[name] = touch_report.ObjectInfo(ids[name], name in symmetric, diameters[name], vertices)
    return samples, infos


def estimate_all(views: list[View], data: Path, seed: int) -> list[dict[str, Any]]:
    """Both variants for every view, scored; one row per (view, variant)."""
    samples, infos = object_infos(data, {v.object for v in views}, seed)
    scenes = scene_ids(views)
    rows: list[dict[str, Any]] = []
    for i, view in enumerate(views):
        found = estimate_view(view, samples[view.object], seed)
        start = (found.start_R, found.start_t)
        for variant in VARIANTS:
            rows.append(
                touch_report.row(
                    view, start, found.by_variant[variant], scenes[view.grasp_id], infos[view.object]
                )
            )
        if (i + 1) % 100 == 0:
            print(f"study touch: {i + 1}/{len(views)} views estimated", file=sys.stderr, flush=True)
    return rows


def main(out: Path, quick: bool, vintctl: Path, work: Path | None) -> int:
    started = time.perf_counter()
    size = QUICK if quick else FULL
    work = work or Path(".vint") / ("study-touch-quick" if quick else "study-touch")
    work.mkdir(parents=True, exist_ok=True)
    out.mkdir(parents=True, exist_ok=True)
    spec = out / touch_report.SPEC_TOML
    spec.write_text(spec_toml(size), encoding="utf-8")
    generated = time.perf_counter()
    data = make_dataset(vintctl, spec, work)
    generated = time.perf_counter() - generated
    seed = int(json.loads((data / "dataset.json").read_text(encoding="utf-8"))["seed"])
    views = list(read_views(data, noisy=True))
    rows = estimate_all(views, data, seed)
    estimates = work / "estimates"
    estimates.mkdir(exist_ok=True)
    for variant in VARIANTS:
        write_bop_results(
            estimates / f"{variant}.csv",
            [
                (r["scene_id"], r["im_id"], r["obj_id"], r["_estimate"])
                for r in rows
                if r["variant"] == variant
            ],
        )
    run = touch_report.RunInfo(
        quick=quick, seed=seed, views=len(views), grasps=len({v.grasp_id for v in views}),
        objects=sorted({v.object for v in views}), hands=sorted({v.hand for v in views}),
        generate_s=generated, total_s=time.perf_counter() - started, scorer=pose_scores.SCORER,
    )  # fmt: skip
    written = touch_report.write(out, rows, run)
    print(f"study done in {time.perf_counter() - started:.1f} s: " + ", ".join(str(p) for p in written))
    return 0
