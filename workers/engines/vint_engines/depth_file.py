"""How a depth image is stored and read back: the one rule for the engines that write depth (render,
noise) and every reader of it (noise, study, preview). `vint_core::contract::depth` defines it and
the committed schema carries its unit (`depth_png`), so Rust and Python agree:

- `.png` (the default): 16-bit grayscale, one step per `unit_m` (0.1 mm), 0 = no reading. A depth
  is rounded to the nearest step, so it reads back within half a step (0.05 mm); one beyond
  `max_m` (6.5535 m) stores as 0 (no reading).
- `.npy`: float32 metres, 0 = no reading.

Readers take whichever a directory has (`find`) and always get float32 metres (`read`).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from vint_engines import contract
from vint_engines.errors import BadInput

FORMATS = ("png", "npy")
# zlib level 3: at 640×480 a clean depth encodes in ~16 ms to ~47 KB and a noisy one in ~27 ms to
# ~221 KB; level 6 saves 5 % of the two together for twice the time, level 9 another 2 % for five
# times (benches/depth_png.py; docs/benchmarks.md, "Depth as PNG").
PNG_COMPRESSION = 3


def unit_m() -> float:
    """Metres per step of a depth PNG (`contract.schema.json` `depth_png.unit_m`)."""
    return float(contract.schema()["depth_png"]["unit_m"])


def max_m() -> float:
    """The farthest depth a PNG holds (`depth_png.max_m`, 6.5535 m); farther stores as 0."""
    return float(contract.schema()["depth_png"]["max_m"])


def to_png_units(depth_m: npt.ArrayLike) -> npt.NDArray[np.uint16]:
    """Depth in metres as PNG steps: the nearest step, 0 where there is no reading (0, negative,
    NaN, infinite) or where the depth lies beyond what uint16 holds."""
    units = np.rint(np.asarray(depth_m, dtype=np.float64) / unit_m())
    holds = np.isfinite(units) & (units > 0) & (units <= np.iinfo(np.uint16).max)
    return np.where(holds, units, 0).astype(np.uint16)


def from_png_units(units: npt.NDArray[np.integer]) -> npt.NDArray[np.float32]:
    """PNG steps as float32 metres (0 stays 0)."""
    return (units.astype(np.float64) * unit_m()).astype(np.float32)


def write(stem: Path, depth_m: npt.NDArray[np.floating], fmt: str) -> Path:
    """Writes `depth_m` (metres, 0 = no reading) to `<stem>.<fmt>`; returns the path."""
    if fmt not in FORMATS:
        raise BadInput(f"depth format {fmt!r} is not one of {', '.join(FORMATS)}")
    path = stem.with_name(f"{stem.name}.{fmt}")
    if fmt == "npy":
        np.save(path, np.asarray(depth_m, dtype=np.float32))
    elif not cv2.imwrite(str(path), to_png_units(depth_m), [cv2.IMWRITE_PNG_COMPRESSION, PNG_COMPRESSION]):
        raise OSError(f"cannot write {path}")
    return path


def media_type(path: Path) -> str:
    return "image/png" if path.suffix == ".png" else "application/x-npy"


def read(path: Path) -> npt.NDArray[np.float32]:
    """The depth file at `path` as float32 metres (0 = no reading). I/O errors propagate (a retry
    may help); a malformed file is BadInput."""
    if path.suffix == ".png":
        if not path.is_file():
            raise FileNotFoundError(path)
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None or image.ndim != 2 or image.dtype != np.uint16:
            raise BadInput(f"depth map {path} is not a single-channel 16-bit PNG")
        return from_png_units(image)
    if path.suffix != ".npy":
        raise BadInput(f"depth map {path} is neither .png nor .npy")
    try:
        depth = np.load(path, allow_pickle=False)
    except ValueError as exc:
        raise BadInput(f"cannot read depth map {path}: {exc}") from exc
    if not np.issubdtype(depth.dtype, np.floating) or depth.ndim != 2:
        raise BadInput(f"depth map {path} is {depth.dtype} {depth.shape}, expected a float image")
    return depth.astype(np.float32, copy=False)


def find(directory: Path, stem: str) -> Path | None:
    """`<directory>/<stem>.png` or `.npy`, whichever exists (None when neither does)."""
    return next((p for fmt in FORMATS if (p := directory / f"{stem}.{fmt}").is_file()), None)
