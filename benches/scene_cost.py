"""What the scene around the grasp and the colour sensor cost per view, side by side: the same views
rendered through the render engine (`RenderEngine.run`, a worker's code path, one warm engine on
one CPU thread) with no scene, the table alone, the arm flange alone, both (the default), and both
plus the sensor model.

    .venv/bin/python benches/scene_cost.py [--size 640x480] [--samples 32] [--views 2] [--repeats 2]
    .venv/bin/python benches/scene_cost.py --smoke     # 32×24, 1 sample, 1 view, 1 repeat (seconds)

Variants run interleaved (round-robin per repeat, each view of each variant once per repeat), so a
slow moment of the machine hits them all alike; the table is medians per view and the ratio to
the bare scene. The grasp comes from the real grasp engine (allegro holding the mustard bottle).
"""

from __future__ import annotations

import argparse
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workers" / "engines"))

from vint_engines.protocol import TaskRequest
from vint_engines.study.grasped import grasp

VARIANTS: dict[str, dict[str, Any]] = {
    "bare (no table, no flange, no sensor)": {
        "scene": {"table": False, "flange": False},
        "sensor": {"enabled": False},
    },
    "table": {"scene": {"table": True, "flange": False}, "sensor": {"enabled": False}},
    "flange": {"scene": {"table": False, "flange": True}, "sensor": {"enabled": False}},
    "table + flange": {"scene": {"table": True, "flange": True}, "sensor": {"enabled": False}},
    "table + flange + sensor (default)": {
        "scene": {"table": True, "flange": True},
        "sensor": {"enabled": True},
    },
    "default + 4 distractors": {
        "scene": {"table": True, "flange": True, "distractors": 4},
        "sensor": {"enabled": True},
    },
}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="640x480")
    parser.add_argument("--samples", type=int, default=32)
    parser.add_argument("--views", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--smoke", action="store_true", help="32x24, 1 sample, 1 view, 1 repeat (seconds)")
    args = parser.parse_args()
    if args.smoke:
        args.size, args.samples, args.views, args.repeats = "32x24", 1, 1, 1
    width, height = (int(v) for v in args.size.split("x"))

    from vint_engines.render.engine import RenderEngine

    with tempfile.TemporaryDirectory(prefix="vint-scene-cost-") as tmp:
        work = Path(tmp)
        scene = grasp("allegro", "mustard_bottle", work / "grasp", [11, 12, 13, 14])
        engine = RenderEngine()
        times: dict[str, list[float]] = {name: [] for name in VARIANTS}
        for repeat in range(args.repeats + 1):  # repeat 0 warms every variant up, untimed
            for name, extra in VARIANTS.items():
                for view in range(args.views):
                    params = {
                        "grasp_index": scene.accepted[0],
                        "render": {
                            "width": width,
                            "height": height,
                            "samples": args.samples,
                            "denoise": True,
                            **extra,
                        },
                        "views": [{"view_index": view, "seed": 900 + view}],
                    }
                    out = work / "out"
                    out.mkdir(exist_ok=True)
                    started = time.perf_counter()
                    engine.run(TaskRequest("bench", params, scene.inputs(), out))
                    if repeat > 0:
                        times[name].append(time.perf_counter() - started)
        engine.close()
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True
    ).stdout.strip()
    bare = statistics.median(next(iter(times.values())))
    print(
        f"# Scene cost per view: {width}×{height}, {args.samples} spp + denoise, {args.views} views × "
        f"{args.repeats} repeats, commit {commit}, {platform.machine()}, one render thread\n"
    )
    print("| variant | median s / view | × bare |")
    print("|---|---:|---:|")
    for name, values in times.items():
        median = statistics.median(values)
        print(f"| {name} | {median:.2f} | {median / bare:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
