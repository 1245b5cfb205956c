"""Touch against geometry: in every grasp of a native dataset, do the taxels that touch the object
fire, and do the taxels that fire touch it?

Reads only the dataset's files: each `<grasp_id>/grasp.json` (the links' world poses
`trial.link_poses`, the object's `trial.object_pose`, one reading per taxel `touch.readings`, and
the layout it cites, `hand.taxels`: a path under the catalog and its SHA-256), the catalog's layout
file of that hash, and the object's exported model the record names (`object.model.file`, e.g.
`../models/mug.ply`, in the `units` and `frame` it states: millimetres, the object's frame).
Every taxel of the layout, moved by the hand instance's placement deviation the record states
(`touch.position_offsets_um`, whole micrometres in the link's frame; none in records older than
the deviations), is placed with its link's recorded pose and its signed distance to the
model at the recorded object pose is measured here (closest point on the triangles; the sign from
the winding number), with no code of the engine that wrote the dataset.

- recall: the share of taxels within NEAR_M of the surface or inside it that read > 0;
- precision: the share of taxels reading > 0 that lie within TOUCH_M of the surface or inside it;
- palm: in every power grasp (`physics.grasp_type`), some taxel of the layout's `palm` link reads > 0
  and lies within TOUCH_M of the surface (the object rests on the palm, and the palm feels it);
- back: no grasp presses the object with the back of a link: MuJoCo's contacts the record keeps
  (`touch.contact_samples`, points in the link's frame) are judged against the link's own geoms in
  the record (`hand.links`): a finger link's back is the side away from the palm (link -x, the
  built-in hands' convention), behind its capsule's axis by more than BACK_FRACTION of its radius
  and short of its end cap; the palm's back is its -z half. A link whose mean force there over the
  samples exceeds ACTIVATION_N fails the grasp.

Usage: check_touch_recall.py DIR [--catalog CATALOG_DIR]. Prints one JSON line; exits 1 when
recall < MIN_RECALL, precision < MIN_PRECISION, a power grasp's palm feels nothing or a grasp
presses with a link's back, 2 on a dataset it cannot read.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import trimesh

Array = npt.NDArray[np.float64]

NEAR_M = 3e-4  # a taxel this close to the surface (or inside it) touches
TOUCH_M = 5e-4  # an active taxel this close to the surface (or inside it) is in contact
REACH_M = 2e-3  # distances beyond this are not needed: such a taxel neither touches nor counts as in contact
MIN_RECALL = 0.90
MIN_PRECISION = 0.95
PALM_LINK = "palm"  # the built-in hands' palm link (the layout's `link` column)
ACTIVATION_N = 0.2  # the FSR's actuation force: a back contact above it would have been felt
BACK_FRACTION = 0.5  # behind the axis by this share of the radius: clear of the link's sides
CATALOG = Path(__file__).resolve().parents[2] / "catalog"


class Unreadable(Exception):
    """The dataset lacks a file or field this check needs."""


def rotation(q: list[float]) -> Array:
    """Rotation matrix of a unit quaternion (w, x, y, z)."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def read_layout(path: Path) -> tuple[list[str], Array]:
    """Each taxel's link and position in the link's frame (m), in taxel order."""
    with path.open(newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    if [int(r["taxel"]) for r in rows] != list(range(len(rows))):
        raise Unreadable(f"{path}: taxels are not numbered 0, 1, 2, …")
    return [r["link"] for r in rows], np.array([[float(r[k]) for k in "xyz"] for r in rows])


def layout_of(grasp: dict[str, Any], catalog: Path) -> tuple[list[str], Array]:
    info = grasp["hand"]["taxels"]
    path = catalog / info["layout"]
    if not path.is_file() or hashlib.sha256(path.read_bytes()).hexdigest() != info["sha256"]:
        raise Unreadable(f"the layout {info['layout']} with SHA-256 {info['sha256']} is not in {catalog}")
    links, positions = read_layout(path)
    if len(links) != info["count"] or len(grasp["touch"]["readings"]) != len(links):
        raise Unreadable(f"{info['layout']}: {len(links)} taxels, the record counts {info['count']}")
    offsets = np.asarray(
        grasp["touch"].get("position_offsets_um", np.zeros((len(links), 3))), dtype=np.float64
    )
    if offsets.shape != positions.shape:
        raise Unreadable(
            f"touch.position_offsets_um: shape {offsets.shape}, the layout has {len(links)} taxels"
        )
    return links, positions + offsets * 1e-6


def taxels_in_object_frame(links: list[str], positions: Array, trial: dict[str, Any]) -> Array:
    """Each taxel placed with its link's recorded world pose, then taken into the object's frame (m)."""
    world = np.empty_like(positions)
    for link in set(links):
        rows = [i for i, name in enumerate(links) if name == link]
        pose = trial["link_poses"][link]
        world[rows] = positions[rows] @ rotation(pose["q"]).T + np.asarray(pose["p"])
    obj = trial["object_pose"]
    return (world - np.asarray(obj["p"])) @ rotation(obj["q"])


def winding_numbers(points: Array, triangles: Array) -> Array:
    """Generalised winding number of a closed, outward-wound triangle mesh at each point (1 inside,
    0 outside): the solid angles of the triangles (Van Oosterom and Strackee, 1983) over 4π."""
    a, b, c = (triangles[None, :, k, :] - points[:, None, :] for k in range(3))
    la, lb, lc = (np.linalg.norm(v, axis=2) for v in (a, b, c))
    det = np.einsum("ptk,ptk->pt", a, np.cross(b, c))
    dots = (
        la * lb * lc
        + np.einsum("ptk,ptk->pt", a, b) * lc
        + np.einsum("ptk,ptk->pt", b, c) * la
        + np.einsum("ptk,ptk->pt", c, a) * lb
    )
    return 2.0 * np.arctan2(det, dots).sum(axis=1) / (4.0 * np.pi)


def signed_distances(points: Array, mesh: trimesh.Trimesh) -> Array:
    """Signed distance (m, negative inside) of each point to the mesh, exact where |d| < REACH_M,
    ±REACH_M further in or out near the mesh, and +inf for points outside its inflated bounds."""
    triangles = np.asarray(mesh.triangles)
    low, high = triangles.min(axis=1) - REACH_M, triangles.max(axis=1) + REACH_M
    distance = np.full(len(points), np.inf)
    box_low, box_high = low.min(axis=0), high.max(axis=0)
    candidates = np.flatnonzero(((points >= box_low) & (points <= box_high)).all(axis=1))
    for i in candidates:
        near = np.flatnonzero(((points[i] >= low) & (points[i] <= high)).all(axis=1))
        inside = winding_numbers(points[i : i + 1], triangles)[0] > 0.5
        if len(near):
            closest = trimesh.triangles.closest_point(
                triangles[near], np.repeat(points[i : i + 1], len(near), 0)
            )
            unsigned = float(np.linalg.norm(closest - points[i], axis=1).min())
        else:
            unsigned = REACH_M  # at least this far from every triangle
        distance[i] = -unsigned if inside else unsigned
    return distance


def read_model(grasp_dir: Path, model: dict[str, Any]) -> trimesh.Trimesh:
    """The model file a grasp record names, in metres."""
    path = (grasp_dir / model["file"]).resolve()
    if not path.is_file():
        raise Unreadable(f"no model {path}")
    if model.get("units") != "mm":
        raise Unreadable(f"{path}: units {model.get('units')!r}, expected mm")
    mesh = trimesh.load(path, process=False, force="mesh")
    mesh.apply_scale(1e-3)
    return mesh


def check_grasp(
    grasp: dict[str, Any], grasp_dir: Path, catalog: Path, meshes: dict[Path, trimesh.Trimesh]
) -> dict[str, Any]:
    links, positions = layout_of(grasp, catalog)
    model = grasp["object"]["model"]
    key = (grasp_dir / model["file"]).resolve()
    if key not in meshes:
        meshes[key] = read_model(grasp_dir, model)
    distance = signed_distances(taxels_in_object_frame(links, positions, grasp["trial"]), meshes[key])
    active = np.asarray(grasp["touch"]["readings"], dtype=np.float64) > 0.0
    near = distance <= NEAR_M
    palm = np.array([link == PALM_LINK for link in links])
    return {
        "power": grasp["physics"].get("grasp_type") == "power",
        "palm_feeling": int((palm & active & (distance <= TOUCH_M)).sum()),
        "near": int(near.sum()),
        "near_active": int((near & active).sum()),
        "active": int(active.sum()),
        "active_touching": int((active & (distance <= TOUCH_M)).sum()),
        "missed": [
            {"taxel": int(i), "link": links[i], "distance_mm": 1e3 * float(distance[i])}
            for i in np.flatnonzero(near & ~active)
        ],
    }


def on_back(link: dict[str, Any], p: Array) -> bool:
    """Whether the link-frame point `p` is on the back of `link`, from the record's geoms."""
    if link["name"] == PALM_LINK:
        return bool(p[2] < 0.0)
    capsules = [g for g in link["geoms"] if g["type"] == "capsule"]
    if not capsules:
        return False  # not a built-in finger link: no convention for its back
    radius, half = capsules[0]["size"]
    end = capsules[0]["p"][2] + half  # the fingertip's end cap is sensorised all round
    return bool(p[2] <= end and p[0] < -BACK_FRACTION * radius)


def back_forces(grasp: dict[str, Any]) -> dict[str, float]:
    """Mean normal force (N) on the back of each link over the record's contact samples."""
    links = {link["name"]: link for link in grasp["hand"]["links"]}
    samples = grasp["touch"]["contact_samples"]
    forces: dict[str, float] = {}
    for contacts in samples:
        for c in contacts:
            if on_back(links[c["link"]], np.asarray(c["p_link"], dtype=np.float64)):
                forces[c["link"]] = forces.get(c["link"], 0.0) + c["force_n"] / len(samples)
    return forces


def ratio(part: int, whole: int) -> float:
    return part / whole if whole else 1.0


def main(root: Path, catalog: Path) -> int:
    meshes: dict[Path, trimesh.Trimesh] = {}
    totals = {"grasps": 0, "near": 0, "near_active": 0, "active": 0, "active_touching": 0}
    worst: list[dict[str, Any]] = []
    power = 0
    numb_palms: list[str] = []  # power grasps whose palm feels nothing
    pressed_backs: list[dict[str, Any]] = []  # grasps pressing the object with a link's back
    try:
        for path in sorted(root.glob("*/grasp.json")):
            grasp = json.loads(path.read_text(encoding="utf-8"))
            result = check_grasp(grasp, path.parent, catalog, meshes)
            totals["grasps"] += 1
            for key in ("near", "near_active", "active", "active_touching"):
                totals[key] += result[key]
            if result["power"]:
                power += 1
                if result["palm_feeling"] == 0:
                    numb_palms.append(path.parent.name)
            backs = {link: f for link, f in back_forces(grasp).items() if f > ACTIVATION_N}
            if backs:
                pressed_backs.append({"grasp": path.parent.name, "back_force_n": backs})
            worst.append(
                {
                    "grasp": path.parent.name,
                    "recall": ratio(result["near_active"], result["near"]),
                    "near": result["near"],
                    "missed": result["missed"][:3],
                }
            )
    except (Unreadable, KeyError, ValueError, OSError) as error:
        print(f"check_touch_recall: {root}: {error!r}", file=sys.stderr)
        return 2
    if totals["grasps"] == 0 or totals["active"] == 0:
        print(f"check_touch_recall: no grasp with active taxels under {root}", file=sys.stderr)
        return 2
    recall = ratio(totals["near_active"], totals["near"])
    precision = ratio(totals["active_touching"], totals["active"])
    worst.sort(key=lambda g: g["recall"])
    report = {
        **totals,
        "recall": recall,
        "precision": precision,
        "near_m": NEAR_M,
        "touch_m": TOUCH_M,
        "power_grasps": power,
        "power_grasps_with_numb_palm": numb_palms,
        "grasps_pressing_with_a_back": pressed_backs,
        "worst_grasps": worst[:3],
    }
    print(json.dumps(report))
    passed = recall >= MIN_RECALL and precision >= MIN_PRECISION and not numb_palms and not pressed_backs
    return 0 if passed else 1


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--catalog", type=Path, default=CATALOG)
    args = parser.parse_args()
    sys.exit(main(args.dataset, args.catalog))
