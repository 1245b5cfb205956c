"""Fireflies on what matters: every RGB image of a native dataset, checked for isolated bright
pixels (more than 0.3 of full scale above all 8 neighbours, in the brightest channel) on the
object, the hand and the arm, as the segmentation and its id map in meta.json label them.

Usage: check_fireflies.py DIR. Prints one JSON line (images, foreground pixels, spikes on the
foreground and elsewhere); exits 1 when any foreground pixel spikes, 2 on a dataset it cannot read.
Shares no code with the renderer.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import cv2
import numpy as np

SPIKE = 0.3
FOREGROUND = ("object", "hand/", "arm/")


def spikes(rgb: np.ndarray) -> np.ndarray:
    g = rgb.astype(np.float64).max(axis=2) / 255.0
    p = np.pad(g, 1, mode="edge")
    h, w = g.shape
    shifts = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dy or dx]
    around = [p[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w] for dy, dx in shifts]
    return (g - np.max(around, axis=0)) > SPIKE


def main(root: Path) -> int:
    images = foreground_px = on_foreground = elsewhere = 0
    worst: list[str] = []
    for meta_path in sorted(root.glob("*/meta.json")):
        sample = meta_path.parent
        rgb = cv2.imread(str(sample / "rgb.png"), cv2.IMREAD_COLOR)
        segmentation = cv2.imread(str(sample / "segmentation.png"), cv2.IMREAD_UNCHANGED)
        if rgb is None or segmentation is None:
            continue
        labels = json.loads(meta_path.read_text())["camera"]["segmentation"]
        ids = [int(k) for k, name in labels.items() if name.startswith(FOREGROUND)]
        foreground = np.isin(segmentation, ids)
        found = spikes(rgb)
        images += 1
        foreground_px += int(foreground.sum())
        on_foreground += int((found & foreground).sum())
        elsewhere += int((found & ~foreground).sum())
        if (found & foreground).any():
            worst.append(sample.name)
    if images == 0:
        print(f"check_fireflies: no sample with rgb.png and segmentation.png under {root}", file=sys.stderr)
        return 2
    report = {
        "images": images,
        "foreground_px": foreground_px,
        "foreground_spikes": on_foreground,
        "other_spikes": elsewhere,
        "samples_with_spikes": worst,
    }
    print(json.dumps(report))
    return 1 if on_foreground else 0


if __name__ == "__main__":
    if len(sys.argv) != 2:
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    sys.exit(main(Path(sys.argv[1])))
