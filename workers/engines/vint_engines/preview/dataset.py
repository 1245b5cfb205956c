"""Which samples a contact sheet shows, and what it reads of each: a native dataset's
`<sample_id>/meta.json`, the grasp record it refers to (`<grasp_id>/grasp.json`) and the sample's
image and depth files, whichever of them the spec asked for (`docs/formats.md`).

Reads only; a directory that is not a native dataset, or one without samples, is a `PreviewError`
naming the path.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from vint_engines import depth_file
from vint_engines.preview.taxels import Camera
from vint_engines.stats.dataset import DatasetError, read_json

META_FILE = "meta.json"
RGB_FILE = "rgb.png"
DEPTH_FILE = "depth"  # .png or .npy: `vint_engines.depth_file`
NOISY_DEPTH_FILE = "depth_noisy"
SEGMENTATION_FILE = "segmentation.png"


class PreviewError(DatasetError):
    """The directory is not a native dataset with samples, or a record in it is malformed."""


@dataclass(frozen=True)
class SampleRef:
    """A sample as listed before it is chosen: enough to choose it."""

    sample_id: str
    object: str
    hand: str
    directory: Path


@dataclass(frozen=True)
class Sample:
    """A chosen sample: what the sheet reads of its records, its grasp's record as it is, and where
    its files are (a file the spec did not ask for is simply absent)."""

    sample_id: str
    object: str
    hand: str
    directory: Path
    camera: Camera
    segment_names: dict[int, str]  # the camera record's `segmentation`: id → `object`, `hand/<link>`, …
    occlusion: float
    active_taxels: int
    grasp: dict[str, Any]

    def file(self, name: str) -> Path | None:
        path = self.directory / name
        return path if path.is_file() else None

    def depth_file(self, stem: str) -> Path | None:
        """The depth file `stem` (`depth`, `depth_noisy`) in whichever format the sample has."""
        return depth_file.find(self.directory, stem)


def list_samples(root: Path) -> list[SampleRef]:
    """Every sample of the native dataset at `root`, in id order."""
    if not root.is_dir():
        raise PreviewError(f"{root}: no such dataset directory")
    refs = []
    for entry in sorted(root.iterdir()):
        if (entry / META_FILE).is_file():
            meta = read_json(entry / META_FILE)
            try:
                refs.append(
                    SampleRef(str(meta["sample_id"]), str(meta["object"]["name"]), str(meta["hand"]), entry)
                )
            except (KeyError, TypeError) as exc:
                raise PreviewError(f"{entry / META_FILE}: malformed sample record ({exc!r})") from exc
    if not refs:
        raise PreviewError(f"{root}: no samples (a native dataset has <sample_id>/{META_FILE})")
    refs.sort(key=lambda r: r.sample_id)
    return refs


def choose(refs: list[SampleRef], count: int) -> list[SampleRef]:
    """`count` samples spread over objects and hands: the first sample (by id) of each
    (object, hand) pair, then the others by id. Pairs are taken object by object, each object's
    hands turned by the object's position, so that consecutive picks change both the object and
    the hand (3 objects × 2 hands: the first 3 picks cover every object and both hands)."""
    refs = sorted(refs, key=lambda r: r.sample_id)
    objects = sorted({r.object for r in refs})
    hands_of = {o: sorted({r.hand for r in refs if r.object == o}) for o in objects}
    turned = {
        o: hands[i % len(hands) :] + hands[: i % len(hands)] for i, (o, hands) in enumerate(hands_of.items())
    }
    pairs = [
        (o, turned[o][k])
        for k in range(max(len(h) for h in hands_of.values()))
        for o in objects
        if k < len(turned[o])
    ]
    firsts = [next(r for r in refs if (r.object, r.hand) == pair) for pair in pairs]
    rest = [r for r in refs if r not in firsts]
    return (firsts + rest)[:count]


def load(ref: SampleRef) -> Sample:
    """The sample's meta.json and its grasp's record (meta.json's `grasp.record`, relative to the
    sample's directory)."""
    meta_path = ref.directory / META_FILE
    meta = read_json(meta_path)
    try:
        record = ref.directory / str(meta["grasp"]["record"])
        camera = meta["camera"]
        sample = Sample(
            sample_id=ref.sample_id,
            object=ref.object,
            hand=ref.hand,
            directory=ref.directory,
            camera=Camera.from_record(camera),
            segment_names={int(k): str(v) for k, v in camera.get("segmentation", {}).items()},
            occlusion=float(meta["visibility"]["occlusion"]),
            active_taxels=0,
            grasp={},
        )
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise PreviewError(f"{meta_path}: malformed sample record ({exc!r})") from exc
    grasp = read_json(record)
    try:
        active = len(grasp["touch"]["active"])
        grasp["trial"]["hand_pose"]
    except (KeyError, TypeError) as exc:
        raise PreviewError(f"{record}: malformed grasp record ({exc!r})") from exc
    return replace(sample, active_taxels=active, grasp=grasp)
