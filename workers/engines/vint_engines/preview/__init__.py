"""`python -m vint_engines preview --dataset DIR --out SHEET.png [--samples N] [--json]` (or
`vintctl preview DIR|JOB`): a contact sheet showing a native dataset at a glance — per sample one
row of RGB, depth, noisy depth, segmentation and the RGB with the grasp's active taxels projected
into it, under a caption with the sample's id, object, hand, occlusion, active taxels and depth
range (`docs/preview.md`).

`dataset` lists and chooses the samples and reads their records, `taxels` projects the grasp's
taxels with the view's camera, `tiles` draws one modality, `sheet` lays them out. Writes only the
sheet and never modifies the dataset.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

DEFAULT_SAMPLES = 4
MAX_SAMPLES = 64


def main(dataset_dir: Path, out: Path, samples: int, as_json: bool) -> int:
    """Exit status: 0 written, 2 the directory is not a native dataset with samples, or a record
    or file of a chosen sample is unreadable (said on stderr, naming the path)."""
    from vint_engines.objects.catalog import CATALOG_DIR
    from vint_engines.preview import dataset, sheet
    from vint_engines.stats.dataset import DatasetError

    if not 1 <= samples <= MAX_SAMPLES:
        print(f"preview: --samples must be 1 to {MAX_SAMPLES}, got {samples}", file=sys.stderr)
        return 2
    try:
        chosen = [dataset.load(ref) for ref in dataset.choose(dataset.list_samples(dataset_dir), samples)]
        made = sheet.compose(chosen, CATALOG_DIR)
    except DatasetError as exc:  # a PreviewError, or a record stats.dataset.read_json refused
        print(f"preview: {exc}", file=sys.stderr)
        return 2
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(sheet.encode_png(made.image))
    height, width = made.image.shape[:2]
    summary = {
        "path": str(out),
        "samples": made.samples,
        "columns": list(sheet.COLUMNS),
        "size": [width, height],
        "tile": [made.tile.width, made.tile.height],
        "header_px": sheet.HEADER_PX,
        "caption_px": sheet.CAPTION_PX,
    }
    if as_json:
        sys.stdout.write(json.dumps(summary, indent=1) + "\n")
    else:
        print(f"{len(made.samples)} samples × {len(sheet.COLUMNS)} columns, {width}×{height} px: {out}")
    return 0
