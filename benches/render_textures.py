"""What object textures cost a rendered view: the same object, camera and seed with its catalog
texture and with a plain material, measured alternately view by view (so machine load affects both
alike), in one warm render scene (`vint_engines.render.scene.BlenderScene`, as the engine keeps it).

Run: PYTHONPATH=workers/engines .venv/bin/python benches/render_textures.py [--views N] [--size PX]
     [--samples S] [--smoke]

`--smoke`: one view per object, 16×16 px, 1 sample (seconds: the test command's check that the
bench still runs, not a figure).

Per object: N views from cameras around it (the object alone, studio HDRI, one CPU thread); the time
of a view is `render_rgb` (path tracing, including the shader compile the first time a material is
used, which the first views pay and the medians leave out). Also the first RGB view's cost, which
includes building and compiling the texture's nodes. Prints one line per object, then one JSON
object with the medians.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from vint_engines.objects import ObjectSpec, Texture, build_model, load_catalog
from vint_engines.render.camera import Intrinsics, look_at
from vint_engines.render.cycles import Bounces, PathTracing
from vint_engines.render.scene import BlenderScene, Hdri

OBJECTS = ("tomato_soup_can", "cracker_box", "wood_block", "mug", "large_metal_shaker")


def plain(spec: ObjectSpec) -> ObjectSpec:
    """The object without its texture, under another name so the scene keeps both meshes (and
    their compiled materials) instead of rebuilding one for every view."""
    return ObjectSpec(f"{spec.name}_plain", spec.mass, spec.material, spec.shape, Texture())


def view_ms(scene: BlenderScene, spec: ObjectSpec, view: int, size: int, tracing: PathTracing) -> float:
    scene.set_object(spec.to_json())
    scene.pose((np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0])), {})
    reach = float(np.linalg.norm(build_model(spec).extent))
    angle = 2 * math.pi * view / 7
    eye = np.array([1.1 * reach * math.cos(angle), 1.1 * reach * math.sin(angle), 0.4 * reach])
    scene.place_camera(look_at(eye, np.zeros(3)), Intrinsics(size, size, 60.0))
    start = time.perf_counter()
    scene.render_rgb(tracing, 1000 + view)
    return 1e3 * (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--views", type=int, default=7)
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--samples", type=int, default=32)
    parser.add_argument("--smoke", action="store_true", help="1 view, 16×16 px, 1 sample (seconds)")
    args = parser.parse_args()
    if args.smoke:
        args.views, args.size, args.samples = 1, 16, 1
    tracing = PathTracing(args.samples, False, Bounces(12, 4, 4, 12, 8))
    catalog = load_catalog()
    figures = {}
    with tempfile.TemporaryDirectory() as scratch:
        scene = BlenderScene(Path(scratch))
        scene.set_environment(Hdri.bundled("studio", "bench"))
        for name in OBJECTS:
            textured, bare = catalog[name], plain(catalog[name])
            times: dict[str, list[float]] = {"textured": [], "plain": []}
            for view in range(args.views + 1):  # view 0 compiles the shaders: reported apart
                for label, spec in (("textured", textured), ("plain", bare)):
                    times[label].append(view_ms(scene, spec, view, args.size, tracing))
            row = {
                label: {"first_ms": round(t[0], 1), "median_ms": round(statistics.median(t[1:]), 1)}
                for label, t in times.items()
            }
            ratio = row["textured"]["median_ms"] / row["plain"]["median_ms"]
            figures[name] = {**row, "ratio": round(ratio, 3), "texture": textured.texture.kind}
            print(
                f"{name:<20} {textured.texture.kind:<10} textured {row['textured']['median_ms']:7.1f} ms"
                f"  plain {row['plain']['median_ms']:7.1f} ms  ×{ratio:.2f}"
                f"  (first view {row['textured']['first_ms']:.0f} / {row['plain']['first_ms']:.0f} ms)",
                flush=True,
            )
    print(json.dumps({"size": args.size, "samples": args.samples, "views": args.views, "objects": figures}))


if __name__ == "__main__":
    main()
