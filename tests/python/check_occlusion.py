"""Occlusion within the spec's range: every view of a native dataset, its occlusion recomputed from
its mask files alone — 1 - visible / full, with `mask.png` the object's visible pixels and
`mask_full.png` its pixels were the hand not there (their union, so a visible pixel always counts) —
checked against [MIN, MAX] (the spec's `render.occlusion`; VinT-6D's 10-90 % by default).

Usage: check_occlusion.py DIR MIN MAX. Prints one JSON line (views, how many lie below, within and
above the range, and the samples outside it); exits 1 when any view lies outside, 2 on a dataset it
cannot read. Shares no code with the renderer.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import cv2
import numpy as np


def occlusion(sample: Path) -> float | None:
    """1 - visible / full from the sample's masks (1 when the object is not in view); None without
    both masks."""
    visible = cv2.imread(str(sample / "mask.png"), cv2.IMREAD_UNCHANGED)
    full = cv2.imread(str(sample / "mask_full.png"), cv2.IMREAD_UNCHANGED)
    if visible is None or full is None:
        return None
    shown = visible > 0
    full_px = int(np.count_nonzero(shown | (full > 0)))
    return 1.0 if full_px == 0 else 1.0 - int(np.count_nonzero(shown)) / full_px


def main(root: Path, low: float, high: float) -> int:
    below: list[str] = []
    above: list[str] = []
    views = 0
    for meta_path in sorted(root.glob("*/meta.json")):
        found = occlusion(meta_path.parent)
        if found is None:
            continue
        views += 1
        if found < low:
            below.append(f"{meta_path.parent.name} ({found:.4f})")
        elif found > high:
            above.append(f"{meta_path.parent.name} ({found:.4f})")
    if views == 0:
        print(f"check_occlusion: no sample with mask.png and mask_full.png under {root}", file=sys.stderr)
        return 2
    report = {
        "views": views,
        "range": [low, high],
        "below": len(below),
        "within": views - len(below) - len(above),
        "above": len(above),
        "outside": below + above,
    }
    print(json.dumps(report))
    return 1 if below or above else 0


if __name__ == "__main__":
    if len(sys.argv) != 4:
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    sys.exit(main(Path(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3])))
