#!/usr/bin/env python3
"""Write the example user files of examples/custom.toml (examples/assets/cup.obj and lab.hdr)
and examples/textured.toml (box.obj, box.mtl, box.png).

    .venv/bin/python scripts/gen_example_assets.py           # write them
    .venv/bin/python scripts/gen_example_assets.py --check   # exit 1 if a committed file differs

cup.obj: a tapered, open-topped cup (a non-convex shape: the importer decomposes it into convex
pieces for collision), as an OBJ in millimetres, the way a CAD tool would export it: 68 mm across
at the rim, 56 mm at the foot, 80 mm tall, 3.5 mm walls on a 5 mm base. The surface is the
revolved profile of vint_engines.objects (the same code as the catalog's revolved shapes), so it
is watertight.

lab.hdr: a small user HDRI, a 128×64 equirectangular Radiance RGBE image (uncompressed
scanlines, 32 KiB) of a made-up lab: cool grey walls, a warm floor, two bright warm ceiling
panels and a bluish window, so it lights a scene visibly unlike Blender's bundled studio.

box.obj + box.mtl + box.png: an 80 × 50 × 30 mm carton the way a scanner or a texturing tool
exports it: four vertices of its own per face (split at every edge: the UV seams), per-face
texture coordinates into one 64-pixel tile each of a 384×64 PNG atlas, each face its own colour
with a darker rim, the MTL naming the PNG.

Deterministic: the same code writes the same bytes (the HDRI is encoded here, not by a library).
"""

from __future__ import annotations

import argparse
import struct
import sys
import zlib
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ASSETS = ROOT / "examples" / "assets"

# (r, z) in mm, bottom to top, closed along the axis: outside up, over the rim, inside down.
PROFILE_MM = ((0.0, 0.0), (28.0, 0.0), (34.0, 80.0), (30.5, 80.0), (25.0, 5.0), (0.0, 5.0))
SEGMENTS = 48

HDRI_SIZE = (128, 64)  # width, height: 2:1 equirectangular
# Linear RGB radiance of the lab's surfaces and lights.
WALL = (0.50, 0.56, 0.64)
CEILING = (0.70, 0.70, 0.68)
FLOOR = (0.24, 0.20, 0.16)
PANEL = (14.0, 12.5, 10.5)
WINDOW = (3.0, 3.8, 5.0)
# Lights as (azimuth range, elevation range) in degrees; azimuth 0 is the image's centre column.
PANELS = (((-100.0, -60.0), (55.0, 75.0)), ((60.0, 100.0), (55.0, 75.0)))
WINDOWS = (((150.0, 210.0), (5.0, 35.0)),)


def obj_text() -> bytes:
    sys.path.insert(0, str(ROOT / "workers" / "engines"))
    from vint_engines.objects.tessellate import revolve

    mesh = revolve(PROFILE_MM, SEGMENTS)
    lines = ["# vint example object: a tapered cup, millimetres (scripts/gen_example_assets.py)"]
    lines += [f"v {x:.4f} {y:.4f} {z:.4f}" for x, y, z in mesh.vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in mesh.faces]
    return ("\n".join(lines) + "\n").encode("utf-8")


def lab_radiance() -> np.ndarray:
    """The lab as a (height, width, 3) float array, top row first (the zenith)."""
    width, height = HDRI_SIZE
    azimuth = (np.arange(width) + 0.5) / width * 360.0 - 180.0
    elevation = 90.0 - (np.arange(height) + 0.5) / height * 180.0
    az, el = np.meshgrid(azimuth, elevation)
    shade = (0.6 + 0.4 * np.sin(np.radians(np.abs(el))))[..., None]
    image = np.where((el >= 0)[..., None], np.array(WALL) * shade, np.array(FLOOR) * shade)
    image[el > 60.0] = CEILING

    def inside(az_range: tuple[float, float], el_range: tuple[float, float]) -> np.ndarray:
        wrapped = (az - az_range[0]) % 360.0  # ranges may cross ±180°
        return (wrapped <= az_range[1] - az_range[0]) & (el >= el_range[0]) & (el <= el_range[1])

    for az_range, el_range in PANELS:
        image[inside(az_range, el_range)] = PANEL
    for az_range, el_range in WINDOWS:
        image[inside(az_range, el_range)] = WINDOW
    return image


def rgbe_bytes(image: np.ndarray) -> bytes:
    """A Radiance .hdr file of `image` (linear RGB, top row first), flat (uncompressed) RGBE
    scanlines, which every reader accepts unless a scanline starts like a run-length marker."""
    height, width, _ = image.shape
    peak = image.max(axis=2)
    mantissa, exponent = np.frexp(peak)
    scale = np.where(peak > 1e-32, mantissa * 256.0 / np.maximum(peak, 1e-32), 0.0)
    rgbe = np.zeros((height, width, 4), dtype=np.uint8)
    rgbe[..., :3] = np.floor(image * scale[..., None]).clip(0, 255).astype(np.uint8)
    rgbe[..., 3] = np.where(peak > 1e-32, exponent + 128, 0).astype(np.uint8)
    starts = rgbe[:, 0]
    if ((starts[:, 0] == 2) & (starts[:, 1] == 2) & (starts[:, 2] < 128)).any():
        raise ValueError("a scanline would read as run-length encoded")
    header = "#?RADIANCE\n# vint example HDRI (scripts/gen_example_assets.py)\nFORMAT=32-bit_rle_rgbe\n\n"
    return (header + f"-Y {height} +X {width}\n").encode("ascii") + rgbe.tobytes()


def lab_hdr() -> bytes:
    return rgbe_bytes(lab_radiance())


BOX_MM = (80.0, 50.0, 30.0)
BOX_TILE = 64
# Each face (by its outward axis) and its colour (sRGB bytes).
BOX_FACES = {
    "+x": (200, 40, 30),
    "-x": (40, 150, 60),
    "+y": (30, 70, 180),
    "-y": (230, 190, 40),
    "+z": (240, 240, 235),
    "-z": (120, 60, 140),
}


def box_corners(face: str) -> list[tuple[float, float, float]]:
    """The face's corners (mm), counter-clockwise seen from outside."""
    axis, sign = "xyz".index(face[1]), (1.0 if face[0] == "+" else -1.0)
    u, v = (axis + 1) % 3, (axis + 2) % 3
    corners = []
    for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
        p = [0.0, 0.0, 0.0]
        p[axis], p[u], p[v] = sign * BOX_MM[axis] / 2, a * BOX_MM[u] / 2, b * BOX_MM[v] / 2
        corners.append((p[0], p[1], p[2]))
    return corners if sign > 0 else corners[::-1]


def box_obj() -> bytes:
    lines = ["# vint example object: a textured carton, millimetres (scripts/gen_example_assets.py)"]
    lines += ["mtllib box.mtl", "usemtl carton"]
    for k, face in enumerate(BOX_FACES):
        lines += [f"v {x:.4f} {y:.4f} {z:.4f}" for x, y, z in box_corners(face)]
        u0, u1 = k / len(BOX_FACES), (k + 1) / len(BOX_FACES)
        lines += [f"vt {u:.6f} {v:.6f}" for u, v in ((u0, 0.0), (u1, 0.0), (u1, 1.0), (u0, 1.0))]
        a = 4 * k + 1
        lines += [f"f {a}/{a} {a + 1}/{a + 1} {a + 2}/{a + 2}", f"f {a}/{a} {a + 2}/{a + 2} {a + 3}/{a + 3}"]
    return ("\n".join(lines) + "\n").encode("utf-8")


def box_mtl() -> bytes:
    return (
        b"# vint example material (scripts/gen_example_assets.py)\nnewmtl carton\nKd 1 1 1\nmap_Kd box.png\n"
    )


def box_png() -> bytes:
    """The atlas as an 8-bit RGB PNG, encoded here (fixed zlib level, no metadata)."""
    atlas = np.zeros((BOX_TILE, BOX_TILE * len(BOX_FACES), 3), np.uint8)
    for k, colour in enumerate(BOX_FACES.values()):
        tile = atlas[:, k * BOX_TILE : (k + 1) * BOX_TILE]
        tile[:] = (np.array(colour) * 0.6).astype(np.uint8)
        tile[6:-6, 6:-6] = colour
    rows = b"".join(b"\0" + row.tobytes() for row in atlas)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", atlas.shape[1], atlas.shape[0], 8, 2, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", header)
        + chunk(b"IDAT", zlib.compress(rows, 9))
        + chunk(b"IEND", b"")
    )


FILES: dict[str, Callable[[], bytes]] = {
    "cup.obj": obj_text,
    "lab.hdr": lab_hdr,
    "box.obj": box_obj,
    "box.mtl": box_mtl,
    "box.png": box_png,
}


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--check", action="store_true", help="compare with the files instead of writing")
    args = parser.parse_args()
    stale = 0
    for name, make in FILES.items():
        out = ASSETS / name
        content = make()
        if args.check:
            if not out.is_file() or out.read_bytes() != content:
                print(f"stale: {out} (run scripts/gen_example_assets.py)", file=sys.stderr)
                stale += 1
            continue
        out.write_bytes(content)
        print(f"wrote {out.relative_to(ROOT)} ({len(content)} bytes)")
    return 1 if stale else 0


if __name__ == "__main__":
    sys.exit(main())
