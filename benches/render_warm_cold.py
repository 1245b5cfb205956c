"""Render engine cost: a warm engine against a fresh Blender process per view, side by side; what
each "leave out what the scene does not need" pruning saves; and resident memory over many views.

Run: PYTHONPATH=workers/engines .venv/bin/python benches/render_warm_cold.py [--views N] [--memory-views M]
     PYTHONPATH=workers/engines .venv/bin/python benches/render_warm_cold.py --smoke

Every render goes through the engine protocol exactly as a worker drives it (`python -m vint_engines
serve --stage render`, framed JSON over pipes), on grasps made by the real grasp engine (trx3 on
the tomato soup can and on the wine glass). Per setting:
  - warm: one engine process, its start-up excluded, N one-view tasks; the time of a view is the
    round trip of its task;
  - cold: for every view a new process is started, serves the one task and exits; the time of a
    view is process start to result (what a generator that runs `blender -b` per view pays);
both measured alternately, view by view, so machine load affects them alike. Pruning: the same
views with every output against depth/masks only (no path tracing), and the opaque can with its
pruned bounce caps against the same can with the caps a glass needs (`prune_bounces: false`).
Memory: M consecutive small views on one warm engine, its RSS (from /proc) after every task;
growth is the last RSS against the RSS after the first 5 % of the views.
Prints one line per setting and, last, one JSON object with every figure (medians).
`--smoke`: one view at 32x24 px and 1 sample per mode, 2 memory views (seconds, mostly engine
start-ups: the test command's check that the bench still runs, not a figure).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from vint_engines.study.grasped import GraspedScene, grasp

ENGINES_DIR = Path(__file__).resolve().parents[1] / "workers" / "engines"
SETTINGS = {"128x128/16spp": (128, 128, 16), "640x480/64spp": (640, 480, 64)}
SMOKE_SETTINGS = {"32x24/1spp": (32, 24, 1)}
ALL_OUTPUTS = ["rgb", "depth", "mask", "segmentation"]
DEPTH_ONLY = ["depth", "mask", "segmentation"]
_LENGTH = struct.Struct(">I")


class EngineProcess:
    """A render engine child process, driven over the engine protocol (PROTOCOL.md)."""

    def __init__(self) -> None:
        env = dict(os.environ, PYTHONPATH=str(ENGINES_DIR), PYTHONUNBUFFERED="1")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "vint_engines", "serve", "--stage", "render"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            env=env,
        )
        hello = self._read()
        if hello.get("type") != "hello":
            raise RuntimeError(f"expected hello, got {hello}")

    def _read(self) -> dict[str, Any]:
        assert self.proc.stdout is not None
        head = self.proc.stdout.read(4)
        if len(head) < 4:
            raise RuntimeError(f"render engine exited ({self.proc.wait()})")
        return dict(json.loads(self.proc.stdout.read(_LENGTH.unpack(head)[0])))

    def _write(self, message: dict[str, Any]) -> None:
        assert self.proc.stdin is not None
        body = json.dumps(message).encode()
        self.proc.stdin.write(_LENGTH.pack(len(body)) + body)
        self.proc.stdin.flush()

    def run(self, task_id: str, params: dict[str, Any], scene: GraspedScene, out_dir: Path) -> dict[str, Any]:
        out_dir.mkdir(parents=True, exist_ok=True)
        inputs = [{"name": i.name, "task_key": i.task_key, "path": str(i.path)} for i in scene.inputs()]
        self._write(
            {
                "type": "task",
                "task_id": task_id,
                "params": params,
                "inputs": inputs,
                "out_dir": str(out_dir),
            }
        )
        result = self._read()
        if not result.get("ok"):
            raise RuntimeError(f"render task failed: {result.get('error')}")
        return result

    def rss_bytes(self) -> int:
        for line in Path(f"/proc/{self.proc.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
        raise RuntimeError("no VmRSS")

    def close(self) -> None:
        self._write({"type": "shutdown"})
        self.proc.wait(timeout=30)


def render_params(
    grasp_index: int,
    view: int,
    size: tuple[int, int, int],
    outputs: list[str],
    environment: str = "studio",
    prune: bool = True,
) -> dict[str, Any]:
    width, height, samples = size
    return {
        "grasp_index": grasp_index,
        "render": {
            "width": width,
            "height": height,
            "samples": samples,
            "fov_deg": 50.0,
            "environment": environment,
            "radius_m": [0.35, 0.5],
            "elevation_deg": [15.0, 75.0],
            "prune_bounces": prune,
        },
        "views": [{"view_index": view % 100, "seed": 1000 + view, "environment": environment}],
        "outputs": outputs,
    }


def median_ms(values: list[float]) -> float:
    return round(1e3 * statistics.median(values), 1)


def warm_vs_cold(scene: GraspedScene, size: tuple[int, int, int], views: int, work: Path) -> dict[str, float]:
    warm_engine = EngineProcess()
    warm_engine.run(
        "warm-up",
        render_params(scene.accepted[0], 99, size, ALL_OUTPUTS),
        scene,
        work / "w",
    )
    warm, cold = [], []
    for v in range(views):
        params = render_params(scene.accepted[0], v, size, ALL_OUTPUTS)
        started = time.perf_counter()
        warm_engine.run(f"warm{v}", params, scene, work / f"warm{v}")
        warm.append(time.perf_counter() - started)
        started = time.perf_counter()
        fresh = EngineProcess()
        fresh.run(f"cold{v}", params, scene, work / f"cold{v}")
        fresh.close()
        cold.append(time.perf_counter() - started)
    warm_engine.close()
    return {
        "warm_ms": median_ms(warm),
        "cold_ms": median_ms(cold),
        "cold_over_warm": round(median_ms(cold) / median_ms(warm), 2),
    }


def pruning(
    can: GraspedScene, glass: GraspedScene, size: tuple[int, int, int], views: int, work: Path
) -> dict[str, float]:
    """Per-view times of the same views: the can with every output, with the bounce caps a glass
    needs (pruning off), with depth and masks only; the glass with every output."""
    engine = EngineProcess()
    variants = (
        (can, "can_full", ALL_OUTPUTS, True),
        (can, "can_glass_caps", ALL_OUTPUTS, False),
        (can, "can_depth_only", DEPTH_ONLY, True),
        (glass, "glass_full", ALL_OUTPUTS, True),
    )
    times: dict[str, list[float]] = {key: [] for _, key, _, _ in variants}
    for scene, key, outputs, prune in variants:
        params = render_params(scene.accepted[0], 99, size, outputs, prune=prune)
        engine.run(f"warm-{key}", params, scene, work / "w")
    for v in range(views):
        for scene, key, outputs, prune in variants:
            params = render_params(scene.accepted[0], v, size, outputs, prune=prune)
            started = time.perf_counter()
            engine.run(f"{key}{v}", params, scene, work / f"{key}{v}")
            times[key].append(time.perf_counter() - started)
    engine.close()
    figures = {f"{key}_ms": median_ms(values) for key, values in times.items()}
    figures["depth_only_saving"] = round(1.0 - figures["can_depth_only_ms"] / figures["can_full_ms"], 3)
    figures["opaque_caps_saving"] = round(1.0 - figures["can_full_ms"] / figures["can_glass_caps_ms"], 3)
    figures["glass_over_can"] = round(figures["glass_full_ms"] / figures["can_full_ms"], 2)
    return figures


def memory(scene: GraspedScene, views: int, work: Path) -> dict[str, float]:
    engine = EngineProcess()
    rss = []
    environments = ("studio", "forest", "city", "courtyard")
    for v in range(views):
        params = render_params(
            scene.accepted[v % len(scene.accepted)],
            v,
            (64, 64, 4),
            ALL_OUTPUTS,
            environments[v % 4],
        )
        engine.run(f"mem{v}", params, scene, work / "mem")
        rss.append(engine.rss_bytes())
    engine.close()
    base = rss[max(0, views // 20 - 1)]
    return {
        "views": views,
        "rss_after_5pct_mib": round(base / 2**20, 1),
        "rss_last_mib": round(rss[-1] / 2**20, 1),
        "rss_max_mib": round(max(rss) / 2**20, 1),
        "growth": round(rss[-1] / base - 1.0, 4),
    }


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--views", type=int, default=5, help="views per setting and mode (default 5)")
    parser.add_argument(
        "--memory-views",
        type=int,
        default=500,
        help="views in the memory run (0: skip)",
    )
    parser.add_argument("--settings", default=",".join(SETTINGS), help="comma-separated settings")
    parser.add_argument("--smoke", action="store_true", help="1 view at 32x24/1spp, 2 memory views")
    args = parser.parse_args()
    if args.smoke:
        args.views, args.memory_views = 1, 2
    settings = SMOKE_SETTINGS if args.smoke else {name: SETTINGS[name] for name in args.settings.split(",")}
    figures: dict[str, Any] = {"machine": {"cpus": os.cpu_count()}}
    with tempfile.TemporaryDirectory(prefix="vint-render-bench-") as tmp:
        work = Path(tmp)
        can = grasp("trx3", "tomato_soup_can", work / "can", list(range(101, 105)))
        glass = grasp("trx3", "wine_glass", work / "glass", list(range(201, 209)))
        for name, size in settings.items():
            figures[name] = {
                **warm_vs_cold(can, size, args.views, work / name),
                **pruning(can, glass, size, args.views, work / name),
            }
            print(f"{name}: {json.dumps(figures[name])}", flush=True)
        if args.memory_views:
            figures["memory"] = memory(can, args.memory_views, work)
            print(f"memory: {json.dumps(figures['memory'])}", flush=True)
    print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    sys.exit(main())
