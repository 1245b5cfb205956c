"""A small synthetic BOP dataset for checking `vintctl eval` where vint's own data cannot reach:
symmetric objects, two objects in one image, models in both PLY encodings, every occlusion bucket.

    synthetic_bop.py OUT_DIR [--seed N]

Objects (millimetres, centred on the origin):
  1 `block`    a 40 × 70 × 100 box sampled on its faces, ascii PLY, no symmetry listed
               (a printed box: ADD(S) is ADD);
  2 `cylinder` radius 30, height 80, rims and caps, binary PLY, symmetries_continuous about z;
  3 `prism`    a 60 × 60 × 20 box sampled on its faces, binary PLY, only symmetries_discrete.
Splits: test (scenes 0-2) and train (scene 3), 5 images a scene, one or two objects an image, random
poses half a metre in front of the camera, visib_fract spread over 0..1.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]


def box_surface(size: tuple[float, float, float], per_edge: int) -> Array:
    """Points on the six faces of an axis-aligned box centred on the origin."""
    half = np.array(size) / 2.0
    grid = np.linspace(-1.0, 1.0, per_edge)
    u, v = (a.reshape(-1) for a in np.meshgrid(grid, grid))
    faces = []
    for axis in range(3):
        others = [k for k in range(3) if k != axis]
        for sign in (-1.0, 1.0):
            p = np.zeros((len(u), 3))
            p[:, axis] = sign
            p[:, others[0]], p[:, others[1]] = u, v
            faces.append(p * half)
    return np.unique(np.concatenate(faces).round(9), axis=0)


def cylinder_surface(radius: float, height: float, around: int, rings: int) -> Array:
    a = np.linspace(0.0, 2.0 * math.pi, around, endpoint=False)
    rim = [np.stack([radius * np.cos(a), radius * np.sin(a), np.full(around, z)], axis=1) for z in
           np.linspace(-height / 2, height / 2, rings)]  # fmt: skip
    caps = [[0.0, 0.0, -height / 2], [0.0, 0.0, height / 2]]
    return np.concatenate([*rim, np.array(caps)])


def ply(points: Array, encoding: str) -> bytes:
    """A PLY of the points with one degenerate triangle after them (readers must step over faces)."""
    header = (
        f"ply\nformat {encoding} 1.0\ncomment synthetic, units: mm\nelement vertex {len(points)}\n"
        "property float x\nproperty float y\nproperty float z\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
    )
    if encoding == "ascii":
        body = "".join(f"{x!r} {y!r} {z!r}\n" for x, y, z in points.astype(np.float32).tolist()) + "3 0 1 2\n"
        return (header + body).encode("ascii")
    face = np.array([3], "u1").tobytes() + np.array([0, 1, 2], "<i4").tobytes()
    return header.encode("ascii") + points.astype("<f4").tobytes() + face


def random_rotation(rng: np.random.Generator) -> Array:
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def write(out: Path, seed: int) -> None:
    rng = np.random.default_rng(seed)
    models = out / "models"
    models.mkdir(parents=True, exist_ok=True)
    flip_x = [1.0, 0, 0, 0, 0, -1.0, 0, 0, 0, 0, -1.0, 0, 0, 0, 0, 1.0]
    flip_z = [-1.0, 0, 0, 0, 0, -1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0]
    objects = {
        1: ("block", box_surface((40.0, 70.0, 100.0), 8), "ascii", {}),
        2: (
            "cylinder",
            cylinder_surface(30.0, 80.0, 72, 9),
            "binary_little_endian",
            {"symmetries_continuous": [{"axis": [0, 0, 1], "offset": [0, 0, 0]}]},
        ),
        3: (
            "prism",
            box_surface((60.0, 60.0, 20.0), 7),
            "binary_little_endian",
            {"symmetries_discrete": [flip_x, flip_z]},
        ),
    }
    info = {}
    for obj_id, (_, points, encoding, symmetries) in objects.items():
        (models / f"obj_{obj_id:06d}.ply").write_bytes(ply(points, encoding))
        p32 = points.astype(np.float32).astype(np.float64)
        diameter = max(float(np.linalg.norm(p32 - p, axis=1).max()) for p in p32)
        lo, hi = p32.min(axis=0), p32.max(axis=0)
        info[str(obj_id)] = {"diameter": diameter, "min_x": lo[0], "min_y": lo[1], "min_z": lo[2],
                             "size_x": hi[0] - lo[0], "size_y": hi[1] - lo[1], "size_z": hi[2] - lo[2],
                             **symmetries}  # fmt: skip
    (models / "models_info.json").write_text(json.dumps(info, indent=1))
    names = [{"obj_id": obj_id, "name": name} for obj_id, (name, *_) in objects.items()]
    (out / "dataset.json").write_text(json.dumps({"format": "vint-bop", "objects": names}, indent=1))
    for scene_id in range(4):
        scene = out / ("test" if scene_id < 3 else "train") / f"{scene_id:06d}"
        scene.mkdir(parents=True, exist_ok=True)
        gt: dict[str, list[dict[str, object]]] = {}
        gt_info: dict[str, list[dict[str, object]]] = {}
        for im_id in range(5):
            shown = rng.choice([1, 2, 3], size=int(rng.integers(1, 3)), replace=False)
            gt[str(im_id)] = [
                {
                    "cam_R_m2c": random_rotation(rng).reshape(-1).tolist(),
                    "cam_t_m2c": [
                        float(rng.uniform(-80, 80)),
                        float(rng.uniform(-80, 80)),
                        float(rng.uniform(400, 600)),
                    ],
                    "obj_id": int(obj_id),
                }
                for obj_id in shown
            ]
            gt_info[str(im_id)] = [{"visib_fract": float(rng.uniform(0.0, 1.0))} for _ in shown]
        (scene / "scene_gt.json").write_text(json.dumps(gt, indent=1))
        (scene / "scene_gt_info.json").write_text(json.dumps(gt_info, indent=1))


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("out", type=Path)
    parser.add_argument("--seed", type=int, default=3)
    args = parser.parse_args()
    write(args.out, args.seed)


if __name__ == "__main__":
    main()
