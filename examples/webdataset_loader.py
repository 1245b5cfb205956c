"""Load a vint dataset exported as WebDataset shards into PyTorch.

    vintctl convert DATASET --out SHARDS --format webdataset
    python examples/webdataset_loader.py SHARDS [--split train] [--batch-size 8] [--workers 2] [--json]

Each sample of a shard is one view of one grasp: the `webdataset` package groups a shard's members
by key (`mug/allegro/g000001/v00`: the sample id with its dots as slashes) and decodes them by
extension; `to_tensors` turns one into the tensors a pose or touch model trains on, and a PyTorch
`DataLoader` batches them. Members (docs/formats.md, "WebDataset"): rgb.png, depth.png and
depth_noisy.png (16-bit, 0.1 mm per step; depth.npy and depth_noisy.npy, float32 metres, in a
dataset made with `depth_format = "npy"`), mask.png, mask_full.png, segmentation.png (those the
dataset was made with), meta.json (camera and poses), grasp.json (the grasp: hand, joints, touch)
and sample.json (the id). Depth comes out in metres either way, 0 where there is no reading.

The script prints one line per batch and a summary; with --json, one JSON object per sample and a
summary line, for tests.
"""

from __future__ import annotations

import argparse
import io
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch
import webdataset as wds
from PIL import Image
from torch.utils.data import DataLoader

SPLITS = ("train", "val", "test")
# Metres per step of a depth PNG (docs/formats.md, "Depth"): 0.1 mm, BOP's depth_scale 0.1.
DEPTH_PNG_UNIT_M = 1e-4


def shard_paths(root: Path, splits: list[str]) -> list[str]:
    """The shards of `splits`, from the export's index (shards.json)."""
    index = json.loads((root / "shards.json").read_text())
    return [str(root / shard["path"]) for split in splits for shard in index["splits"][split]["shards"]]


def decode_png(data: bytes) -> np.ndarray:
    """A PNG as stored: H×W×3 uint8 for rgb, H×W uint8 for masks, uint8 or uint16 for segmentation,
    uint16 for depth."""
    with Image.open(io.BytesIO(data)) as image:
        return np.array(image)


def depth_metres(sample: dict[str, Any], stem: str) -> np.ndarray | None:
    """The member `stem` (`depth`, `depth_noisy`) as float32 metres, whichever format it has; None
    when the sample has neither."""
    if f"{stem}.png" in sample:
        return (sample[f"{stem}.png"].astype(np.float64) * DEPTH_PNG_UNIT_M).astype(np.float32)
    if f"{stem}.npy" in sample:
        return sample[f"{stem}.npy"].astype(np.float32, copy=False)
    return None


def quaternion_matrix(q: list[float]) -> np.ndarray:
    """Rotation matrix of a unit quaternion [w, x, y, z] (the dataset's convention)."""
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def touch_in_camera(meta: dict[str, Any], grasp: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """Active taxels' positions (N×3, metres) in this view's camera frame, and their forces (N).

    The grasp record gives them in the palm frame, which is the hand's pose in the world (meta's
    poses.hand); the camera's R_w2c, t_w2c take world points into the camera (OpenCV axes).
    """
    active = grasp["touch"]["active"]
    p_palm = np.array([a["p_palm"] for a in active], dtype=np.float64).reshape(-1, 3)
    palm = meta["poses"]["hand"]
    p_world = p_palm @ quaternion_matrix(palm["q"]).T + np.array(palm["p"])
    camera = meta["camera"]
    p_cam = p_world @ np.array(camera["R_w2c"]).T + np.array(camera["t_w2c"])
    force = np.array([a["force_n"] for a in active], dtype=np.float32)
    return p_cam.astype(np.float32), force


def to_tensors(sample: dict[str, Any]) -> dict[str, Any]:
    """One decoded sample as tensors: images channels-first, the object's pose in the camera."""
    meta, grasp = sample["meta.json"], sample["grasp.json"]
    camera = meta["camera"]
    touch, force = touch_in_camera(meta, grasp)
    out: dict[str, Any] = {
        "sample_id": sample["sample.json"]["sample_id"],
        "split": sample["sample.json"]["split"],
        "rgb": torch.from_numpy(sample["rgb.png"]).permute(2, 0, 1).contiguous(),
        "depth": torch.from_numpy(depth_metres(sample, "depth")),
        "mask": torch.from_numpy(sample["mask.png"] > 0),
        "K": torch.tensor(camera["K"], dtype=torch.float32),
        # OpenCV's lens distortion [k1, k2, p1, p2, k3]; a record without it is a pinhole's.
        "dist": torch.tensor(camera.get("dist", [0.0] * 5), dtype=torch.float32),
        "R": torch.tensor(camera["R_m2c"], dtype=torch.float32),
        "t": torch.tensor(camera["t_m2c"], dtype=torch.float32),
        "touch": torch.from_numpy(touch),
        "touch_force": torch.from_numpy(force),
    }
    noisy = depth_metres(sample, "depth_noisy")
    if noisy is not None:
        out["depth_noisy"] = torch.from_numpy(noisy)
    return out


def collate(samples: list[dict[str, Any]]) -> dict[str, Any]:
    """Stacks fixed-size tensors; pads the touch points (their count varies) with a validity mask."""
    batch: dict[str, Any] = {
        "sample_id": [s["sample_id"] for s in samples],
        "split": [s["split"] for s in samples],
    }
    for name in ("rgb", "depth", "depth_noisy", "mask", "K", "dist", "R", "t"):
        if all(name in s for s in samples):
            batch[name] = torch.stack([s[name] for s in samples])
    most = max(len(s["touch"]) for s in samples)
    batch["touch"] = torch.zeros(len(samples), most, 3)
    batch["touch_force"] = torch.zeros(len(samples), most)
    batch["touch_valid"] = torch.zeros(len(samples), most, dtype=torch.bool)
    for i, s in enumerate(samples):
        n = len(s["touch"])
        batch["touch"][i, :n] = s["touch"]
        batch["touch_force"][i, :n] = s["touch_force"]
        batch["touch_valid"][i, :n] = True
    return batch


def loader(root: Path, splits: list[str], batch_size: int, workers: int) -> DataLoader:
    dataset = (
        # Shards in index order and no shuffle, so a run is repeatable; to train, pass
        # shardshuffle=N and add .shuffle(1000): a shard holds a grasp's views next to each other.
        # empty_check=False: with more workers than a split has shards, some workers get none.
        wds.WebDataset(shard_paths(root, splits), shardshuffle=False, empty_check=False)
        .decode(wds.handle_extension("png", decode_png))
        .map(to_tensors)
    )
    return DataLoader(dataset, batch_size=batch_size, num_workers=workers, collate_fn=collate)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("shards", type=Path, help="a vint WebDataset export (with shards.json)")
    parser.add_argument("--split", choices=[*SPLITS, "all"], default="all")
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--workers", type=int, default=0, help="DataLoader worker processes")
    parser.add_argument("--json", action="store_true", help="one JSON line per sample, then a summary")
    args = parser.parse_args(argv)

    splits = list(SPLITS) if args.split == "all" else [args.split]
    per_split = dict.fromkeys(splits, 0)
    shapes: dict[str, list[int]] = {}
    batches = samples = touch_points = 0
    for batch in loader(args.shards, splits, args.batch_size, args.workers):
        batches += 1
        size = len(batch["sample_id"])
        samples += size
        touch_points += int(batch["touch_valid"].sum())
        for name in ("rgb", "depth", "depth_noisy", "mask", "K", "dist", "R", "t"):
            if name in batch:
                shapes[name] = list(batch[name].shape[1:])
        for i, sample_id in enumerate(batch["sample_id"]):
            per_split[batch["split"][i]] += 1
            if args.json:
                valid = batch["touch_valid"][i]
                line = {
                    "sample_id": sample_id,
                    "split": batch["split"][i],
                    "rgb": list(batch["rgb"][i].shape),
                    "depth": list(batch["depth"][i].shape),
                    "mask_px": int(batch["mask"][i].sum()),
                    "R": batch["R"][i].tolist(),
                    "t": batch["t"][i].tolist(),
                    "touch": batch["touch"][i][valid].tolist(),
                }
                print(json.dumps(line))
        if not args.json:
            rgb = batch["rgb"]
            print(
                f"batch {batches}: {size} samples, rgb {tuple(rgb.shape)} {rgb.dtype}, "
                f"depth {tuple(batch['depth'].shape)}, touch {tuple(batch['touch'].shape)}"
            )
    summary = {"samples": samples, "batches": batches, "splits": per_split, "shapes": shapes}
    summary["touch_points"] = touch_points
    if args.json:
        print(json.dumps({"summary": summary}))
    else:
        print(f"{samples} samples in {batches} batches; per split {per_split}; shapes {shapes}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
