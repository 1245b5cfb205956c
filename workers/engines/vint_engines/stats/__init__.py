"""`python -m vint_engines stats --dataset DIR --out OUT [--json]` (or `vintctl stats DIR|JOB`): a
dataset's statistics — occlusion, camera distance, viewing direction in the object frame, active
taxels per grasp by hand and region, grasp acceptance per (object, hand) pair, the object's pose in
the palm frame, the camera's side of the palm, grasp types, samples per object and environment —
as PNG figures, `stats.md` (markdown tables) and `stats.json` (the numbers), for a native or a BOP
dataset.

`dataset` reads either layout into the same records, `numbers` computes (`hand` the palm-frame
statistics, `summaries` the summaries and bins all share), `plots` and `table` only present.
Writes nothing outside OUT and never modifies the dataset.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

STATS_JSON = "stats.json"
STATS_MD = "stats.md"


def main(dataset_dir: Path, out: Path, as_json: bool) -> int:
    """Exit status: 0 written, 2 the directory is not a dataset this reads (said on stderr)."""
    from vint_engines.stats import dataset, numbers, plots, table

    try:
        data = dataset.read(dataset_dir)
    except dataset.DatasetError as exc:
        print(f"stats: {exc}", file=sys.stderr)
        return 2
    stats = numbers.compute(data)
    out.mkdir(parents=True, exist_ok=True)
    document = json.dumps(stats, indent=1, allow_nan=False) + "\n"
    (out / STATS_JSON).write_text(document, encoding="utf-8")
    (out / STATS_MD).write_text(table.markdown(stats), encoding="utf-8")
    plots.write_all(out, stats, data)
    if as_json:
        sys.stdout.write(document)
    else:
        counts = stats["counts"]
        print(
            f"{counts['samples']} samples, {counts['grasps']} grasps ({data.layout} layout): "
            f"{STATS_MD}, {STATS_JSON} and {len(plots.PNGS)} figures in {out}"
        )
    return 0
