"""benches/dispatch_report.py's lineage check on a hand-made chain: a sample's chain as `vintctl
lineage --json` shows it passes, and each way it can be wrong is named (the dispatch smoke runs the
check on a real run; this holds that it can fail)."""

import copy
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benches"))
from dispatch_report import check_sample  # noqa: E402

SAMPLE = "mug.trx3.g000003.v01"


def artifact(store: Path, name: str, digest: str, size: int = 4) -> dict[str, Any]:
    path = store / "sha256" / digest[:2] / digest
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"x" * size)
    return {"name": name, "sha256": digest, "size": size}


def chain(store: Path) -> dict[str, Any]:
    grasps = artifact(store, "grasps.json", "1" * 64)
    depth = artifact(store, "v01_depth.npy", "2" * 64)
    noisy = artifact(store, "v01_depth_noisy.npy", "3" * 64)
    meta = artifact(store, f"{SAMPLE}/meta.json", "4" * 64)

    def task(stage: str, key: str, params: dict[str, Any], inputs: list[Any], outputs: list[Any]) -> Any:
        engine = {"mode": "timing-only"}
        return {"stage": stage, "key": key, "state": "succeeded", "engine": engine, "params": params,
                "inputs": inputs, "outputs": outputs}  # fmt: skip

    packaged = dict(noisy, name=f"{SAMPLE}/depth_noisy.npy")
    return {
        "tasks": [
            task("package", "package/mug/trx3/c00000", {}, [grasps, depth, noisy], [meta, packaged]),
            task("noise", "noise/mug/trx3/g000003", {}, [depth], [noisy]),
            task("render", "render/mug/trx3/g000003", {"grasp_index": 3}, [grasps], [depth]),
            task("grasp", "grasp/mug/trx3/c00000", {"trials": [{"grasp_index": 3}]}, [], [grasps]),
        ]
    }


def test_a_whole_chain_passes(tmp_path: Path) -> None:
    assert check_sample(SAMPLE, chain(tmp_path), tmp_path) == []


def test_each_fault_is_named(tmp_path: Path) -> None:
    good = chain(tmp_path)

    def fault(change: Any) -> list[str]:
        lineage = copy.deepcopy(good)
        change(lineage["tasks"])
        return check_sample(SAMPLE, lineage, tmp_path)

    def without_noise(t: list[Any]) -> None:
        del t[1]
        t[0]["inputs"] = t[0]["inputs"][:2]
        t[0]["outputs"] = t[0]["outputs"][:1]

    def foreign_grasp(t: list[Any]) -> None:
        t[1]["key"] = "noise/mug/trx3/g000004"

    def stray_input(t: list[Any]) -> None:
        t[2]["inputs"].append({"name": "x", "sha256": "9" * 64, "size": 1})

    def pixels_from_elsewhere(t: list[Any]) -> None:
        t[0]["outputs"][1]["sha256"] = "1" * 64

    def never_ran_the_trial(t: list[Any]) -> None:
        t[3]["params"]["trials"] = [{"grasp_index": 4}]

    assert fault(lambda t: t.reverse())[0].startswith("stages")
    assert any("noise/mug/trx3/g000004 is not grasp 3's noise task" in p for p in fault(foreign_grasp))
    assert any("reads ['x']" in p for p in fault(stray_input))
    assert any("is not an artifact of its grasp's own tasks" in p for p in fault(pixels_from_elsewhere))
    assert any("did not run trial 3" in p for p in fault(never_ran_the_trial))
    no_middle = {"tasks": good["tasks"][:1] + good["tasks"][3:]}
    assert check_sample(SAMPLE, no_middle, tmp_path)[0].startswith("stages")
    assert fault(without_noise) == [], "a job without noisy depth has its render task alone between"
