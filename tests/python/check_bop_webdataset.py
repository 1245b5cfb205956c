"""Check a BOP-webdataset export of a vint dataset against the BOP export of the same dataset.

    check_bop_webdataset.py WDS_DIR BOP_DIR
        exit 0 and a JSON summary on stdout, or exit 1 and every failure on stderr

WDS_DIR is `vintctl convert --format bop-webdataset`'s output, BOP_DIR `--format bop`'s of the same
native dataset. Per split folder the shards are read twice, as their loaders read them:

- in sequence with the `webdataset` package (`wds.WebDataset(urls)`, raw members), every member
  decoded as the BOP toolkit's `bop_webdataset.decode_sample` decodes it: `camera.json`, `gt.json`
  and `gt_info.json` parsed (poses to 3×3 and 3×1 arrays), `rgb.png` to uint8 H×W×3, `depth.png` to
  uint16 H×W times `camera["depth_scale"]` (mm), `mask.json` and `mask_visib.json` as instance id →
  COCO uncompressed RLE decoded to N×H×W booleans, and our members (`touch.json`, `hand.json`,
  `meta.json`, `depth_noisy.png`, `segmentation.png`) parsed or decoded;
- by index with `wids` (`ShardListDataset` over the split's `shardindex.json`): every index gives
  the image the sequential read gave at that position, with the same bytes.

Every image is then compared with the BOP export: its key `{scene_id:06d}_{im_id:06d}` names a
scene and image there, each JSON member equals that image's entry in the scene file of the same
name (`gt.json` ↔ `scene_gt.json`, …), each PNG decodes to the same pixels, each mask to the mask
PNG's pixels; every image of the split is there exactly once; `key_to_shard.json` says where each
key is. The shard order is recomputed here from the rule `docs/formats.md` states (nothing shared
with the writer): per split, images by increasing rank, ties by key, then cut into shards of
`shard_samples`, where rank = the first 8 bytes, little-endian, of sha256(b"vint-seed-v1\\0" + seed
as 8 little-endian bytes + b"shard-order" + per part its length as 8 little-endian bytes and its
UTF-8 bytes), masked to 53 bits, over the parts (object, hand, grasp index, view index).
"""

from __future__ import annotations

import hashlib
import json
import struct
import sys
import tempfile
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
import webdataset as wds

SPLITS = ("train", "val", "test")
# Our member name → the BOP export's scene file holding the same per-image record.
JSON_MEMBERS = {
    "camera.json": "scene_camera",
    "gt.json": "scene_gt",
    "gt_info.json": "scene_gt_info",
    "touch.json": "scene_touch",
    "hand.json": "scene_hand",
    "meta.json": "scene_meta",
}
PNG_MEMBERS = {
    "rgb.png": "rgb",
    "depth.png": "depth",
    "depth_noisy.png": "depth_noisy",
    "segmentation.png": "segmentation",
}
MASK_MEMBERS = {"mask.json": "mask", "mask_visib.json": "mask_visib"}


class Failures:
    def __init__(self) -> None:
        self.messages: list[str] = []

    def check(self, ok: bool, message: str) -> bool:
        if not ok:
            self.messages.append(message)
        return ok


def shard_rank(seed: int, parts: list[str]) -> int:
    h = hashlib.sha256(b"vint-seed-v1\0" + struct.pack("<Q", seed) + b"shard-order")
    for part in parts:
        data = part.encode()
        h.update(struct.pack("<Q", len(data)) + data)
    return struct.unpack("<Q", h.digest()[:8])[0] & ((1 << 53) - 1)


def expected_order(seed: int, images: dict[str, tuple[str, int]]) -> list[str]:
    """Keys by the documented rule; `images` maps key → (grasp id, view index)."""

    def rank(key: str) -> tuple[int, str]:
        grasp_id, view = images[key]
        obj, hand, grasp = grasp_id.split(".")
        return shard_rank(seed, [obj, hand, str(int(grasp.lstrip("g"))), str(view)]), key

    return sorted(images, key=rank)


def decode_png(data: bytes) -> npt.NDArray[Any]:
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError("not a PNG")
    if image.ndim == 3:
        image = image[..., ::-1]  # OpenCV decodes BGR
    return image


def rle_to_mask(rle: dict[str, Any]) -> npt.NDArray[np.bool_]:
    """COCO's uncompressed RLE: alternating runs of 0 and 1, column-major, starting with 0."""
    height, width = rle["size"]
    flat = np.zeros(height * width, dtype=bool)
    at, value = 0, False
    for run in rle["counts"]:
        flat[at : at + run] = value
        at, value = at + run, not value
    if at != height * width:
        raise ValueError(f"runs cover {at} pixels of {height * width}")
    return flat.reshape((width, height)).T


def load_masks(data: bytes) -> npt.NDArray[np.bool_]:
    """`bop_imagewise.io_load_masks`: instance id → RLE, stacked by instance id."""
    masks = {int(k): v for k, v in json.loads(data).items()}
    return np.stack([rle_to_mask(masks[i]) for i in sorted(masks)])


def load_gt(data: bytes) -> list[dict[str, Any]]:
    """`bop_imagewise.io_load_gt`: the per-instance list, poses as arrays."""
    gt = json.loads(data)
    for g in gt:
        if "cam_R_m2c" in g:
            g["cam_R_m2c"] = np.array(g["cam_R_m2c"], np.float64).reshape((3, 3))
            g["cam_t_m2c"] = np.array(g["cam_t_m2c"], np.float64).reshape((3, 1))
    return gt


def decode_sample(sample: dict[str, Any]) -> dict[str, Any]:
    """Every member decoded, as the toolkit's `decode_sample` does for BOP's (and likewise ours)."""
    out: dict[str, Any] = {}
    camera = json.loads(sample["camera.json"])
    out["camera"] = camera
    out["rgb"] = decode_png(sample["rgb.png"]).astype(np.uint8)
    for name in ("depth.png", "depth_noisy.png"):
        if name in sample:
            depth = decode_png(sample[name])
            if depth.dtype != np.uint16 or depth.ndim != 2:
                raise ValueError(f"{name}: {depth.dtype} {depth.shape}, not uint16 H×W")
            out[name] = depth.astype(np.float32) * camera["depth_scale"]
    if "segmentation.png" in sample:
        out["segmentation"] = decode_png(sample["segmentation.png"])
    out["gt"] = load_gt(sample["gt.json"])
    if "gt_info.json" in sample:
        out["gt_info"] = json.loads(sample["gt_info.json"])
    for name in MASK_MEMBERS:
        if name in sample:
            out[name] = load_masks(sample[name])
    for name in ("touch.json", "hand.json", "meta.json"):
        out[name] = json.loads(sample[name])
    return out


class Bop:
    """The BOP export: per-image records by (scene id, im id), and where its files are."""

    def __init__(self, root: Path) -> None:
        self.root = root
        dataset = json.loads((root / "dataset.json").read_text())
        self.scenes = {s["scene_id"]: s for s in dataset["bop"]["scenes"]}
        self.files: dict[str, dict[str, Any]] = {}

    def scene_dir(self, scene_id: int) -> Path:
        return self.root / self.scenes[scene_id]["split"] / f"{scene_id:06d}"

    def record(self, scene_id: int, im_id: int, file: str) -> Any:
        """The image's entry in the scene's `file`.json, None where it has none."""
        path = self.scene_dir(scene_id) / f"{file}.json"
        if str(path) not in self.files:
            self.files[str(path)] = json.loads(path.read_text()) if path.exists() else {}
        return self.files[str(path)].get(str(im_id))

    def images(self, split: str) -> dict[str, tuple[int, int]]:
        return {
            f"{s['scene_id']:06d}_{im:06d}": (s["scene_id"], im)
            for s in self.scenes.values()
            if s["split"] == split
            for im in s["im_ids"]
        }


def raw(value: Any) -> bytes:
    if isinstance(value, bytes):
        return value
    if hasattr(value, "read"):
        return value.read()
    return bytes(value)


def check_image(key: str, sample: dict[str, bytes], bop: Bop, fail: Failures) -> int:
    """Compares one sample with the BOP export's image of the same key; returns members checked."""
    scene_id, im_id = (int(x) for x in key.split("_"))
    decoded = decode_sample(sample)
    scene = bop.scene_dir(scene_id)
    expected = {name for name, file in JSON_MEMBERS.items() if bop.record(scene_id, im_id, file) is not None}
    expected |= {
        name for name, folder in PNG_MEMBERS.items() if (scene / folder / f"{im_id:06d}.png").exists()
    }
    expected |= {
        name for name, folder in MASK_MEMBERS.items() if (scene / folder / f"{im_id:06d}_000000.png").exists()
    }
    fail.check(set(sample) == expected, f"{key}: members {sorted(sample)}, expected {sorted(expected)}")
    checked = 0
    for name, file in JSON_MEMBERS.items():
        if name in sample:
            fail.check(
                json.loads(sample[name]) == bop.record(scene_id, im_id, file), f"{key}: {name} ≠ {file}.json"
            )
            checked += 1
    for name, folder in PNG_MEMBERS.items():
        if name in sample:
            want = decode_png((scene / folder / f"{im_id:06d}.png").read_bytes())
            got = decode_png(sample[name])
            fail.check(got.dtype == want.dtype and np.array_equal(got, want), f"{key}: {name} ≠ {folder}/")
            checked += 1
    for name, folder in MASK_MEMBERS.items():
        if name in sample:
            want = decode_png((scene / folder / f"{im_id:06d}_000000.png").read_bytes()) > 0
            got = decoded[name]
            fail.check(
                got.shape == (1, *want.shape) and np.array_equal(got[0], want), f"{key}: {name} ≠ {folder}/"
            )
            checked += 1
    camera, gt = decoded["camera"], decoded["gt"][0]
    shape = (camera["height"], camera["width"])
    fail.check(decoded["rgb"].shape == (*shape, 3), f"{key}: rgb {decoded['rgb'].shape}")
    fail.check(decoded["depth.png"].shape == shape, f"{key}: depth {decoded['depth.png'].shape}")
    # The depth in mm at the object's visible pixels is about the distance of its origin.
    if "mask_visib.json" in decoded:
        visible = decoded["mask_visib.json"][0] & (decoded["depth.png"] > 0)
        if visible.any():
            z = float(np.median(decoded["depth.png"][visible]))
            t_z = float(gt["cam_t_m2c"][2, 0])
            fail.check(
                abs(z - t_z) < 500.0, f"{key}: depth {z:.1f} mm at the object, its pose says {t_z:.1f} mm"
            )
    fail.check(decoded["meta.json"]["obj_id"] == gt["obj_id"], f"{key}: meta.json's obj_id")
    return checked


def read_sequentially(urls: list[str]) -> list[dict[str, Any]]:
    dataset = wds.WebDataset(urls, shardshuffle=False, empty_check=False)
    return [dict(sample) for sample in dataset]


def read_by_index(index: Path, cache: Path) -> list[dict[str, Any]]:
    import wids  # torch is imported with it: loaded only here

    dataset = wids.ShardListDataset(str(index), cache_dir=str(cache), transformations=[])
    return [dataset[i] for i in range(len(dataset))]


def check_split(root: Path, split: str, bop: Bop, dataset: dict[str, Any], fail: Failures) -> dict[str, Any]:
    folder = root / split
    index = json.loads((folder / "shardindex.json").read_text())
    fail.check(index.get("__kind__") == "wids-shard-index-v1", f"{split}: shardindex.json's __kind__")
    fail.check(index.get("wids_version") == 1, f"{split}: shardindex.json's wids_version")
    shardlist = index["shardlist"]
    names = [s["url"] for s in shardlist]
    fail.check(names == [f"shard-{n:06d}.tar" for n in range(len(names))], f"{split}: shard names {names}")
    on_disk = sorted(p.name for p in folder.glob("shard-*.tar"))
    fail.check(on_disk == names, f"{split}: shards on disk {on_disk} vs shardindex.json {names}")
    for s in shardlist:
        fail.check(s["filesize"] == (folder / s["url"]).stat().st_size, f"{split}/{s['url']}: filesize")

    urls = [str(folder / name) for name in names]
    samples = read_sequentially(urls)
    keys = [s["__key__"] for s in samples]
    shard_of = {s["__key__"]: Path(s["__url__"]).name for s in samples}
    fail.check(
        [s["nsamples"] for s in shardlist] == [list(shard_of.values()).count(n) for n in names],
        f"{split}: shardindex.json's nsamples",
    )
    key_to_shard = json.loads((folder / "key_to_shard.json").read_text())
    fail.check(
        key_to_shard == {k: int(shard_of[k][len("shard-") : -len(".tar")]) for k in keys},
        f"{split}: key_to_shard.json is not where the keys are",
    )

    images = bop.images(split)
    fail.check(sorted(keys) == sorted(images), f"{split}: keys are not the BOP export's images, once each")
    members = 0
    for sample in samples:
        members += check_image(
            sample["__key__"], {k: v for k, v in sample.items() if not k.startswith("__")}, bop, fail
        )

    # The seeded order, recomputed, and its cut into shards.
    seed = dataset["seed"]
    ids = {k: (bop.scenes[s]["grasp_id"], im) for k, (s, im) in images.items()}
    order = expected_order(seed, ids)
    fail.check(keys == order, f"{split}: shard order is not the seeded shuffle: {keys[:5]}… vs {order[:5]}…")
    per_shard = dataset["bop_webdataset"]["shard_samples"]
    cut = [f"shard-{i // per_shard:06d}.tar" for i in range(len(order))]
    fail.check(
        [shard_of[k] for k in order] == cut, f"{split}: images are not dealt into shards of {per_shard}"
    )
    fail.check(
        order != sorted(order) or len(order) < 3, f"{split}: the order is the sorted one: not shuffled"
    )

    with tempfile.TemporaryDirectory() as cache:
        indexed = read_by_index(folder / "shardindex.json", Path(cache))
    fail.check(
        len(indexed) == len(samples), f"{split}: wids has {len(indexed)} samples, the shards {len(samples)}"
    )
    for i, (by_index, sample) in enumerate(zip(indexed, samples, strict=False)):
        same_key = fail.check(
            by_index["__key__"] == sample["__key__"], f"{split}: wids index {i} is {by_index['__key__']}"
        )
        wanted = {k: v for k, v in sample.items() if not k.startswith("__")}
        got = {k.lstrip("."): raw(v) for k, v in by_index.items() if not k.startswith("__")}
        if same_key:
            fail.check(got == wanted, f"{split}: wids index {i} ({sample['__key__']}): members differ")
    return {"images": len(samples), "shards": len(names), "members_compared": members, "first": keys[:3]}


def check(root: Path, bop_root: Path) -> tuple[dict[str, Any], list[str]]:
    fail = Failures()
    dataset = json.loads((root / "dataset.json").read_text())
    fail.check(
        dataset.get("format") == "vint-bop-webdataset", f"dataset.json's format is {dataset.get('format')}"
    )
    bop = Bop(bop_root)
    summary: dict[str, Any] = {"splits": {}}
    for split in SPLITS:
        has_images = bool(bop.images(split))
        fail.check(
            (root / split).is_dir() == has_images, f"{split}: a folder exactly when the split has images"
        )
        if has_images:
            summary["splits"][split] = check_split(root, split, bop, dataset, fail)
    summary["images"] = sum(s["images"] for s in summary["splits"].values())
    return summary, fail.messages


def main(argv: list[str]) -> int:
    if len(argv) != 3:
        print(__doc__, file=sys.stderr)
        return 2
    summary, failures = check(Path(argv[1]), Path(argv[2]))
    print(json.dumps(summary, indent=1))
    for message in failures:
        print(f"check_bop_webdataset: {message}", file=sys.stderr)
    if failures:
        print(f"check_bop_webdataset: FAILED ({len(failures)} problems)", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
