"""Check a BOP export of a vint dataset geometrically, independently of the code that wrote it.

    check_bop.py DIR        exit 0 and a JSON summary on stdout, or exit 1 and every failure on stderr

It loads the export the way the BOP toolkit's readers do (`inout.load_json(keys_to_int=True)`,
`load_scene_camera`, `load_scene_gt`, `load_depth`, `load_ply`: integer keys, 3×3 and 3×1 arrays,
uint16 depth PNGs, binary PLYs of the property types that reader knows) and then, with nothing
shared with the writer:

- re-projects each model PLY with cam_K, cam_R_m2c and cam_t_m2c through its own z-buffer
  (pixel centres on integer coordinates, OpenCV axes: docs/rendering.md) and compares the result
  with depth/ × depth_scale on the visible-mask pixels and with the silhouette in mask/;
- recomputes scene_gt_info from the masks (and px_count_valid from depth/);
- checks models_eval/: every vertex on the models/ surface, no two closer than the spacing
  dataset.json states, every point of the surface (drawn uniformly here) within 1.25 spacings of
  one, the triangles wound outward around nearly the model's volume, normals and models_info
  measured on that file;
- checks the models: watertight and consistently wound, outward, in millimetres, diameter and
  extents equal to models_info.json's and dataset.json's, and their vertex normals (every BOP model
  has them) equal to the angle-weighted sums of the incident triangles' normals computed here;
- checks that every per-image file and folder of a scene lists the same images, and the scene ids
  against dataset.json's grasps and split;
- decodes scene_gt_coco.json's RLE masks itself (column-major runs, as pycocotools lays them) and
  compares each with mask_visib/, its bbox with mask/'s (COCO's pixel-counting width), its area,
  category, image and ignore flag with scene_gt and scene_gt_info;
- loads camera.json as `inout.load_cam_params` does and compares it with the images' cam_K, and
  enumerates the test targets by the toolkit's rules from scene_gt and scene_gt_info (BOP 19: per
  test image, each object with instances at least 10 % visible and their count; BOP 24: every test
  image), comparing them with test_targets_bop19.json and test_targets_bop24.json;
- takes each active taxel's p_cam_mm back into the model frame with the ground-truth pose and
  measures its distance to the model surface (the touch frames, checked through the camera).
"""

from __future__ import annotations

import json
import struct
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]

DEPTH_MEDIAN_MM = 1.0  # the bound on the median |rendered - exported| depth
MASK_IOU = 0.98  # rendered silhouette vs mask/, pixels on the rendered boundary left out
TOUCH_SURFACE_MM = (
    2.0  # taxels lie within the skin's contact margin of the collision surface (tiny: < 0.6 mm)
)
MODEL_MM = 0.01  # models_info / dataset.json / the PLY itself
PLAUSIBLE_EXTENT_MM = (5.0, 500.0)  # a hand-held object, in mm (metres would be < 1, µm > 5000)
PLY_TYPES = {"float": ("f", 4), "double": ("d", 8), "int": ("i", 4), "uchar": ("B", 1)}  # load_ply's
SCENE_FILES = ("scene_camera", "scene_gt", "scene_gt_info", "scene_touch", "scene_hand", "scene_meta")
IMAGE_FOLDERS = ("rgb", "depth", "depth_noisy", "segmentation")
MASK_FOLDERS = ("mask", "mask_visib")


class Failures:
    def __init__(self) -> None:
        self.messages: list[str] = []

    def check(self, ok: bool, message: str) -> bool:
        if not ok:
            self.messages.append(message)
        return ok


# --- loading, as the toolkit's readers do --------------------------------------------------------


def load_json(path: Path, keys_to_int: bool = False) -> Any:
    def to_int(pairs: dict[str, Any]) -> dict[Any, Any]:
        return {int(k) if k.lstrip("-").isdigit() else k: v for k, v in pairs.items()}

    with path.open() as f:
        return json.load(f, object_hook=to_int) if keys_to_int else json.load(f)


def load_scene_camera(path: Path) -> dict[int, dict[str, Any]]:
    cameras = load_json(path, keys_to_int=True)
    for cam in cameras.values():
        cam["cam_K"] = np.array(cam["cam_K"], np.float64).reshape(3, 3)
        cam["cam_R_w2c"] = np.array(cam["cam_R_w2c"], np.float64).reshape(3, 3)
        cam["cam_t_w2c"] = np.array(cam["cam_t_w2c"], np.float64).reshape(3, 1)
    return cameras


def load_scene_gt(path: Path) -> dict[int, list[dict[str, Any]]]:
    gts = load_json(path, keys_to_int=True)
    for im_gts in gts.values():
        for gt in im_gts:
            gt["cam_R_m2c"] = np.array(gt["cam_R_m2c"], np.float64).reshape(3, 3)
            gt["cam_t_m2c"] = np.array(gt["cam_t_m2c"], np.float64).reshape(3, 1)
    return gts


def load_png(path: Path) -> npt.NDArray[Any]:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError(f"{path}: not a readable image")
    return image


def load_ply(path: Path) -> tuple[Array, npt.NDArray[np.int64]]:
    """Vertices and triangles of a binary little-endian PLY, accepting only what `load_ply` reads."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    if "format binary_little_endian 1.0" not in header:
        raise ValueError(f"{path}: not binary little-endian")
    elements: list[tuple[str, int, list[list[str]]]] = []
    for line in header:
        words = line.split()
        if words[:1] == ["element"]:
            elements.append((words[1], int(words[2]), []))
        elif words[:1] == ["property"]:
            elements[-1][2].append(words[1:])
    offset, vertices, faces = end, np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    for name, count, props in elements:
        if name == "vertex":
            kinds = [p[0] for p in props]
            if any(k not in PLY_TYPES for k in kinds) or [p[1] for p in props][:3] != ["x", "y", "z"]:
                raise ValueError(f"{path}: vertex properties {props} are not what load_ply reads")
            fmt = "<" + "".join(PLY_TYPES[k][0] for k in kinds)
            size = struct.calcsize(fmt)
            rows = [struct.unpack_from(fmt, data, offset + i * size) for i in range(count)]
            vertices = np.array([r[:3] for r in rows], np.float64)
            offset += count * size
        elif name == "face":
            if props != [["list", "uchar", "int", "vertex_indices"]]:
                raise ValueError(f"{path}: face properties {props} are not what load_ply reads")
            record = np.dtype([("n", "u1"), ("i", "<i4", (3,))])
            table = np.frombuffer(data, record, count, offset)
            if np.any(table["n"] != 3):
                raise ValueError(f"{path}: only triangles are supported")
            faces = table["i"].astype(np.int64)
            offset += count * record.itemsize
        else:
            raise ValueError(f"{path}: unexpected element {name}")
    return vertices, faces


# --- geometry ------------------------------------------------------------------------------------


def ply_normals(path: Path) -> Array | None:
    """The vertex normals (nx, ny, nz) of a binary little-endian PLY of float vertex properties."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    names: list[str] = []
    count = 0
    for line in header:
        words = line.split()
        if words[:2] == ["element", "vertex"]:
            count = int(words[2])
        elif words[:1] == ["element"] and count:
            break
        elif words[:2] == ["property", "float"] and count:
            names.append(words[2])
    if not {"nx", "ny", "nz"} <= set(names):
        return None
    table = np.frombuffer(data, np.dtype([(n, "<f4") for n in names]), count, end)
    return np.stack([table["nx"], table["ny"], table["nz"]], axis=1).astype(np.float64)


def angle_weighted_normals(vertices: Array, faces: npt.NDArray[np.int64]) -> Array:
    """Each vertex's normal: the incident triangles' unit normals weighted by the triangle's angle
    at the vertex (Thürrner and Wüthrich 1998, as MeshLab computes the BOP models'), normalized."""
    tri = vertices[faces]
    face_n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    face_n /= np.maximum(np.linalg.norm(face_n, axis=1, keepdims=True), 1e-30)
    normals = np.zeros_like(vertices)
    for k in range(3):
        a = tri[:, (k + 1) % 3] - tri[:, k]
        b = tri[:, (k + 2) % 3] - tri[:, k]
        cos = np.einsum("ij,ij->i", a, b) / np.maximum(
            np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-30
        )
        np.add.at(normals, faces[:, k], face_n * np.arccos(np.clip(cos, -1.0, 1.0))[:, None])
    return normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)


def render_depth(
    vertices: Array, faces: npt.NDArray[np.int64], K: Array, R: Array, t: Array, shape: tuple[int, int]
) -> Array:
    """Z-buffer of the mesh: camera-frame z (mm) at each pixel centre, 0 where nothing is hit.
    Pixel (u, v) is the point u = fx·X/Z + cx, v = fy·Y/Z + cy (integer coordinates are centres)."""
    height, width = shape
    cam = vertices @ R.T + t.reshape(1, 3)
    z = cam[:, 2]
    uv = (cam @ K.T)[:, :2] / z[:, None]
    depth = np.full(shape, np.inf)
    for a, b, c in faces:
        if min(z[a], z[b], z[c]) <= 0:
            continue
        tri = uv[[a, b, c]]
        lo = np.maximum(np.ceil(tri.min(axis=0)).astype(int), 0)
        hi = np.minimum(np.floor(tri.max(axis=0)).astype(int), [width - 1, height - 1])
        if lo[0] > hi[0] or lo[1] > hi[1]:
            continue
        us, vs = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1))
        (x0, y0), (x1, y1), (x2, y2) = tri
        area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if abs(area) < 1e-12:
            continue
        w0 = ((x1 - us) * (y2 - vs) - (x2 - us) * (y1 - vs)) / area
        w1 = ((x2 - us) * (y0 - vs) - (x0 - us) * (y2 - vs)) / area
        w2 = 1.0 - w0 - w1
        inside = (w0 >= -1e-9) & (w1 >= -1e-9) & (w2 >= -1e-9)
        if not inside.any():
            continue
        # 1/z is affine in screen space (perspective-correct depth).
        zz = 1.0 / (w0 / z[a] + w1 / z[b] + w2 / z[c])
        view = depth[vs, us]
        nearer = inside & (zz < view)
        view[nearer] = zz[nearer]
        depth[vs, us] = view
    depth[np.isinf(depth)] = 0.0
    return depth


def bbox(mask: npt.NDArray[np.bool_]) -> list[int]:
    """The toolkit's calc_2d_bbox: [x_min, y_min, x_max - x_min, y_max - y_min]; -1s when empty."""
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return [-1, -1, -1, -1]
    return [int(xs.min()), int(ys.min()), int(xs.max() - xs.min()), int(ys.max() - ys.min())]


def boundary(mask: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    """Pixels whose 3×3 neighbourhood holds both inside and outside pixels."""
    kernel = np.ones((3, 3), np.uint8)
    m = mask.astype(np.uint8)
    return cv2.dilate(m, kernel).astype(bool) & ~cv2.erode(m, kernel, borderType=cv2.BORDER_REPLICATE).astype(
        bool
    )


def point_triangle_distance(p: Array, tris: Array) -> Array:
    """Distance from point p (3,) to each triangle (n, 3, 3): the closest point by region
    (vertex, edge or face), as in Ericson's Real-Time Collision Detection, 5.1.5."""
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(1), (ac * ap).sum(1)
    bp, cp = p - b, p - c
    d3, d4 = (ab * bp).sum(1), (ac * bp).sum(1)
    d5, d6 = (ab * cp).sum(1), (ac * cp).sum(1)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v_face, w_face = vb / denom, vc / denom
        closest = a + ab * v_face[:, None] + ac * w_face[:, None]
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    regions = [
        ((d1 <= 0) & (d2 <= 0), a),
        ((d3 >= 0) & (d4 <= d3), b),
        ((d6 >= 0) & (d5 <= d6), c),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + ab * t_ab[:, None]),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + ac * t_ac[:, None]),
        ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), b + (c - b) * t_bc[:, None]),
    ]
    done = np.zeros(len(tris), bool)
    for region, point in regions:
        take = region & ~done
        closest[take] = point[take]
        done |= take
    return np.linalg.norm(closest - p, axis=1)


def diameter(vertices: Array) -> float:
    best = 0.0
    for start in range(0, len(vertices), 256):
        chunk = vertices[start : start + 256]
        d = np.sqrt(((chunk[:, None, :] - vertices[None, :, :]) ** 2).sum(-1))
        best = max(best, float(d.max()))
    return best


# --- checks --------------------------------------------------------------------------------------


def check_models(
    root: Path, dataset: dict[str, Any], fail: Failures
) -> dict[int, tuple[Array, npt.NDArray[np.int64]]]:
    info = load_json(root / "models" / "models_info.json", keys_to_int=True)
    declared = {o["obj_id"]: o for o in dataset["objects"]}
    fail.check(
        set(info) == set(declared), f"models_info ids {sorted(info)} != dataset.json's {sorted(declared)}"
    )
    models = {}
    for obj_id, entry in sorted(info.items()):
        path = root / "models" / f"obj_{obj_id:06d}.ply"
        vertices, faces = load_ply(path)
        models[obj_id] = (vertices, faces)
        directed = {(int(a), int(b)) for f in faces for a, b in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0]))}
        fail.check(
            len(directed) == 3 * len(faces),
            f"{path.name}: a directed edge is used twice (inconsistent winding)",
        )
        fail.check(
            all((b, a) in directed for a, b in directed),
            f"{path.name}: an edge lacks its opposite (not watertight)",
        )
        normals = ply_normals(path)
        if fail.check(normals is not None, f"{path.name}: no vertex normals (nx, ny, nz)"):
            assert normals is not None
            dots = np.einsum("ij,ij->i", normals, angle_weighted_normals(vertices, faces))
            fail.check(
                float(dots.min()) >= 0.9999,
                f"{path.name}: vertex normals differ from the angle-weighted ones (min cos {dots.min():.6f})",
            )
        tri = vertices[faces]
        volume = float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0)
        fail.check(volume > 0, f"{path.name}: faces point inwards (signed volume {volume:.1f} mm³)")
        size = vertices.max(0) - vertices.min(0)
        d = diameter(vertices)
        lo, hi = PLAUSIBLE_EXTENT_MM
        fail.check(
            bool(np.all((size > lo) & (size < hi))),
            f"{path.name}: extent {size} mm is not a hand-held object's",
        )
        fail.check(
            abs(d - entry["diameter"]) <= MODEL_MM,
            f"{path.name}: diameter {d:.4f} != models_info {entry['diameter']}",
        )
        obj = declared.get(obj_id, {})
        fail.check(
            obj.get("model") == f"models/{path.name}",
            f"dataset.json names {obj.get('model')!r} for {path.name}",
        )
        fail.check(
            abs(d - obj.get("diameter_mm", -1)) <= MODEL_MM,
            f"{path.name}: diameter {d:.4f} != dataset.json {obj.get('diameter_mm')}",
        )
        written = np.array([entry[f"size_{a}"] for a in "xyz"])
        fail.check(
            bool(np.all(np.abs(written - size) <= MODEL_MM)),
            f"{path.name}: models_info size {written} != {size}",
        )
        mins = np.array([entry[f"min_{a}"] for a in "xyz"])
        fail.check(
            bool(np.all(np.abs(mins - vertices.min(0)) <= MODEL_MM)), f"{path.name}: models_info min {mins}"
        )
        extent = np.array(obj.get("extent_mm", [np.nan] * 3))
        fail.check(
            bool(np.all(np.abs(extent - size) <= MODEL_MM)),
            f"{path.name}: dataset.json extent {extent} != {size}",
        )
    return models


def surface_samples(vertices: Array, faces: npt.NDArray[np.int64], n: int, seed: int) -> Array:
    """n points drawn uniformly over the mesh's surface: a triangle by area, then a point uniformly in
    it (the square-root construction of Osada et al. 2002, "Shape distributions")."""
    rng = np.random.default_rng(seed)
    tri = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    pick = rng.choice(len(faces), size=n, p=area / area.sum())
    r1, r2 = np.sqrt(rng.random(n))[:, None], rng.random(n)[:, None]
    a, b, c = tri[pick, 0], tri[pick, 1], tri[pick, 2]
    return (1 - r1) * a + r1 * (1 - r2) * b + r1 * r2 * c


def nearest_distances(points: Array, to: Array, skip_self: bool = False) -> Array:
    """For each of `points`, the distance to the nearest of `to` (brute force, in chunks)."""
    out = np.empty(len(points))
    for start in range(0, len(points), 256):
        chunk = points[start : start + 256]
        d2 = ((chunk[:, None, :] - to[None, :, :]) ** 2).sum(-1)
        if skip_self:
            d2[np.arange(len(chunk)), np.arange(start, start + len(chunk))] = np.inf
        out[start : start + 256] = np.sqrt(d2.min(axis=1))
    return out


def check_models_eval(
    root: Path,
    dataset: dict[str, Any],
    models: dict[int, tuple[Array, npt.NDArray[np.int64]]],
    fail: Failures,
) -> dict[str, Any]:
    """models_eval/: per model, every vertex on the models/ surface, no two closer than the stated
    spacing r, every point of the surface (20,000 drawn uniformly here) within 1.25 r of one, the
    triangles wound outward around nearly the original volume, normals and models_info measured on
    this file, symmetries as models/'s."""
    folder = root / "models_eval"
    info = load_json(folder / "models_info.json", keys_to_int=True)
    info_models = load_json(root / "models" / "models_info.json", keys_to_int=True)
    stated = {o["obj_id"]: o for o in dataset.get("bop", {}).get("models_eval", {}).get("objects", [])}
    fail.check(set(info) == set(models), f"models_eval ids {sorted(info)} != models/ {sorted(models)}")
    fail.check(set(stated) == set(models), f"dataset.json states models_eval for {sorted(stated)}")
    worst: dict[str, Any] = {"on_surface_mm": 0.0, "min_spacing_over_r": np.inf, "max_gap_over_r": 0.0}
    worst["volume_ratio"] = []
    for obj_id, (model_v, model_f) in sorted(models.items()):
        path = folder / f"obj_{obj_id:06d}.ply"
        if not fail.check(path.is_file() and obj_id in stated and obj_id in info, f"{path}: missing"):
            continue
        vertices, faces = load_ply(path)
        r = float(stated[obj_id]["spacing_mm"])
        fail.check(
            len(vertices) == stated[obj_id]["points"],
            f"{path.name}: {len(vertices)} vertices, dataset.json states {stated[obj_id]['points']}",
        )
        tris = model_v[model_f]
        off = max(float(point_triangle_distance(p, tris).min()) for p in vertices)
        fail.check(off <= 1e-3, f"{path.name}: a vertex lies {off:.4f} mm off the model's surface")
        spacing = float(nearest_distances(vertices, vertices, skip_self=True).min())
        fail.check(spacing >= r - 1e-4, f"{path.name}: two vertices {spacing:.4f} mm apart, spacing {r}")
        gap = float(nearest_distances(surface_samples(model_v, model_f, 20_000, obj_id), vertices).max())
        fail.check(gap <= 1.25 * r + 1e-4, f"{path.name}: a surface point is {gap:.3f} mm from every vertex")
        tri = vertices[faces]
        volume = float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0)
        original = float(np.einsum("ij,ij->i", tris[:, 0], np.cross(tris[:, 1], tris[:, 2])).sum() / 6.0)
        fail.check(
            abs(volume / original - 1) < 0.1,
            f"{path.name}: the triangles enclose {volume:.0f} mm³, the model {original:.0f} mm³",
        )
        normals = ply_normals(path)
        if fail.check(normals is not None, f"{path.name}: no vertex normals (nx, ny, nz)"):
            assert normals is not None
            used = np.unique(faces)
            dots = np.einsum("ij,ij->i", normals[used], angle_weighted_normals(vertices, faces)[used])
            fail.check(
                float(dots.min()) >= 0.9999, f"{path.name}: vertex normals are not the angle-weighted ones"
            )
        entry = info[obj_id]
        fail.check(
            abs(diameter(vertices) - entry["diameter"]) <= MODEL_MM,
            f"{path.name}: diameter != models_eval/models_info {entry['diameter']}",
        )
        size = vertices.max(0) - vertices.min(0)
        written = np.array([entry[f"size_{a}"] for a in "xyz"])
        fail.check(bool(np.all(np.abs(written - size) <= MODEL_MM)), f"{path.name}: size {written} != {size}")
        for key in ("symmetries_continuous", "symmetries_discrete"):
            fail.check(
                entry.get(key) == info_models[obj_id].get(key),
                f"{path.name}: {key} differs from models/models_info.json's",
            )
        worst["on_surface_mm"] = max(worst["on_surface_mm"], off)
        worst["min_spacing_over_r"] = min(worst["min_spacing_over_r"], spacing / r)
        worst["max_gap_over_r"] = max(worst["max_gap_over_r"], gap / r)
        worst["volume_ratio"].append(round(volume / original, 4))
    return worst


def check_scene_ids(root: Path, dataset: dict[str, Any], fail: Failures) -> list[tuple[str, int, str]]:
    """(split, scene_id, grasp_id) of every scene: ids are the grasps' ordinals in sorted order."""
    grasps = sorted(dataset["split"]["grasps"])
    folders = sorted(
        (int(d.name), d.parent.name)
        for split in ("train", "val", "test")
        for d in (root / split).glob("*")
        if d.is_dir()
    )
    fail.check(
        [s for s, _ in folders] == list(range(len(grasps))),
        f"scene ids {[s for s, _ in folders]} are not 0..{len(grasps) - 1}",
    )
    listed = {s["scene_id"]: s for s in dataset["bop"]["scenes"]}
    scenes = []
    for scene_id, split in folders:
        grasp = grasps[scene_id] if scene_id < len(grasps) else "?"
        fail.check(
            listed.get(scene_id, {}).get("grasp_id") == grasp,
            f"dataset.json maps scene {scene_id} to {listed.get(scene_id)}, expected {grasp}",
        )
        fail.check(
            dataset["split"]["grasps"].get(grasp) == split, f"scene {scene_id} ({grasp}) is in {split}/"
        )
        scenes.append((split, scene_id, grasp))
    return scenes


def scene_im_ids(scene: Path, fail: Failures) -> list[int]:
    """The images of a scene, checked to be the same in every per-image file and folder."""
    sets = {name: set(load_json(scene / f"{name}.json", keys_to_int=True)) for name in SCENE_FILES}
    for folder in IMAGE_FOLDERS:
        if (scene / folder).is_dir():
            sets[folder] = {int(p.stem) for p in (scene / folder).glob("*.png")}
    for folder in MASK_FOLDERS:
        sets[folder] = {int(p.stem.split("_")[0]) for p in (scene / folder).glob("*_000000.png")}
    reference = sets["scene_gt"]
    for name, ids in sets.items():
        fail.check(
            ids == reference, f"{scene}: {name} lists images {sorted(ids)}, scene_gt {sorted(reference)}"
        )
    return sorted(reference)


def mask_png(path: Path, fail: Failures) -> npt.NDArray[np.bool_]:
    image = load_png(path)
    fail.check(image.dtype == np.uint8 and image.ndim == 2, f"{path}: not an 8-bit single-channel mask")
    fail.check(bool(np.isin(image, (0, 255)).all()), f"{path}: values other than 0 and 255")
    return image > 0


def check_image(
    scene: Path, im: int, ctx: dict[str, Any], fail: Failures, stats: dict[str, list[float]]
) -> None:
    where = f"{scene.parent.name}/{scene.name} im {im}"
    cam, gt, info = ctx["camera"][im], ctx["gt"][im], ctx["gt_info"][im]
    fail.check(len(gt) == 1 and len(info) == 1, f"{where}: expected one object instance")
    gt, info = gt[0], info[0]
    R, t, K = gt["cam_R_m2c"], gt["cam_t_m2c"], cam["cam_K"]
    if np.any(cam.get("cam_dist", [])):
        # A distorted view's images are not a pinhole's of cam_K (its cam_dist says how): this
        # check's z-buffer renders a pinhole, so it cannot vouch for them.
        fail.check(
            False, f"{where}: cam_dist: a distorted image, which this pinhole z-buffer cannot re-render"
        )
        return
    fail.check(
        np.allclose(R @ R.T, np.eye(3), atol=1e-6) and np.linalg.det(R) > 0,
        f"{where}: cam_R_m2c is not a rotation",
    )
    depth_raw = load_png(scene / "depth" / f"{im:06d}.png")
    fail.check(depth_raw.dtype == np.uint16 and depth_raw.ndim == 2, f"{where}: depth is not uint16")
    depth = depth_raw.astype(np.float32) * cam["depth_scale"]  # load_depth, then × depth_scale = mm
    full = mask_png(scene / "mask" / f"{im:06d}_000000.png", fail)
    visib = mask_png(scene / "mask_visib" / f"{im:06d}_000000.png", fail)
    rgb = load_png(scene / "rgb" / f"{im:06d}.png") if (scene / "rgb").is_dir() else None
    shape = depth.shape
    fail.check(rgb is None or rgb.shape[:2] == shape, f"{where}: rgb and depth sizes differ")
    fail.check(full.shape == shape == visib.shape, f"{where}: mask and depth sizes differ")
    fail.check(
        not np.any(visib & ~full), f"{where}: {int(np.sum(visib & ~full))} mask_visib pixels outside mask"
    )

    vertices, faces = ctx["models"][gt["obj_id"]]
    rendered = render_depth(vertices, faces, K, R, t, shape)
    hit = rendered > 0
    edge = boundary(hit)
    inner = ~edge
    union = np.sum((hit | full) & inner)
    iou = float(np.sum(hit & full & inner) / union) if union else 1.0
    raw_union = np.sum(hit | full)
    stats["iou"].append(iou)
    stats["iou_raw"].append(float(np.sum(hit & full) / raw_union) if raw_union else 1.0)
    fail.check(iou >= MASK_IOU, f"{where}: rendered silhouette vs mask IoU {iou:.4f} < {MASK_IOU}")
    compare = visib & hit & (depth > 0)
    if compare.any():
        error = np.abs(rendered[compare] - depth[compare])
        stats["depth_median"].append(float(np.median(error)))
        stats["depth_all"].extend(error.tolist())
        fail.check(
            float(np.median(error)) <= DEPTH_MEDIAN_MM,
            f"{where}: median depth error {np.median(error):.3f} mm",
        )

    expected = {
        "bbox_obj": bbox(full),
        "bbox_visib": bbox(visib),
        "px_count_all": int(full.sum()),
        "px_count_visib": int(visib.sum()),
        "px_count_valid": int(np.sum(full & (depth_raw > 0))),
    }
    for key, value in expected.items():
        fail.check(
            info.get(key) == value, f"{where}: scene_gt_info {key} {info.get(key)} != {value} from the masks"
        )
    fract = expected["px_count_visib"] / expected["px_count_all"] if expected["px_count_all"] else 0.0
    fail.check(
        abs(info.get("visib_fract", -1) - fract) < 1e-9,
        f"{where}: visib_fract {info.get('visib_fract')} != {fract}",
    )

    check_touch(where, ctx["touch"][im], vertices[faces], R, t, fail, stats)


def check_touch(
    where: str,
    touch: dict[str, Any],
    tris: Array,
    R: Array,
    t: Array,
    fail: Failures,
    stats: dict[str, list[float]],
) -> None:
    """p_cam_mm back in the model frame (x_m = Rᵀ(x_c - t)) lies on the model's surface."""
    for taxel in touch["active"]:
        p_model = R.T @ (np.asarray(taxel["p_cam_mm"], np.float64) - t.ravel())
        d = float(point_triangle_distance(p_model, tris).min())
        stats["touch_mm"].append(d)
        fail.check(
            d <= TOUCH_SURFACE_MM, f"{where}: taxel {taxel['taxel']} is {d:.2f} mm from the model surface"
        )
        fail.check(
            abs(np.linalg.norm(taxel["n_cam"]) - 1) < 1e-6,
            f"{where}: taxel {taxel['taxel']} n_cam is not unit",
        )
    fail.check(isinstance(touch.get("readings"), list), f"{where}: scene_touch has no readings vector")


def rle_decode(rle: dict[str, Any]) -> npt.NDArray[np.bool_]:
    """An uncompressed COCO RLE ({counts, size: [h, w]}) as a boolean [h, w] mask."""
    h, w = rle["size"]
    flat = np.zeros(h * w, bool)
    at, value = 0, False
    for run in rle["counts"]:
        flat[at : at + run] = value
        at, value = at + run, not value
    if at != h * w:
        raise ValueError(f"RLE runs cover {at} pixels of {h * w}")
    return flat.reshape((w, h)).T  # column-major


def check_coco(scene: Path, ids: list[int], ctx: dict[str, Any], fail: Failures) -> int:
    """scene_gt_coco.json against the masks and the ground truth; returns the annotations checked."""
    path = scene / "scene_gt_coco.json"
    if not fail.check(path.is_file(), f"{scene}: no scene_gt_coco.json"):
        return 0
    coco = load_json(path)
    fail.check(
        [i["id"] for i in coco["images"]] == ids, f"{path}: images {[i['id'] for i in coco['images']]}"
    )
    fail.check(
        {c["id"] for c in coco["categories"]} >= set(ctx["models"]), f"{path}: categories lack an object"
    )
    by_image = {a["image_id"]: a for a in coco["annotations"]}
    fail.check(len(by_image) == len(coco["annotations"]), f"{path}: two annotations of one image")
    fail.check(
        sorted(a["id"] for a in coco["annotations"]) == list(range(1, len(coco["annotations"]) + 1)),
        f"{path}: annotation ids are not 1..n",
    )
    for im in ids:
        visib = mask_png(scene / "mask_visib" / f"{im:06d}_000000.png", fail)
        full = mask_png(scene / "mask" / f"{im:06d}_000000.png", fail)
        a = by_image.get(im)
        if not fail.check(a is not None or not visib.any(), f"{path}: image {im} has no annotation"):
            continue
        if a is None:
            continue
        where = f"{path} image {im}"
        decoded = rle_decode(a["segmentation"])
        fail.check(
            decoded.shape == visib.shape and bool(np.all(decoded == visib)), f"{where}: mask != mask_visib"
        )
        rows, cols = np.where(full)
        box = [
            int(cols.min()),
            int(rows.min()),
            int(cols.max() - cols.min() + 1),
            int(rows.max() - rows.min() + 1),
        ]
        fail.check(a["bbox"] == box, f"{where}: bbox {a['bbox']} != mask's {box}")
        fail.check(a["area"] == int(visib.sum()), f"{where}: area {a['area']} != {int(visib.sum())}")
        fail.check(a["category_id"] == ctx["gt"][im][0]["obj_id"], f"{where}: category {a['category_id']}")
        fail.check(a["iscrowd"] == 0, f"{where}: iscrowd")
        fail.check(
            a["ignore"] == (ctx["gt_info"][im][0]["visib_fract"] < 0.1), f"{where}: ignore {a['ignore']}"
        )
    return len(by_image)


def check_dataset_files(
    root: Path,
    cameras: list[dict[str, Any]],
    test_images: list[tuple[int, int, list[Any], list[Any]]],
    fail: Failures,
) -> dict[str, Any]:
    """camera.json against the images' cameras; the test targets, enumerated here from
    (scene_id, im_id, scene_gt entries, scene_gt_info entries) of each test image."""
    c = load_json(root / "camera.json")
    k = np.array([[c["fx"], 0.0, c["cx"]], [0.0, c["fy"], c["cy"]], [0.0, 0.0, 1.0]])  # load_cam_params
    ks = np.array([np.reshape(cam["cam_K"], (3, 3)) for cam in cameras])
    median = np.median(ks, axis=0)
    fail.check(
        np.allclose(k, median, atol=1e-6), f"camera.json K {k.tolist()} is not the images' {median.tolist()}"
    )
    sizes = {(cam["width"], cam["height"]) for cam in cameras}
    fail.check(sizes == {(c["width"], c["height"])}, f"camera.json size vs the images' {sizes}")
    fail.check(c["depth_scale"] == cameras[0]["depth_scale"], "camera.json depth_scale")
    bop19 = []
    for scene_id, im_id, gts, infos in sorted(test_images, key=lambda t: (t[0], t[1])):
        counts: dict[int, int] = {}
        for gt, info in zip(gts, infos, strict=True):
            if info["visib_fract"] >= 0.1:
                counts[gt["obj_id"]] = counts.get(gt["obj_id"], 0) + 1
        bop19 += [
            {"im_id": im_id, "inst_count": n, "obj_id": obj_id, "scene_id": scene_id}
            for obj_id, n in sorted(counts.items())
        ]
    bop24 = [{"im_id": im, "scene_id": s} for s, im, _, _ in sorted(test_images, key=lambda t: (t[0], t[1]))]
    written19 = load_json(root / "test_targets_bop19.json")
    written24 = load_json(root / "test_targets_bop24.json")
    fail.check(written19 == bop19, f"test_targets_bop19.json: {written19[:3]}…, enumerated {bop19[:3]}…")
    fail.check(written24 == bop24, f"test_targets_bop24.json: {written24[:3]}…, enumerated {bop24[:3]}…")
    return {"bop19": len(bop19), "bop24": len(bop24), "test_images": len(test_images)}


def check(root: Path) -> tuple[dict[str, Any], list[str]]:
    fail = Failures()
    dataset = load_json(root / "dataset.json")
    fail.check(dataset.get("format") == "vint-bop", f"dataset.json format {dataset.get('format')!r}")
    models = check_models(root, dataset, fail)
    models_eval = check_models_eval(root, dataset, models, fail)
    stats: dict[str, list[float]] = {
        k: [] for k in ("iou", "iou_raw", "depth_median", "depth_all", "touch_mm")
    }
    images = 0
    coco_annotations = 0
    cameras: list[dict[str, Any]] = []
    test_images: list[tuple[int, int, list[Any], list[Any]]] = []
    scenes = check_scene_ids(root, dataset, fail)
    for split, scene_id, grasp in scenes:
        scene = root / split / f"{scene_id:06d}"
        ids = scene_im_ids(scene, fail)
        ctx = {
            "camera": load_scene_camera(scene / "scene_camera.json"),
            "gt": load_scene_gt(scene / "scene_gt.json"),
            "gt_info": load_json(scene / "scene_gt_info.json", keys_to_int=True),
            "touch": load_json(scene / "scene_touch.json", keys_to_int=True),
            "models": models,
        }
        meta = load_json(scene / "scene_meta.json", keys_to_int=True)
        raw_cameras = load_json(scene / "scene_camera.json", keys_to_int=True)
        for im in ids:
            fail.check(
                meta[im]["grasp_id"] == grasp,
                f"{scene}: scene_meta im {im} is of {meta[im]['grasp_id']}, not {grasp}",
            )
            check_image(scene, im, ctx, fail, stats)
            images += 1
            cameras.append(raw_cameras[im])
            if split == "test":
                test_images.append((scene_id, im, ctx["gt"][im], ctx["gt_info"][im]))
        coco_annotations += check_coco(scene, ids, ctx, fail)
    targets = check_dataset_files(root, cameras, test_images, fail) if cameras else {}
    depth_all = np.array(stats["depth_all"] or [np.nan])
    summary = {
        "scenes": len(scenes),
        "images": images,
        "models": len(models),
        "models_eval": models_eval,
        "depth_error_mm": {
            "median": float(np.median(depth_all)),
            "p95": float(np.percentile(depth_all, 95)),
            "max": float(depth_all.max()),
            "worst_image_median": max(stats["depth_median"], default=float("nan")),
            "pixels": len(stats["depth_all"]),
        },
        "mask_iou": {
            "min": min(stats["iou"], default=float("nan")),
            "min_with_boundary": min(stats["iou_raw"], default=float("nan")),
        },
        "touch_surface_mm": {
            "taxels": len(stats["touch_mm"]),
            "median": float(np.median(stats["touch_mm"])) if stats["touch_mm"] else None,
            "max": max(stats["touch_mm"], default=None),
        },
        "targets": targets,
        "coco_annotations": coco_annotations,
        "failures": len(fail.messages),
    }
    return summary, fail.messages


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print(__doc__, file=sys.stderr)
        return 2
    summary, failures = check(Path(argv[1]))
    print(json.dumps(summary, indent=1))
    for message in failures:
        print(f"check_bop: {message}", file=sys.stderr)
    if failures:
        print(f"check_bop: FAILED ({len(failures)} problems)", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
