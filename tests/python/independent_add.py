"""ADD and ADD-S of BOP-format pose estimates, written apart from `vintctl eval` to check it.

    independent_add.py DATASET ESTIMATES.csv [--split NAME]...   a JSON report on stdout

numpy only: its own PLY reader, brute-force nearest neighbours (every ground-truth posed point
against every estimated posed point), and the AUC in its closed form rather than as a sum over
sorted errors. Definitions (docs/metrics.md; PoseCNN's, as the BOP toolkit's `add` and `adi`):

    ADD   = mean_x ‖(R̂x + t̂) - (Rx + t)‖
    ADD-S = mean_x min_y ‖(Rx + t) - (R̂y + t̂)‖        x, y over the vertices of models_eval/ (else models/)
    AUC   = 100/T · [ Σ_i max(0, T - e_i)/n + d_max/n ],  T = 100 mm

where d_max is the largest error ≤ T (0 when none): the YCB-Video toolbox's VOCap equals the exact
area under the accuracy curve plus that last step. A ground-truth instance scores the
best-scored estimate of its (scene, image, object) (ties: the earlier line); without one its
errors are infinite. Occlusion = 1 - visib_fract, in buckets of 10 %.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]

AUC_MAX_MM = 100.0
WITHIN = {"0.1d": 0.1, "0.05d": 0.05}
BUCKETS = 10
PLY_SCALARS = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip


# --- reading ----------------------------------------------------------------------------------


def ply_vertices(path: Path) -> Array:
    """The vertex coordinates of a PLY (ascii or binary little-endian), as float64 N×3."""
    data = path.read_bytes()
    end = data.index(b"end_header")
    body = data[data.index(b"\n", end) + 1 :]
    header = data[:end].decode("ascii").splitlines()
    fmt = next(line.split()[1] for line in header if line.startswith("format"))
    elements: list[tuple[str, int, list[list[str]]]] = []
    for line in header:
        words = line.split()
        if words and words[0] == "element":
            elements.append((words[1], int(words[2]), []))
        elif words and words[0] == "property":
            elements[-1][2].append(words[1:])
    if fmt == "ascii":
        return _ascii_vertices(body.decode("ascii").split(), elements)
    if fmt != "binary_little_endian":
        raise ValueError(f"{path}: unsupported PLY format {fmt}")
    offset = 0
    for name, count, props in elements:
        if name == "vertex":
            dtype = np.dtype([(p[-1], "<" + PLY_SCALARS[p[0]]) for p in props])
            records = np.frombuffer(body, dtype=dtype, count=count, offset=offset)
            return np.stack([records[a].astype(np.float64) for a in "xyz"], axis=1)
        for _ in range(count):  # step over an element before the vertices, record by record
            for p in props:
                if p[0] == "list":
                    n = int(np.frombuffer(body, "<" + PLY_SCALARS[p[1]], 1, offset)[0])
                    offset += np.dtype(PLY_SCALARS[p[1]]).itemsize + n * np.dtype(PLY_SCALARS[p[2]]).itemsize
                else:
                    offset += np.dtype(PLY_SCALARS[p[0]]).itemsize
    raise ValueError(f"{path}: no vertex element")


def _ascii_vertices(words: list[str], elements: list[tuple[str, int, list[list[str]]]]) -> Array:
    at = 0
    for name, count, props in elements:
        rows = []
        for _ in range(count):
            row = []
            for p in props:
                if p[0] == "list":
                    n = int(words[at])
                    at += 1 + n
                    row.append(math.nan)
                else:
                    row.append(float(words[at]))
                    at += 1
            rows.append(row)
        if name == "vertex":
            names = [p[-1] for p in props]
            table = np.array(rows, dtype=np.float64).reshape(count, len(props))
            return table[:, [names.index(a) for a in "xyz"]]
    raise ValueError("no vertex element")


@dataclass
class Model:
    obj_id: int
    diameter: float
    symmetric: bool
    points: Array


@dataclass
class Instance:
    scene_id: int
    im_id: int
    gt_index: int
    obj_id: int
    R: Array
    t: Array
    visib_fract: float


def models_folder(root: Path) -> Path:
    """models_eval/ (the uniformly resampled models BOP scores on) when the dataset has it, else models/."""
    resampled = root / "models_eval"
    return resampled if (resampled / "models_info.json").is_file() else root / "models"


def load_dataset(root: Path, splits: list[str]) -> tuple[dict[int, Model], list[Instance]]:
    if not splits:
        splits = sorted(
            p.name
            for p in root.iterdir()
            if p.is_dir() and p.name not in ("models", "models_eval") and any(p.glob("*/scene_gt.json"))
        )
    instances: list[Instance] = []
    for split in splits:
        for scene in sorted((root / split).iterdir()):
            if not (scene / "scene_gt.json").is_file() or not scene.name.isdigit():
                continue
            gt = json.loads((scene / "scene_gt.json").read_text())
            info = json.loads((scene / "scene_gt_info.json").read_text())
            for im_key, listed in gt.items():
                for k, (a, i) in enumerate(zip(listed, info[im_key], strict=True)):
                    instances.append(
                        Instance(
                            scene_id=int(scene.name),
                            im_id=int(im_key),
                            gt_index=k,
                            obj_id=int(a["obj_id"]),
                            R=np.array(a["cam_R_m2c"], dtype=np.float64).reshape(3, 3),
                            t=np.array(a["cam_t_m2c"], dtype=np.float64),
                            visib_fract=float(i["visib_fract"]),
                        )
                    )
    folder = models_folder(root)
    info = json.loads((folder / "models_info.json").read_text())
    models: dict[int, Model] = {}
    for obj_id in sorted({i.obj_id for i in instances}):
        entry = info[str(obj_id)]
        symmetric = bool(entry.get("symmetries_continuous")) or bool(entry.get("symmetries_discrete"))
        points = ply_vertices(folder / f"obj_{obj_id:06d}.ply")
        models[obj_id] = Model(obj_id, float(entry["diameter"]), symmetric, points)
    instances.sort(key=lambda i: (i.scene_id, i.im_id, i.gt_index))
    return models, instances


@dataclass
class Row:
    line: int
    scene_id: int
    im_id: int
    obj_id: int
    score: float
    R: Array
    t: Array


def load_estimates(path: Path) -> list[Row]:
    rows = []
    lines = path.read_text().splitlines()
    assert lines[0].strip() == "scene_id,im_id,obj_id,score,R,t,time", lines[0]
    for number, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        scene, im, obj, score, r, t, _time = line.split(",")
        rows.append(
            Row(
                line=number,
                scene_id=int(scene),
                im_id=int(im),
                obj_id=int(obj),
                score=float(score),
                R=np.array([float(v) for v in r.split()], dtype=np.float64).reshape(3, 3),
                t=np.array([float(v) for v in t.split()], dtype=np.float64),
            )
        )
    return rows


# --- metrics ------------------------------------------------------------------------------------


def add(points: Array, R_e: Array, t_e: Array, R_g: Array, t_g: Array) -> float:
    return float(np.linalg.norm((points @ R_e.T + t_e) - (points @ R_g.T + t_g), axis=1).mean())


def adds(points: Array, R_e: Array, t_e: Array, R_g: Array, t_g: Array) -> float:
    est = points @ R_e.T + t_e
    gt = points @ R_g.T + t_g
    nearest = np.empty(len(gt))
    for start in range(0, len(gt), 512):  # every pair, a block of ground-truth points at a time
        block = gt[start : start + 512]
        d2 = ((block[:, None, :] - est[None, :, :]) ** 2).sum(axis=2)
        nearest[start : start + 512] = np.sqrt(d2.min(axis=1))
    return float(nearest.mean())


def auc(errors: list[float]) -> float | None:
    if not errors:
        return None
    e = np.array(errors, dtype=np.float64)
    kept = e[e <= AUC_MAX_MM]
    exact = np.clip(AUC_MAX_MM - e, 0.0, None).sum() / len(e)
    last_step = (kept.max() if len(kept) else 0.0) / len(e)
    return float(100.0 * (exact + last_step) / AUC_MAX_MM)


def bucket(occlusion: float) -> int:
    return min(BUCKETS - 1, max(0, math.floor(occlusion * BUCKETS + 1e-9)))


# --- scoring ------------------------------------------------------------------------------------


def evaluate(root: Path, estimates_csv: Path, splits: list[str]) -> dict[str, Any]:
    models, instances = load_dataset(root, splits)
    rows = load_estimates(estimates_csv)
    best: dict[tuple[int, int, int], Row] = {}
    for row in rows:  # file order: a later row with the same score does not replace an earlier one
        key = (row.scene_id, row.im_id, row.obj_id)
        if key not in best or row.score > best[key].score:
            best[key] = row
    seen: set[tuple[int, int, int]] = set()
    per_estimate = []
    for inst in instances:
        key = (inst.scene_id, inst.im_id, inst.obj_id)
        assert key not in seen, f"two instances of object {inst.obj_id} in one image: not handled here"
        seen.add(key)
        model = models[inst.obj_id]
        row = best.get(key)
        if row is None:
            e_add = e_adds = math.inf
        else:
            e_add = add(model.points, row.R, row.t, inst.R, inst.t)
            e_adds = adds(model.points, row.R, row.t, inst.R, inst.t)
        per_estimate.append(
            {
                "scene_id": inst.scene_id,
                "im_id": inst.im_id,
                "gt_index": inst.gt_index,
                "obj_id": inst.obj_id,
                "line": None if row is None else row.line,
                "add_mm": e_add,
                "adds_mm": e_adds,
                "add_s_mm": e_adds if model.symmetric else e_add,
                "diameter": model.diameter,
                "occlusion_bucket": bucket(1.0 - inst.visib_fract),
            }
        )
    groups: dict[str, list[dict[str, Any]]] = {"overall": per_estimate}
    for obj_id in models:
        groups[f"object {obj_id}"] = [p for p in per_estimate if p["obj_id"] == obj_id]
    for b in range(BUCKETS):
        groups[f"bucket {b}"] = [p for p in per_estimate if p["occlusion_bucket"] == b]
    return {"per_estimate": per_estimate, "groups": {name: summary(g) for name, g in groups.items()}}


def summary(group: list[dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {
        "n": len(group),
        "estimated": sum(p["line"] is not None for p in group),
        "add_auc": auc([p["add_mm"] for p in group]),
        "adds_auc": auc([p["adds_mm"] for p in group]),
        "add_s_auc": auc([p["add_s_mm"] for p in group]),
    }
    for label, fraction in WITHIN.items():
        hits = [p["add_s_mm"] < fraction * p["diameter"] for p in group]
        out[f"add_s_{label}"] = 100.0 * sum(hits) / len(hits) if hits else None
    return out


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("dataset", type=Path)
    parser.add_argument("estimates", type=Path)
    parser.add_argument("--split", action="append", default=[])
    args = parser.parse_args()
    report = evaluate(args.dataset, args.estimates, args.split)
    for p in report["per_estimate"]:
        for k in ("add_mm", "adds_mm", "add_s_mm"):
            p[k] = None if math.isinf(p[k]) else p[k]
    json.dump(report, sys.stdout, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
