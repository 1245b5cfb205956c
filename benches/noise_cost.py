"""What the depth-noise model costs per view and what each piece changes, side by side with the
previous model (white Gaussian σ = 0.5 mm + 1 mm/m beyond 0.5 m, 3×3 edge holes, 1 % dropout),
and the σ curves docs/depth_noise.md shows.

    .venv/bin/python benches/noise_cost.py [--repeats 15] [--out docs/depth_noise]
    .venv/bin/python benches/noise_cost.py --smoke

Writes `cost.md` (the tables) and `sigma.png` into --out. `--smoke`: one repeat at the smallest
resolution, written into a temporary directory (seconds: the test command's check that the bench
still runs). The scene is synthetic but has what
the pieces act on: a wall, a metal sphere, a glass cylinder, rubber fingers touching the sphere
(concave corners) and no-return background. Variants run interleaved (round-robin per repeat),
so a slow moment of the machine hits them all alike; times are medians.
"""

from __future__ import annotations

import argparse
import math
import platform
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workers" / "engines"))

from vint_engines.noise import sensor
from vint_engines.noise.geometry import Intrinsics
from vint_engines.noise.model import NoiseModel, Surfaces

RESOLUTIONS = [(128, 128), (512, 512), (1024, 1024)]
PIECES = ("lateral", "flying_pixels", "multipath", "materials", "registration")


def previous_model(depth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The model this one replaced (vint commit 0425b54, noise/model.py), for the comparison."""
    gaussian = rng.standard_normal(depth.shape, dtype=np.float32)
    dropped = rng.random(depth.shape, dtype=np.float32) < 0.01
    valid = np.isfinite(depth) & (depth > 0)
    clean = np.where(valid, depth, np.float32(0))
    far = np.where(valid, clean, np.float32(1e6))
    kernel = np.ones((3, 3), np.uint8)
    valid &= ~((cv2.dilate(far, kernel) - cv2.erode(far, kernel)) > 0.05)
    sigma = 0.0005 + 0.001 * np.maximum(clean - np.float32(0.5), 0)
    noisy = clean + sigma.astype(np.float32) * gaussian
    valid &= (noisy >= 0.25) & (noisy <= 3.86) & ~dropped
    return np.where(valid, noisy, np.float32(0)).astype(np.float32)


def scene(width: int, height: int) -> tuple[np.ndarray, np.ndarray, Intrinsics]:
    """Depth (m) and segment ids of the synthetic view, 60° horizontal FOV."""
    f = (width / 2) / math.tan(math.radians(30))
    k = Intrinsics(f, f, (width - 1) / 2, (height - 1) / 2)
    x = (np.arange(width) - k.cx) / f
    y = (np.arange(height) - k.cy) / f
    rx, ry = np.meshgrid(x, y)
    depth = np.full((height, width), 0.9, np.float32)
    seg = np.full((height, width), 4, np.uint8)  # the wall
    depth[:, int(0.85 * width) :] = 0  # no return
    seg[:, int(0.85 * width) :] = 0
    # A metal sphere r = 6 cm at 0.6 m.
    a = rx**2 + ry**2 + 1
    disc = 1.2**2 - 4 * a * (0.36 - 0.0036)
    t = (1.2 - np.sqrt(np.maximum(disc, 0))) / (2 * a)
    sphere = disc > 0
    depth[sphere], seg[sphere] = t[sphere], 1
    # A glass cylinder (axis vertical) r = 3 cm at 0.55 m, to the left.
    cx = -0.12
    b = -2 * (cx * rx + 0.55)
    c2 = rx**2 + 1
    disc_c = b * b - 4 * c2 * (cx**2 + 0.55**2 - 0.03**2)
    tc = (-b - np.sqrt(np.maximum(disc_c, 0))) / (2 * c2)
    glass = (disc_c > 0) & (np.abs(ry * tc) < 0.08) & ((tc < depth) | (depth == 0))
    depth[glass], seg[glass] = tc[glass], 2
    # Rubber fingers: slabs pressed against the sphere's left and lower sides.
    for x0, y0, w, h in [(-0.075, -0.02, 0.03, 0.1), (-0.03, 0.04, 0.08, 0.025)]:
        slab = (rx * 0.6 > x0) & (rx * 0.6 < x0 + w) & (ry * 0.6 > y0) & (ry * 0.6 < y0 + h)
        z = np.float32(0.585)
        nearer = slab & ((depth == 0) | (depth > z))
        depth[nearer], seg[nearer] = z, 3
    return depth, seg, k


MATERIALS = {1: "metal", 2: "glass", 3: "rubber", 4: "plastic"}


def variants() -> dict[str, NoiseModel | None]:
    full = NoiseModel.parse({"mode": "wfov_2x2binned"})
    out: dict[str, NoiseModel | None] = {"previous model": None, "new, all pieces": full}
    for piece in PIECES:
        out[f"new, without {piece}"] = full.without(piece)
    out["new, white axial noise (spatial_sigma_px 0)"] = replace(full, spatial_sigma_px=0.0)
    out["new, axial only (white)"] = replace(full.without(*PIECES), spatial_sigma_px=0.0)
    return out


def run(model: NoiseModel | None, depth: np.ndarray, seg: np.ndarray, k: Intrinsics, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    if model is None:
        return previous_model(depth, rng)
    surfaces = Surfaces.from_segmentation(seg, MATERIALS) if model.materials else None
    return model.apply(depth, k, surfaces, rng)


def rms_mm(noisy: np.ndarray, depth: np.ndarray, where: np.ndarray) -> float:
    return 1e3 * float(np.sqrt(np.mean((noisy[where] - depth[where]) ** 2))) if where.any() else float("nan")


def measure(
    repeats: int, resolutions: list[tuple[int, int]]
) -> list[tuple[str, str, float, float, float, float]]:
    rows = []
    for width, height in resolutions:
        depth, seg, k = scene(width, height)
        models = variants()
        times: dict[str, list[float]] = {name: [] for name in models}
        last: dict[str, np.ndarray] = {}
        for r in range(repeats):
            for name, model in models.items():
                start = time.perf_counter()
                last[name] = run(model, depth, seg, k, 1000 + r)
                times[name].append(time.perf_counter() - start)
        clean = depth > 0
        for name in models:
            noisy = last[name]
            both = clean & (noisy > 0)
            opaque = both & (seg != 2)  # glass reads what lies behind it: a large, intended error
            invalid = 100 * float(np.mean(noisy[clean] == 0))
            median_ms = 1e3 * float(np.median(times[name]))
            rms, rms_opaque = rms_mm(noisy, depth, both), rms_mm(noisy, depth, opaque)
            rows.append((f"{width}×{height}", name, median_ms, rms, rms_opaque, invalid))
    return rows


def sigma_plot(path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    for name in ("nfov_unbinned", "nfov_2x2binned", "wfov_2x2binned", "wfov_unbinned"):
        model = NoiseModel.parse({"mode": name})
        d = np.linspace(model.mode.min_range_m, model.mode.max_range_m, 100).astype(np.float32)
        one = np.ones_like(d)
        line = left.plot(d, 1e3 * model.sigma(d, one, 0.5 * one), label=f"{name}, rho 0.5")
        left.plot(
            d,
            1e3 * model.sigma(d, one, 0.15 * one),
            "--",
            color=line[0].get_color(),
            label=f"{name}, rho 0.15",
        )
    left.axhline(1e3 * sensor.SPEC_SIGMA_MAX_M, color="k", lw=0.8)
    left.text(0.3, 1e3 * sensor.SPEC_SIGMA_MAX_M + 0.3, "Microsoft spec: sigma <= 17 mm", fontsize=8)
    left.set(xlabel="distance (m), normal incidence", ylabel="axial sigma (mm)", title="sigma vs distance")
    left.legend(fontsize=6)
    model = NoiseModel.parse({"mode": "nfov_unbinned"})
    theta = np.linspace(0, 85, 100)
    cos = np.cos(np.radians(theta)).astype(np.float32)
    for d in (0.5, 1.0, 2.0):
        dd = np.full_like(cos, d)
        right.plot(theta, 1e3 * model.sigma(dd, cos, 0.5 * np.ones_like(cos)), label=f"{d} m, rho 0.5")
    right.set(
        xlabel="incidence angle (deg)", ylabel="axial sigma (mm)", title="sigma vs incidence (nfov_unbinned)"
    )
    right.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110, metadata={"Software": None})
    plt.close(fig)


def report(repeats: int, resolutions: list[tuple[int, int]], out: Path) -> None:
    """Writes sigma.png and cost.md into `out` and prints the tables."""
    out.mkdir(parents=True, exist_ok=True)
    sigma_plot(out / "sigma.png")
    rows = measure(repeats, resolutions)
    lines = [
        f"Machine: {platform.machine()}, Python {platform.python_version()}, numpy {np.__version__}, "
        f"OpenCV {cv2.__version__}; {repeats} repeats, medians.",
        "",
        "| resolution | variant | ms per view | RMS error (mm) | RMS without glass (mm) | invalid (%) |",
        "|---|---|---|---|---|---|",
    ]
    lines += [f"| {r} | {n} | {t:.1f} | {e:.2f} | {o:.2f} | {i:.1f} |" for r, n, t, e, o, i in rows]
    (out / "cost.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--out", type=Path, default=None, help="default docs/depth_noise")
    parser.add_argument("--smoke", action="store_true", help="1 repeat, 128×128 only, into a temp dir")
    args = parser.parse_args()
    if args.smoke:
        with tempfile.TemporaryDirectory(prefix="vint-noise-cost-") as scratch:
            report(1, RESOLUTIONS[:1], args.out or Path(scratch))
    else:
        report(args.repeats, RESOLUTIONS, args.out or Path("docs/depth_noise"))


if __name__ == "__main__":
    main()
