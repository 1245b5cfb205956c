"""What storing depth as 16-bit PNG (0.1 mm steps, the native default) costs and saves against
float32 `.npy`, on real depth: the files of a native dataset written with `[outputs] depth_format =
"npy"`, whose float depth is the truth.

    .venv/bin/python benches/depth_png.py DATASET [--levels 1 3 6 9] [--repeats 5] [--json]
    .venv/bin/python benches/depth_png.py --smoke

Per zlib level, for the clean (`depth.npy`) and the noisy (`depth_noisy.npy`) images apart: median
PNG bytes, their share of the `.npy`'s, median encode time, and the largest decode error over the
pixels a PNG holds (it must stay within half a step, 0.05 mm), with the holes compared. The engines
write level `depth_file.PNG_COMPRESSION`. Levels run interleaved per image, so a slow moment of the
machine hits them all alike. `--smoke`: a synthetic 64×48 pair, one repeat (the test command's
check that the bench still runs).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workers" / "engines"))

from vint_engines import depth_file

KINDS = ("depth", "depth_noisy")


def synthetic_pair(width: int = 64, height: int = 48) -> dict[str, list[np.ndarray]]:
    """A wall at 0.9 m with a sphere in front and no return in one corner, and its noisy copy."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float32)
    depth = np.full((height, width), 0.9, np.float32) + 0.001 * u
    inside = (u - width / 2) ** 2 + (v - height / 2) ** 2 < (height / 3) ** 2
    bulge = np.sqrt(np.clip((height / 3) ** 2 - (u - width / 2) ** 2 - (v - height / 2) ** 2, 0, None))
    depth[inside] = 0.6 - 0.0005 * bulge[inside]
    depth[: height // 4, : width // 4] = 0.0
    rng = np.random.default_rng(7)
    noisy = np.where(depth > 0, depth + rng.normal(0.0, 0.001, depth.shape), 0.0).astype(np.float32)
    return {"depth": [depth], "depth_noisy": [noisy]}


def dataset_images(root: Path) -> dict[str, list[np.ndarray]]:
    """Every sample's float depth files under a native dataset written with `depth_format = "npy"`."""
    images: dict[str, list[np.ndarray]] = {kind: [] for kind in KINDS}
    for kind in KINDS:
        for path in sorted(root.glob(f"*/{kind}.npy")):
            images[kind].append(depth_file.read(path))
    if not images["depth"]:
        raise SystemExit(f'{root}: no */depth.npy: run a spec with [outputs] depth_format = "npy" into it')
    return images


def encode(depth: np.ndarray, level: int) -> tuple[bytes, float]:
    started = time.perf_counter()
    ok, png = cv2.imencode(".png", depth_file.to_png_units(depth), [cv2.IMWRITE_PNG_COMPRESSION, level])
    elapsed = time.perf_counter() - started
    if not ok:
        raise RuntimeError("cv2.imencode failed")
    return png.tobytes(), elapsed


def decode_error_m(depth: np.ndarray, png: bytes) -> float:
    """The largest |decoded - float| over the pixels a PNG holds (0 < d ≤ 6.5535 m); inf when the
    holes differ (a pixel with a return lost, or one gained). Decoded with OpenCV and numpy alone."""
    units = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED).astype(np.float64)
    exact = depth.astype(np.float64)
    held = (exact > 0) & (exact <= depth_file.max_m())
    if not np.array_equal(units > 0, held):
        return float("inf")
    return float(np.abs(units * depth_file.unit_m() - exact)[held].max(initial=0.0))


def measure(images: dict[str, list[np.ndarray]], levels: list[int], repeats: int) -> list[dict[str, object]]:
    rows = []
    for kind in KINDS:
        if not images[kind]:
            continue
        npy_bytes = statistics.median(d.size * 4 + 128 for d in images[kind])
        sizes: dict[int, list[int]] = {level: [] for level in levels}
        times: dict[int, list[float]] = {level: [] for level in levels}
        errors: dict[int, float] = dict.fromkeys(levels, 0.0)
        for depth in images[kind]:
            for _ in range(repeats):
                for level in levels:
                    png, seconds = encode(depth, level)
                    times[level].append(seconds)
            for level in levels:
                png, _ = encode(depth, level)
                sizes[level].append(len(png))
                errors[level] = max(errors[level], decode_error_m(depth, png))
        for level in levels:
            png_bytes = statistics.median(sizes[level])
            rows.append(
                {
                    "file": kind,
                    "level": level,
                    "images": len(images[kind]),
                    "pixels": int(images[kind][0].size),
                    "npy_bytes": npy_bytes,
                    "png_bytes": png_bytes,
                    "png_share": png_bytes / npy_bytes,
                    "bytes_per_pixel": png_bytes / images[kind][0].size,
                    "encode_ms": 1e3 * statistics.median(times[level]),
                    "max_error_mm": 1e3 * errors[level],
                }
            )
    return rows


def table(rows: list[dict[str, object]]) -> str:
    lines = [
        "| file | zlib level | images | .npy bytes | PNG bytes (median) | share | B/px | encode ms "
        "| max error (mm) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['file']} | {r['level']} | {r['images']} | {r['npy_bytes']:,.0f} | {r['png_bytes']:,.0f} "
            f"| {r['png_share']:.1%} | {r['bytes_per_pixel']:.3f} | {r['encode_ms']:.2f} "
            f"| {r['max_error_mm']:.4f} |"
        )
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", nargs="?", type=Path)
    parser.add_argument("--levels", type=int, nargs="+", default=[1, 3, 6, 9])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--smoke", action="store_true")
    args = parser.parse_args()
    if args.smoke:
        images, repeats = synthetic_pair(), 1
    elif args.dataset is None:
        parser.error("DATASET is required (or --smoke)")
    else:
        images, repeats = dataset_images(args.dataset), args.repeats
    rows = measure(images, args.levels, repeats)
    worst = max(float(r["max_error_mm"]) for r in rows)  # type: ignore[arg-type]
    print(json.dumps(rows, indent=1) if args.json else table(rows))
    level = depth_file.PNG_COMPRESSION
    print(f"largest decode error: {worst:.4f} mm (bound 0.05 mm); engines write level {level}")
    return 0 if worst <= 0.05 + 1e-6 else 1


if __name__ == "__main__":
    sys.exit(main())
