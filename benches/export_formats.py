"""Export formats: how long `vintctl convert` takes to write BOP's layout and WebDataset shards from a
native dataset, against a plain `cp -r` of the same bytes, and what each layout costs on disk.

    python benches/export_formats.py NATIVE_DIR [--runs 5] [--copies 20] [--vintctl target/debug/vintctl]
    python benches/export_formats.py --smoke [NATIVE_DIR]

NATIVE_DIR is a native dataset (`vintctl run examples/tiny.toml --out DIR`). It is timed as it is,
and, with --copies K > 1, as a larger dataset made here of K copies of its grasps under new grasp
indices (index + 100·k; ids, records, manifest and split rewritten to match, the images and depth
maps copied as they are). Per dataset, each repetition runs, in turn, `cp -r NATIVE OUT`, `vintctl
convert NATIVE --out OUT --format webdataset` and `... --format bop` (the output removed and `sync`
run before each run, untimed), after one untimed warm-up of each: the page cache is warm (dropping
it needs root on the host), and a run's time is until its writes are in the page cache, not on
disk. A convert includes what `vintctl convert` always does: reading the native files, writing the
output and hashing it into manifest.jsonl. Prints a markdown table (medians) and a
JSON line. A layout whose writer fails (e.g. `--format bop` before its writer landed) is reported
as such and left out, and the exit status is then 1.

`--smoke`: one run and 2 copies, on NATIVE_DIR or, without it, on a dataset of benches/smoke.toml
that it makes with `vintctl run` in its temporary directory (seconds: the test command's check that
the bench still runs).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SMOKE_SPEC = ROOT / "benches" / "smoke.toml"
LAYOUTS = ("cp -r", "webdataset", "bop")


def du_bytes(path: Path) -> int:
    """`du -sb`: apparent bytes of the files and directories under `path`."""
    done = subprocess.run(["du", "-sb", str(path)], check=True, capture_output=True, text=True)
    return int(done.stdout.split()[0])


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def scale_native(native: Path, out: Path, copies: int) -> None:
    """Writes `copies` copies of the native dataset at `native` into `out` under new grasp indices."""
    record = json.loads((native / "dataset.json").read_text())
    lines = [json.loads(line) for line in (native / "manifest.jsonl").read_text().splitlines() if line]
    out.mkdir(parents=True)
    shutil.copytree(native / "models", out / "models")
    split: dict[str, str] = {}
    manifest: list[dict] = [line for line in lines if "model" in line]
    for k in range(copies):

        def renamed(grasp_id: str, k: int = k) -> str:
            obj, hand, g = grasp_id.split(".")
            return f"{obj}.{hand}.g{int(g[1:]) + 100 * k:06d}"

        for grasp, name in record["split"]["grasps"].items():
            split[renamed(grasp)] = name
        for line in lines:
            if "grasp_id" in line:
                new = renamed(line["grasp_id"])
                grasp = json.loads((native / line["grasp_id"] / "grasp.json").read_text())
                grasp["grasp_id"], grasp["grasp_index"] = new, int(new.rsplit(".g", 1)[1])
                (out / new).mkdir()
                (out / new / "grasp.json").write_text(json.dumps(grasp, indent=1))
                files = {"grasp.json": file_entry(out / new / "grasp.json")}
                manifest.append({"grasp_id": new, "files": files})
        for line in lines:
            if "sample_id" in line:
                old_grasp, view = line["sample_id"].rsplit(".", 1)
                grasp, sample = renamed(old_grasp), f"{renamed(old_grasp)}.{view}"
                shutil.copytree(native / line["sample_id"], out / sample)
                meta = json.loads((out / sample / "meta.json").read_text())
                meta["sample_id"], meta["grasp_id"] = sample, grasp
                meta["grasp_index"] = int(grasp.rsplit(".g", 1)[1])
                meta["grasp"]["record"] = f"../{grasp}/grasp.json"
                meta["grasp"]["sha256"] = sha256(out / grasp / "grasp.json")
                (out / sample / "meta.json").write_text(json.dumps(meta, indent=1))
                files = {name: file_entry(out / sample / name) for name in line["files"]}
                manifest.append({"sample_id": sample, "files": files})
    record["split"]["grasps"] = dict(sorted(split.items()))
    (out / "dataset.json").write_text(json.dumps(record, indent=2))
    head = [line for line in lines if "dataset" in line]
    for line in head:
        line["files"]["dataset.json"] = file_entry(out / "dataset.json")
    order = {"model": 0, "grasp_id": 1, "sample_id": 1}
    body = sorted(manifest, key=lambda m: next((order[k], m[k]) for k in order if k in m))
    text = "".join(json.dumps(line) + "\n" for line in head + body)
    (out / "manifest.jsonl").write_text(text)


def file_entry(path: Path) -> dict:
    media = "application/json" if path.suffix == ".json" else "application/octet-stream"
    return {"sha256": sha256(path), "size": path.stat().st_size, "media_type": media}


def command(layout: str, vintctl: Path, native: Path, out: Path) -> list[str]:
    if layout == "cp -r":
        return ["cp", "-r", str(native), str(out)]
    return [str(vintctl), "convert", str(native), "--out", str(out), "--format", layout]


def run_once(layout: str, vintctl: Path, native: Path, out: Path) -> float | None:
    """Seconds one run took, or None when it failed; `out` is removed first (untimed)."""
    shutil.rmtree(out, ignore_errors=True)
    # Start every run with no dirty pages: otherwise the writeback of earlier runs' output
    # throttles whichever run comes later (cp -r of 1200 samples went 0.8 s → 5.8 s over 5 runs).
    subprocess.run(["sync"], check=True)
    started = time.perf_counter()
    done = subprocess.run(command(layout, vintctl, native, out), capture_output=True, text=True)
    elapsed = time.perf_counter() - started
    if done.returncode != 0:
        print(f"export_formats: {layout} failed: {done.stderr.strip()[:300]}", file=sys.stderr)
        return None
    return elapsed


def smoke_dataset(vintctl: Path, scratch: Path) -> Path:
    """A native dataset of benches/smoke.toml, made with `vintctl run` under `scratch`."""
    out = scratch / "smoke"
    argv = [str(vintctl), "run", str(SMOKE_SPEC), "--out", str(out), "--state", str(scratch / "smoke-state")]
    done = subprocess.run(argv, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"export_formats: vintctl run {SMOKE_SPEC} failed:\n{done.stderr[-2000:]}")
    return out


def measure(name: str, native: Path, vintctl: Path, runs: int, scratch: Path) -> list[dict]:
    samples = sum(1 for line in (native / "manifest.jsonl").read_text().splitlines() if '"sample_id"' in line)
    if samples == 0:
        raise SystemExit(f"export_formats: {native} holds no sample")
    outs = {layout: scratch / f"{name}-{layout.replace(' ', '')}" for layout in LAYOUTS}
    working = [layout for layout in LAYOUTS if run_once(layout, vintctl, native, outs[layout]) is not None]
    times: dict[str, list[float]] = {layout: [] for layout in working}
    for _ in range(runs):
        for layout in working:
            elapsed = run_once(layout, vintctl, native, outs[layout])
            if elapsed is None:
                raise SystemExit(f"export_formats: {layout} failed after its warm-up")
            times[layout].append(elapsed)
    copy = statistics.median(times["cp -r"])
    rows = []
    for layout in LAYOUTS:
        row: dict = {"dataset": name, "samples": samples, "layout": layout}
        if layout in working:
            median = statistics.median(times[layout])
            size = du_bytes(outs[layout])
            row |= {"median_s": median, "runs_s": times[layout], "samples_per_s": samples / median}
            row |= {"vs_copy": median / copy, "bytes": size, "bytes_per_sample": size / samples}
        rows.append(row)
        shutil.rmtree(outs[layout], ignore_errors=True)
    return rows


def main() -> int:
    formatter = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=formatter)
    parser.add_argument("native", type=Path, nargs="?")
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--copies", type=int, default=20)
    parser.add_argument("--vintctl", type=Path, default=ROOT / "target" / "debug" / "vintctl")
    parser.add_argument("--smoke", action="store_true", help="1 run, 2 copies (seconds)")
    args = parser.parse_args()
    if args.smoke:
        args.runs, args.copies = 1, 2
    elif args.native is None:
        parser.error("NATIVE_DIR is required (without it only --smoke runs, on a dataset it makes)")

    rows: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="vint-export-bench-") as tmp:
        scratch = Path(tmp)
        native = args.native or smoke_dataset(args.vintctl, scratch)
        rows += measure(native.name, native, args.vintctl, args.runs, scratch)
        if args.copies > 1:
            big = scratch / f"{native.name}x{args.copies}"
            scale_native(native, big, args.copies)
            rows += measure(big.name, big, args.vintctl, args.runs, scratch)

    print("| dataset | samples | layout | median s | samples/s | time vs `cp -r` | bytes/sample |")
    print("|---|---:|---|---:|---:|---:|---:|")
    for r in rows:
        layout = "native (`cp -r`)" if r["layout"] == "cp -r" else r["layout"]
        if "median_s" not in r:
            print(f"| {r['dataset']} | {r['samples']} | {layout} | failed | | | |")
            continue
        print(
            f"| {r['dataset']} | {r['samples']} | {layout} | {r['median_s']:.3f} | "
            f"{r['samples_per_s']:.0f} | {r['vs_copy']:.2f} | {r['bytes_per_sample']:,.0f} |"
        )
    print(json.dumps({"runs": args.runs, "rows": rows}))
    return 0 if all("median_s" in r for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
