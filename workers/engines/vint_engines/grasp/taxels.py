"""Taxel layouts: the one definition of the layout file format, its reader and its writer.

A layout is a CSV file with the header `taxel,link,x,y,z,nx,ny,nz,region` and one row per taxel:
`taxel` numbers the rows 0, 1, 2, … (it is the index of the taxel's reading), `link` names a hand
link, (x, y, z) is the taxel's position and (nx, ny, nz) its outward unit normal in that link's
frame (metres), and `region` is `tip`, `pulp` or `palm`. The built-in layouts live in
`catalog/hands/<hand>/taxels.csv` (written by `scripts/gen_taxels.py`); a user's layout (e.g. the
scanned taxels of a real sensor) is read the same way and checked against the hand it is used on.

The committed file is authoritative: engines read it and datasets cite its SHA-256. Whether it is
what the generator (`skin.py`) would write is a question of `layout_differences`, which allows one
unit in the last written digit: a different CPU may round a value lying on a half-micrometre the
other way (numpy and MuJoCo take different SIMD paths there), so the text need not match byte for
byte, but the taxels, their order, links and regions must.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from vint_engines.protocol import BadInput

HEADER = ("taxel", "link", "x", "y", "z", "nx", "ny", "nz", "region")
REGIONS = ("tip", "pulp", "palm")
NORMAL_TOLERANCE = 1e-3  # |n| may differ from 1 by this much (six written decimals are far closer)
DECIMALS = 6  # micrometres
LAST_DIGIT = 10.0**-DECIMALS  # one unit in the last written digit: 1 µm, or 1e-6 of a unit normal


@dataclass(frozen=True, eq=False)
class TaxelLayout:
    """Taxel i sits on `links[i]` at `positions[i]` facing `normals[i]` (link frame)."""

    links: tuple[str, ...]
    positions: npt.NDArray[np.float64]  # (n, 3)
    normals: npt.NDArray[np.float64]  # (n, 3), unit
    regions: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.links)

    def indices_by_link(self) -> dict[str, npt.NDArray[np.intp]]:
        """Taxel indices grouped by link, in order of first appearance."""
        groups: dict[str, list[int]] = {}
        for i, link in enumerate(self.links):
            groups.setdefault(link, []).append(i)
        return {link: np.array(indices, dtype=np.intp) for link, indices in groups.items()}

    def to_csv(self) -> str:
        out = io.StringIO()
        writer = csv.writer(out, lineterminator="\n")
        writer.writerow(HEADER)
        for i, (link, p, n, region) in enumerate(
            zip(self.links, self.positions, self.normals, self.regions, strict=True)
        ):
            writer.writerow([i, link, *(f"{v:.{DECIMALS}f}" for v in (*p, *n)), region])
        return out.getvalue()


def layout_differences(committed: TaxelLayout, generated: TaxelLayout, limit: int = 5) -> list[str]:
    """How `generated` differs from `committed` beyond one unit in the last written digit of a
    position or normal (empty: the same layout); at most `limit` taxels are named."""
    if len(committed) != len(generated):
        return [f"{len(committed)} taxels committed, {len(generated)} generated"]
    differences = []
    position_off = _last_digits_apart(committed.positions, generated.positions)
    normal_off = _last_digits_apart(committed.normals, generated.normals)
    for i in range(len(committed)):
        was = (committed.links[i], committed.regions[i])
        now = (generated.links[i], generated.regions[i])
        if was != now:
            differences.append(f"taxel {i}: {'/'.join(was)} committed, {'/'.join(now)} generated")
        elif position_off[i] > 1 or normal_off[i] > 1:
            differences.append(
                f"taxel {i} on {was[0]}: position {_digits(committed.positions[i])} committed, "
                f"{_digits(generated.positions[i])} generated; normal {_digits(committed.normals[i])}, "
                f"{_digits(generated.normals[i])}"
            )
    if len(differences) > limit:
        differences[limit:] = [f"… and {len(differences) - limit} more taxels"]
    return differences


def _last_digits_apart(a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]) -> npt.NDArray[np.int64]:
    """Per row, the largest difference of the written values in units of the last digit."""
    apart = np.abs(np.rint(a / LAST_DIGIT) - np.rint(b / LAST_DIGIT))
    return apart.max(axis=1).astype(np.int64)


def _digits(values: npt.NDArray[np.float64]) -> str:
    return "(" + ", ".join(f"{v:.{DECIMALS}f}" for v in values) + ")"


def read_layout(path: Path, links: Collection[str]) -> TaxelLayout:
    """Read a layout file for a hand whose link names are `links`; BadInput names the bad line."""
    return parse_layout(path.read_text(encoding="utf-8"), links, str(path))


def parse_layout(text: str, links: Collection[str], source: str) -> TaxelLayout:
    rows = list(csv.reader(io.StringIO(text)))
    if not rows or tuple(cell.strip() for cell in rows[0]) != HEADER:
        raise BadInput(f"{source}: line 1: expected the header {','.join(HEADER)}")
    names: list[str] = []
    values: list[list[float]] = []
    regions: list[str] = []
    for number, row in enumerate(rows[1:], start=2):
        if not row:
            continue
        where = f"{source}: line {number}"
        taxel, link, *numbers, region = _cells(row, where)
        if taxel != str(len(names)):
            raise BadInput(f"{where}: taxel {taxel!r} out of sequence (expected {len(names)})")
        if link not in links:
            raise BadInput(f"{where}: unknown link {link!r} (the hand has {sorted(links)})")
        if region not in REGIONS:
            raise BadInput(f"{where}: region {region!r} is not one of {list(REGIONS)}")
        coords = [_finite(cell, where) for cell in numbers]
        if abs(math.hypot(*coords[3:]) - 1.0) > NORMAL_TOLERANCE:
            raise BadInput(f"{where}: the normal {coords[3:]} is not a unit vector")
        names.append(link)
        values.append(coords)
        regions.append(region)
    if not names:
        raise BadInput(f"{source}: the layout has no taxels")
    array = np.array(values, dtype=np.float64)
    normals = array[:, 3:] / np.linalg.norm(array[:, 3:], axis=1, keepdims=True)
    return TaxelLayout(tuple(names), array[:, :3], normals, tuple(regions))


def _cells(row: list[str], where: str) -> list[str]:
    if len(row) != len(HEADER):
        raise BadInput(f"{where}: expected {len(HEADER)} fields, got {len(row)}")
    return [cell.strip() for cell in row]


def _finite(cell: str, where: str) -> float:
    try:
        value = float(cell)
    except ValueError:
        raise BadInput(f"{where}: {cell!r} is not a number") from None
    if not math.isfinite(value):
        raise BadInput(f"{where}: {cell!r} is not finite")
    return value
