"""The Blender scenes of the render engine: built once, then only moved.

Three Cycles scenes share one camera and the same objects, and each keeps its own persistent render
session, so a re-render after a move costs only the render:
- `vint_rgb` path-traces the image under the world (one environment texture node whose image is
  swapped between HDRIs — bundled ones and users' files — each loaded once and kept by name or
  content hash; a mapping node rotates it about world z and the background's strength scales it).
  Rendered only when a task asks for RGB.
- `vint_geometry` holds the object and the hand and renders depth and the object index pass with
  no path tracing (one ray per pixel centre, no bounces, no world, one flat override material).
- `vint_object` holds the object alone and renders its index pass the same way: the object's full
  mask, as if the hand were not there.

Objects: the hand's link objects (rebuilt only when the hand geometry changes; link k has pass
index 2 + k, the object 1) and the object: one Blender object whose mesh is swapped between object
meshes, each made once per object name from the grasp engine's model PLY or, without one, from the
shape in the catalog entry, or — for a user's textured mesh, staged with RGB tasks only — from the
mesh file itself with its texture coordinates and image (or colours) and its material at once. Any
other object mesh gets its material (and texture nodes) only when an RGB view first needs it: the
geometry scenes never read it. Knows nothing about tasks or files beyond the
pass scratch directory and the model PLY and HDRI files it is handed.
"""

from __future__ import annotations

import hashlib
import json
import math
import shutil
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import addon_utils
import bpy
import numpy as np
import numpy.typing as npt
from mathutils import Matrix

from vint_engines import hand_meshes
from vint_engines.objects import ObjectSpec, build_model
from vint_engines.objects.meshio import read_ply_m
from vint_engines.objects.textured import MeshSource, SurfaceLook
from vint_engines.poses import pose_matrix
from vint_engines.protocol import BadInput
from vint_engines.render import clutter, cycles, dressing, materials, meshes
from vint_engines.render.camera import CameraPose, Intrinsics
from vint_engines.render.cycles import PathTracing
from vint_engines.render.hdri_file import check_hdri
from vint_engines.render.passes import (
    add_pass_outputs,
    read_colour,
    read_depth,
    read_index,
    use_pass_tree,
)

OBJECT_PASS_INDEX = 1
FIRST_LINK_PASS_INDEX = 2  # link k of the hand (in grasps.json order) has pass index 2 + k;
# after the n links: the arm's flange (2 + n) and last link (3 + n), then the table (4 + n)
# (`dressing.py`), then distractor i (5 + n + i, `clutter.py`), each labelled only while shown.
HAND_MATERIAL_TAG = dressing.HAND_MATERIAL_TAG
RGB_PREFIX = "rgb_"
RGB_PASSES = ("image",)  # the path-traced image, linear
DENOISED_PASSES = ("image", "albedo", "normal")  # and the denoiser's guides
GEOMETRY_PREFIX = "geometry_"
OBJECT_PREFIX = "object_"
ENVIRONMENT_MAP_RESOLUTION = 256  # importance map for the HDRI: 0.3 s to build instead of ~2 s
OBJECT_MESH_CAPACITY = 64  # object meshes kept for reuse (the catalog has fewer objects)
TURNED_IMAGE_CAPACITY = 8  # turned copies of HDRIs kept
SHARP_EDGE_DEG = 30.0  # model meshes shade smooth except across edges sharper than this


@dataclass(frozen=True)
class Geometry:
    """What the geometry passes of one view saw."""

    depth: npt.NDArray[np.float32]  # metres along the optical axis, 0 where nothing is hit
    index: npt.NDArray[np.int32]  # pass index of the visible surface, 0 for background
    object_full: npt.NDArray[np.bool_]  # where the object would be seen without the hand


@dataclass(frozen=True)
class Radiance:
    """What the RGB render of one view saw: H×W×3 float, R, G, B, rows top to bottom."""

    image: npt.NDArray[np.float32]  # linear light as Cycles path-traced it (noisy)
    albedo: npt.NDArray[np.float32] | None = None  # the denoiser's guides, when asked for
    normal: npt.NDArray[np.float32] | None = None


def environment_dir() -> Path:
    return Path(bpy.utils.system_resource("DATAFILES", path="studiolights/world"))


def environments() -> list[str]:
    """The bundled HDRIs' names."""
    return sorted(path.stem for path in environment_dir().glob("*.exr"))


def check_environment(name: str, where: str) -> None:
    """BadInput unless `name` is a bundled HDRI; `where` names the parameter in the message."""
    if name not in environments():  # a name, never a path
        raise BadInput(f"{where}: unknown environment {name!r} (have {environments()})")


@dataclass(frozen=True)
class Hdri:
    """An HDRI image to light the RGB scene with: a bundled one (`key` its name) or a user's file
    staged with the task (`key` the file's SHA-256). `label` names it in error messages."""

    key: str
    path: Path
    label: str
    staged: bool = False

    @staticmethod
    def bundled(name: str, where: str) -> Hdri:
        check_environment(name, where)
        return Hdri(name, environment_dir() / f"{name}.exr", f"environment {name!r}")

    @staticmethod
    def user(sha256: str, path: Path, label: str) -> Hdri:
        return Hdri(sha256, path, label, staged=True)


class BlenderScene:
    def __init__(self, scratch: Path) -> None:
        self.scratch = scratch
        bpy.ops.wm.read_factory_settings(use_empty=True)
        addon_utils.enable("cycles")
        self.device = cycles.select_device()
        self.threads = cycles.render_threads()
        self.rgb_scene = bpy.context.scene
        self.rgb_scene.name = "vint_rgb"
        self.geometry_scene = bpy.data.scenes.new("vint_geometry")
        self.object_scene = bpy.data.scenes.new("vint_object")
        self.scenes = (self.rgb_scene, self.geometry_scene, self.object_scene)
        for scene in self.scenes:
            cycles.configure_scene(scene, self.device, self.threads)
        self._configure_rgb()
        self._configure_geometry()
        self.camera = self._add_camera()
        self._environment_node, self._tint_node, self._background_node = self._add_world()
        self._turned_images: dict[tuple[str, float], bpy.types.Image] = {}  # (key, turn) → image, LRU
        self._environment_images: dict[str, bpy.types.Image] = {}  # by `Hdri.key`
        # (Hdri.key, rotation_deg, strength, tint) of the environment set last
        self.environment: tuple[str, float, float, tuple[float, float, float]] | None = None
        self._hand_key: str | None = None
        self._links: dict[str, bpy.types.Object] = {}
        self._object: bpy.types.Object | None = None
        self._object_meshes: dict[str, tuple[str, bpy.types.Mesh]] = {}  # name → (content key, mesh)
        self._object_spec: ObjectSpec | None = None
        # Material slots of a hand link: 0 anodised (links and palm housing), 1 fingertip pad,
        # 2 the taxels of the sensor skin.
        self._hand_materials = (
            materials.principled("vint_hand", dressing.ANODISED_BLACK),
            materials.principled("vint_fingertip_pad", dressing.FINGERTIP_PAD),
            materials.principled("vint_taxel", dressing.TAXEL_SKIN),
        )
        self._arm_materials = {
            "flange": materials.principled("vint_flange", dressing.FLANGE_ALUMINIUM),
            "link": materials.principled("vint_arm_link", dressing.ARM_PAINT),
        }
        self._arm: dict[str, tuple[bpy.types.Object, str]] = {}  # piece → (object, mount link)
        self.dressing = dressing.SceneDressing()
        self._table = self._add_table()
        self.table_top_z: float | None = None
        # Distractors: a pool of objects, shown while a grasp stands that many (`set_distractors`).
        self._distractors: list[bpy.types.Object] = []
        self._distractor_meshes: dict[str, tuple[ObjectSpec, bpy.types.Mesh]] = {}  # by catalog name
        self._standing: list[tuple[clutter.Placed, ObjectSpec]] = []

    def _configure_geometry(self) -> None:
        """Both geometry scenes: no path tracing, and one flat material for every surface, so no
        object's node tree is compiled or evaluated (the first hit does not depend on it)."""
        flat = materials.principled("vint_flat", {"Base Color": (0.5, 0.5, 0.5, 1.0)})
        for scene, prefix, passes in (
            (self.geometry_scene, GEOMETRY_PREFIX, ("depth", "index")),
            (self.object_scene, OBJECT_PREFIX, ("index",)),
        ):
            cycles.configure_geometry_pass(scene)
            scene.view_layers[0].material_override = flat
            add_pass_outputs(scene, self.scratch, prefix, passes)

    def _configure_rgb(self) -> None:
        """The RGB scene writes the image as linear float (and, for a denoised view, the albedo
        and normal guides): one compositor tree per set of passes, switched per render, so a raw
        view makes Cycles store no guides."""
        scene = self.rgb_scene
        scene.view_settings.view_transform = "Standard"  # no tone curve on the linear output
        self._rgb_trees = {
            passes: add_pass_outputs(scene, self.scratch, RGB_PREFIX, passes)
            for passes in (DENOISED_PASSES, RGB_PASSES)
        }

    def _add_camera(self) -> bpy.types.Object:
        data = bpy.data.cameras.new("vint_camera")
        data.sensor_fit = "HORIZONTAL"
        data.clip_start = 0.01
        data.clip_end = 100.0
        camera = bpy.data.objects.new("vint_camera", data)
        for scene in self.scenes:
            scene.collection.objects.link(camera)
            scene.camera = camera
        return camera

    def _add_world(self) -> tuple[bpy.types.Node, bpy.types.Node, bpy.types.Node]:
        """The RGB scene's world: environment texture → × tint → background (strength); a tint of
        (1, 1, 1) passes the colour through exactly (a + 1·(a·1 - a) = a). The geometry
        scenes have no world. An environment is turned by rolling its image's columns
        (`_turned_image`) rather than by a Mapping node turning the texture lookup; an unturned
        environment renders exactly as without the feature.

        Known limit (measured, docs/rendering.md): under a *turned* HDRI, Cycles' importance map
        for it is not byte-stable between processes — one pixel of one tiny.toml view (allegro
        in the mug, forest turned 90°) differed in 7 of 24 fresh processes. Unturned HDRIs have
        been byte-stable in every run, which is what the determinism tests exercise."""
        world = bpy.data.worlds.new("vint_world")
        world.use_nodes = True
        world.cycles.sampling_method = "MANUAL"
        world.cycles.sample_map_resolution = ENVIRONMENT_MAP_RESOLUTION
        tree = world.node_tree
        environment = tree.nodes.new("ShaderNodeTexEnvironment")
        tint = tree.nodes.new("ShaderNodeMix")
        tint.data_type = "RGBA"
        tint.blend_type = "MULTIPLY"
        tint.inputs["Factor"].default_value = 1.0
        _socket(tint.inputs, "B_Color").default_value = (1.0, 1.0, 1.0, 1.0)
        background = tree.nodes["Background"]
        tree.links.new(environment.outputs["Color"], _socket(tint.inputs, "A_Color"))
        tree.links.new(_socket(tint.outputs, "Result_Color"), background.inputs["Color"])
        self.rgb_scene.world = world
        return environment, tint, background

    # -- scene content ---------------------------------------------------------------------------

    def load_environment(self, hdri: Hdri) -> None:
        """Load `hdri` unless an HDRI with its key is loaded already (a user's file is known by
        its content, so the same file staged for another task is not read again). A user's file
        is copied into the scratch directory first: the image must outlive the task's staged
        inputs. BadInput when its header declares too large an image or is malformed (read before
        Blender allocates what it declares: `hdri_file.py`), or Blender cannot read it."""
        if hdri.key in self._environment_images:
            return
        path = hdri.path
        if hdri.staged:
            check_hdri(hdri.path, hdri.label)
            path = self.scratch / "hdri" / f"{hdri.key}{hdri.path.suffix.lower()}"
            path.parent.mkdir(exist_ok=True)
            shutil.copyfile(hdri.path, path)
        image = bpy.data.images.load(str(path), check_existing=True)
        if image.size[0] == 0 or image.size[1] == 0:  # Blender loads lazily; size reads the pixels
            bpy.data.images.remove(image)
            path.unlink(missing_ok=True)
            raise BadInput(f"{hdri.label}: Blender cannot read the file as an image")
        self._environment_images[hdri.key] = image

    def set_environment(
        self,
        hdri: Hdri,
        rotation_deg: float = 0.0,
        strength: float = 1.0,
        tint: tuple[float, float, float] = (1.0, 1.0, 1.0),
    ) -> None:
        """Light the RGB scene with `hdri`, turned by `rotation_deg` about world +z
        (counter-clockwise seen from above), scaled by `strength` and its colour multiplied by
        `tint` (linear RGB; `lighting.py`). Each HDRI is loaded on first use and kept, so switching
        between views only swaps the texture's image."""
        if (hdri.key, rotation_deg, strength, tint) == self.environment:
            return
        self.load_environment(hdri)
        self._environment_node.image = self._turned_image(hdri.key, rotation_deg)
        self._background_node.inputs["Strength"].default_value = strength
        _socket(self._tint_node.inputs, "B_Color").default_value = (*tint, 1.0)
        self.environment = (hdri.key, rotation_deg, strength, tint)

    def _turned_image(self, key: str, rotation_deg: float) -> bpy.types.Image:
        """The loaded HDRI `key` turned by `rotation_deg` about world +z: its columns rolled.

        Cycles maps azimuth φ (from +x towards +y) to u = 0.5 - φ/2π, so turning the environment
        by +θ (what was at φ is now at φ + θ) shows at column u what was at u + θ/2π. A turn
        that is not a whole number of columns interpolates linearly between the two nearest.
        Turned copies are kept (a few, least recently used dropped first)."""
        base = self._environment_images[key]
        turn = rotation_deg % 360.0
        if turn == 0.0:
            return base
        cached = self._turned_images.pop((key, turn), None)
        if cached is None:
            width, height = base.size
            pixels = np.empty(width * height * 4, np.float32)
            base.pixels.foreach_get(pixels)
            pixels = pixels.reshape(height, width, 4)
            shift = turn / 360.0 * width
            whole = math.floor(shift)
            part = np.float32(shift - whole)
            turned = np.roll(pixels, -whole, axis=1)
            if part > 0.0:
                turned = (1.0 - part) * turned + part * np.roll(pixels, -(whole + 1), axis=1)
            name = f"{base.name}_turned_{turn:g}"
            cached = bpy.data.images.new(name, width, height, alpha=True, float_buffer=True)
            cached.colorspace_settings.name = base.colorspace_settings.name
            cached.pixels.foreach_set(turned.astype(np.float32).ravel())
        self._turned_images[(key, turn)] = cached
        while len(self._turned_images) > TURNED_IMAGE_CAPACITY:
            bpy.data.images.remove(self._turned_images.pop(next(iter(self._turned_images))))
        return cached

    def set_hand(self, hand: Mapping[str, Any]) -> None:
        """Create the hand's link objects (and the arm pieces at its `mount`, when it names one),
        unless this exact geometry is already loaded. A user's link with visual geoms is drawn
        from those alone (`_drawn`); mesh and visual geoms are painted in their own colour."""
        key = json.dumps(
            {
                "links": hand.get("links"),
                "meshes": hand.get("meshes"),
                "mount": hand.get("mount"),
                "taxels": hand.get("taxels"),
            },
            sort_keys=True,
        )
        if key == self._hand_key:
            return
        for obj in [*self._links.values(), *(piece for piece, _ in self._arm.values())]:
            _remove_object(obj)
        self._links, self._arm, self._hand_key = {}, {}, None
        try:
            layout = dressing.built_in_taxels(hand, [link["name"] for link in hand["links"]])
            taxels = layout.indices_by_link() if layout is not None else {}
            for k, link in enumerate(hand["links"]):
                shown = _drawn(link["geoms"])
                slots = list(self._hand_materials)
                primitives, indices, triangles = [], [], []
                for g in shown:
                    if "rgba" in g:
                        slot = _colour_slot(slots, g["rgba"])
                    else:  # the built-in dressing: anodised, fingertip pads on slot 1
                        slot = 1 if dressing.geom_role(link["name"], g) == "pad" else 0
                    matrix = meshes.geom_matrix(g["p"], g["q"])
                    if g["type"] == "mesh":
                        vertices, faces = hand_meshes.decode(hand["meshes"][g["mesh"]])
                        triangles.append((vertices, faces, matrix, slot))
                    else:
                        primitives.append((g["type"], g["size"], matrix))
                        indices.append(slot)
                roles = [dressing.geom_role(link["name"], g) for g in shown if g["type"] != "mesh"]
                discs = None
                if layout is not None and link["name"] in taxels:
                    rows = taxels[link["name"]]
                    normals = layout.normals[rows]
                    centres = layout.positions[rows] + normals * dressing.TAXEL_HALF_HEIGHT_M
                    discs = (centres, normals, dressing.TAXEL_RADIUS_M, dressing.TAXEL_HALF_HEIGHT_M, 2)
                mesh = meshes.new_mesh(
                    f"link_{link['name']}",
                    primitives,
                    indices,
                    dressing.PALM_EDGE_RADIUS_M if "palm" in roles else 0.0,
                    triangles,
                    discs,
                )
                index = FIRST_LINK_PASS_INDEX + k
                self._links[link["name"]] = self._add_object(mesh, slots, index)
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise BadInput(f"grasps.json: malformed hand geometry ({exc!r})") from exc
        if hand.get("mount") is not None:
            mount = dressing.Mount.parse(hand["mount"], list(self._links), "grasps.json hand.mount")
            first = FIRST_LINK_PASS_INDEX + len(self._links)
            for i, (name, radius, half, centre, axis) in enumerate(dressing.arm_pieces(mount)):
                geoms = [("cylinder", (radius, half), meshes.axis_matrix(centre, axis))]
                mesh = meshes.new_mesh(f"arm_{name}", geoms)
                piece = self._add_object(mesh, (self._arm_materials[name],), first + i)
                self._arm[name] = (piece, mount.link)
        self._table.pass_index = self._table_pass_index()
        for i, obj in enumerate(self._distractors):
            obj.pass_index = self._distractor_pass_index(i)
        self._hand_key = key

    def set_object(
        self, obj: Mapping[str, Any], model_ply: Path | None = None, textured: MeshSource | None = None
    ) -> None:
        """Show the object of a grasps.json entry: with `textured` (a user's mesh file and its
        sidecars, staged when RGB is rendered), that file's surface with its texture or colours
        and its material made at once; else its model mesh `model_ply` (the grasp engine's
        object.ply, millimetres) when given, else its shape rebuilt from the entry — the same
        surface every way. Each object name keeps its mesh and material; they are remade only
        when the files or the entry's shape or material change."""
        spec = ObjectSpec.parse(obj, "grasps.json object")
        if textured is not None:
            source = f"textured:{textured.key}"
        else:
            source = hashlib.sha256(model_ply.read_bytes()).hexdigest() if model_ply else spec.to_json()
        look = {"material": spec.material, "texture": spec.texture.to_json()}
        key = json.dumps({"mesh": source, **look}, sort_keys=True)
        cached = self._object_meshes.pop(spec.name, None)  # re-inserted last: least recently used first
        if cached is not None and cached[0] == key:
            mesh = cached[1]
        elif textured is not None:
            mesh = _looked_mesh(spec, textured.load("grasps.json object (the user's mesh file)"))
        else:
            vertices, faces = read_ply_m(model_ply) if model_ply else _rebuilt_mesh(spec)
            mesh = meshes.triangle_mesh(f"object_{spec.name}", vertices, faces, SHARP_EDGE_DEG)
        self._object_meshes[spec.name] = (key, mesh)
        self._object_spec = spec
        if self._object is None:
            self._object = bpy.data.objects.new("object", mesh)
            self._object.pass_index = OBJECT_PASS_INDEX
            for scene in self.scenes:
                scene.collection.objects.link(self._object)
        else:
            self._object.data = mesh
        if cached is not None and cached[1] is not mesh:
            _remove_mesh(cached[1])
        self._evict_object_meshes()

    def object_radius(self) -> float:
        """The shown object's bounding radius about its frame's origin (m); 0 before any."""
        if self._object is None:
            return 0.0
        mesh = self._object.data
        co = np.empty(3 * len(mesh.vertices), np.float64)
        mesh.vertices.foreach_get("co", co)
        return float(np.linalg.norm(co.reshape(-1, 3), axis=1).max(initial=0.0))

    def _evict_object_meshes(self) -> None:
        while len(self._object_meshes) > OBJECT_MESH_CAPACITY:
            name = next(iter(self._object_meshes))
            _remove_mesh(self._object_meshes.pop(name)[1])

    def pose(self, object_pose: tuple[np.ndarray, np.ndarray], links: Mapping[str, tuple]) -> None:
        """Place the object and every link ((p, q) world poses); links must all be present."""
        assert self._object is not None
        self._object.matrix_world = Matrix(pose_matrix(*object_pose).tolist())
        missing = set(self._links) - set(links)
        if missing:
            raise BadInput(f"grasps.json: trial lacks poses for links {sorted(missing)}")
        for name, obj in self._links.items():
            obj.matrix_world = Matrix(pose_matrix(*links[name]).tolist())
        for piece, link in self._arm.values():
            piece.matrix_world = Matrix(pose_matrix(*links[link]).tolist())
            piece.hide_render = not self.dressing.flange
        self._place_table(object_pose[0])

    def set_dressing(self, dressing_: dressing.SceneDressing) -> None:
        """What of the scene around the grasp the next `pose` shows."""
        self.dressing = dressing_

    def grasp_reach(self) -> float:
        """How far the shown object, hand and arm pieces reach horizontally from the object's
        centre (m): the radius of the grasp's footprint."""
        assert self._object is not None
        centre = np.asarray(self._object.matrix_world, dtype=np.float64)[:2, 3]
        reach = 0.0
        for obj in self._grasp_objects():
            points = _world_vertices(obj)
            if len(points):
                reach = max(reach, float(np.linalg.norm(points[:, :2] - centre, axis=1).max()))
        return reach

    def set_distractors(self, standing: Sequence[tuple[clutter.Placed, ObjectSpec]]) -> None:
        """Stand these catalog objects where `clutter.place` put them (none hides them all); each
        keeps its mesh by name, its material made when an RGB view first shows it."""
        while len(self._distractors) < len(standing):
            mesh = bpy.data.meshes.new(f"distractor_{len(self._distractors)}_empty")
            obj = self._add_object(mesh, (), self._distractor_pass_index(len(self._distractors)))
            self._distractors.append(obj)
        for i, obj in enumerate(self._distractors):
            if i >= len(standing):
                obj.hide_render = True
                continue
            placed, spec = standing[i]
            cached = self._distractor_meshes.get(spec.name)
            if cached is None or cached[0] != spec:
                vertices, faces = _rebuilt_mesh(spec)
                mesh = meshes.triangle_mesh(f"distractor_{spec.name}", vertices, faces, SHARP_EDGE_DEG)
                self._distractor_meshes[spec.name] = (spec, mesh)
            obj.data = self._distractor_meshes[spec.name][1]
            obj.matrix_world = Matrix(pose_matrix(placed.position, placed.quat).tolist())
            obj.hide_render = self._table.hide_render
        self._standing = list(standing)

    def distractors_shown(self) -> list[clutter.Placed]:
        """The distractors the placed camera sees stand (none when it does not see the table)."""
        return [placed for placed, _ in self._standing] if self.table_shown() else []

    def _grasp_objects(self) -> list[bpy.types.Object]:
        """What the grasp shows: the object, the hand's links and, with the flange, the arm's
        pieces (the table stands under them, distractors around them)."""
        shown = [obj for obj in (self._object, *self._links.values()) if obj is not None]
        if self.dressing.flange:
            shown += [piece for piece, _ in self._arm.values()]
        return shown

    def _place_table(self, object_position: np.ndarray) -> None:
        """The table top level under the object, `table_gap_m` below the lowest shown point."""
        if not self.dressing.table:
            self.table_top_z = None
            self._table.hide_render = True
            return
        # A user's link may show nothing (a body with no geom of its own).
        lowest = min(_lowest_z(obj) for obj in self._grasp_objects() if len(obj.data.vertices))
        top = dressing.table_top_z(lowest, self.dressing.table_gap_m)
        thickness = dressing.TABLE_SIZE_M[2]
        self._table.location = (float(object_position[0]), float(object_position[1]), top - thickness / 2)
        self._table.hide_render = False
        self.table_top_z = top

    # -- rendering -------------------------------------------------------------------------------

    def segmentation_labels(self) -> dict[int, str]:
        """Pass index → name: the object, then each hand link as `hand/<link>`."""
        labels = {OBJECT_PASS_INDEX: "object"}
        for k, name in enumerate(self._links):
            labels[FIRST_LINK_PASS_INDEX + k] = f"hand/{name}"
        if self.dressing.flange:
            for piece, _ in self._arm.values():
                labels[piece.pass_index] = f"arm/{piece.name.removeprefix('arm_')}"
        if self.dressing.table:
            labels[self._table_pass_index()] = "scene/table"
        for i, (placed, _) in enumerate(self._standing):
            labels[self._distractor_pass_index(i)] = f"distractor/{placed.name}"
        return labels

    def _table_pass_index(self) -> int:
        return FIRST_LINK_PASS_INDEX + len(self._links) + len(dressing.ARM_PIECES)

    def _distractor_pass_index(self, i: int) -> int:
        return self._table_pass_index() + 1 + i

    def _object_material(self) -> str:
        """The shown object's material tag (plastic before any object is set)."""
        return self._object_spec.material if self._object_spec else "plastic"

    def segment_materials(self) -> dict[int, str]:
        """Pass index → material tag, for the depth-noise model: the object's catalog tag, and
        `HAND_MATERIAL_TAG` for every hand link."""
        tags = {OBJECT_PASS_INDEX: self._object_material()}
        for k in range(len(self._links)):
            tags[FIRST_LINK_PASS_INDEX + k] = HAND_MATERIAL_TAG
        for index, label in self.segmentation_labels().items():
            if label.startswith(("arm/", "scene/")):
                tags[index] = dressing.MATERIAL_TAGS[label]
        for i, (_, spec) in enumerate(self._standing):
            tags[self._distractor_pass_index(i)] = spec.material
        return tags

    def lobes(self) -> frozenset[str]:
        """The scattering lobes of every material in the RGB scene (see `cycles.Bounces.pruned`)."""
        lobes = materials.object_lobes(self._object_material())
        if self._links:
            for look in (dressing.ANODISED_BLACK, dressing.FINGERTIP_PAD, dressing.TAXEL_SKIN):
                lobes |= materials.lobes(look)
        if self.dressing.flange and self._arm:
            lobes |= materials.lobes(dressing.FLANGE_ALUMINIUM) | materials.lobes(dressing.ARM_PAINT)
        if self.dressing.table:
            lobes |= materials.lobes(dressing.TABLE_WOOD)
        for _, spec in self._standing:
            lobes |= materials.object_lobes(spec.material)
        return lobes

    def place_camera(self, camera: CameraPose, intrinsics: Intrinsics) -> None:
        for scene in self.scenes:
            scene.render.resolution_x = intrinsics.width
            scene.render.resolution_y = intrinsics.height
        self.camera.data.angle = intrinsics.angle_rad
        self.camera.data.shift_x, self.camera.data.shift_y = intrinsics.blender_shift()
        self.camera.matrix_world = Matrix(camera.blender_matrix_world().tolist())
        if self.table_top_z is not None:
            self._table.hide_render = not dressing.camera_sees_table(
                float(camera.position[2]), self.table_top_z
            )
        for obj in self._distractors[: len(self._standing)]:  # they stand on the table
            obj.hide_render = self._table.hide_render

    def table_shown(self) -> bool:
        """Whether the placed camera sees the table."""
        return not self._table.hide_render

    def render_geometry(self) -> Geometry:
        """Depth and pass indices of the placed camera's view, and the object's full mask."""
        bpy.ops.render.render(scene=self.geometry_scene.name)
        depth = read_depth(self.scratch, GEOMETRY_PREFIX)
        index = read_index(self.scratch, GEOMETRY_PREFIX)
        bpy.ops.render.render(scene=self.object_scene.name)
        full = read_index(self.scratch, OBJECT_PREFIX) == OBJECT_PASS_INDEX
        return Geometry(depth=depth, index=index, object_full=full)

    def render_rgb(self, tracing: PathTracing, seed: int) -> Radiance:
        """The placed camera's path-traced image under the environment, in linear light, with
        the denoiser's guides when `tracing.denoise` asks for them."""
        scene = self.rgb_scene
        self._dress_object()
        self._dress_distractors()
        tracing.apply(scene, seed)
        passes = DENOISED_PASSES if tracing.denoise else RGB_PASSES
        use_pass_tree(scene, self._rgb_trees[passes], passes)
        bpy.ops.render.render(scene=scene.name)
        image = read_colour(self.scratch, RGB_PREFIX, "image")
        if not tracing.denoise:
            return Radiance(image)
        albedo = read_colour(self.scratch, RGB_PREFIX, "albedo")
        return Radiance(image, albedo, read_colour(self.scratch, RGB_PREFIX, "normal"))

    # -- helpers ---------------------------------------------------------------------------------

    def _dress_object(self) -> None:
        """Give the shown object mesh its material, made the first time an RGB view shows it."""
        if self._object is None or self._object_spec is None:
            return  # nothing shown yet (the engine's warm-up render)
        mesh = self._object.data
        if not mesh.materials:
            spec = self._object_spec
            mesh.materials.append(materials.object_material(spec.name, spec.material, spec.texture))

    def _dress_distractors(self) -> None:
        """Give each standing distractor's mesh its catalog material, made the first time an RGB
        view shows it."""
        for _, spec in self._standing:
            mesh = self._distractor_meshes[spec.name][1]
            if not mesh.materials:
                mesh.materials.append(materials.object_material(spec.name, spec.material, spec.texture))

    def _add_object(
        self, mesh: bpy.types.Mesh, slots: Sequence[bpy.types.Material], pass_index: int
    ) -> bpy.types.Object:
        for material in slots:
            mesh.materials.append(material)
        obj = bpy.data.objects.new(mesh.name, mesh)
        obj.pass_index = pass_index
        for scene in (self.rgb_scene, self.geometry_scene):
            scene.collection.objects.link(obj)
        return obj

    def _add_table(self) -> bpy.types.Object:
        """The table top (hidden until a task shows it): a box with slightly rounded edges, wood
        grain along its length. Its pass index follows the hand's links (`set_hand`)."""
        half = [size / 2 for size in dressing.TABLE_SIZE_M]
        mesh = meshes.new_mesh("scene_table", [("box", half, Matrix.Identity(4))], edge_radius=0.003)
        table = self._add_object(mesh, (_table_material(),), 0)
        table.hide_render = True
        return table


def _socket(sockets: Any, identifier: str) -> Any:
    """The socket with `identifier`: a Mix node has an A, B and Result per data type, and a name
    finds the first (the float one)."""
    return next(socket for socket in sockets if socket.identifier == identifier)


def _table_material() -> bpy.types.Material:
    """Oiled wood for the table top: grain as banded waves across the planks' length (x), bent by
    low-frequency noise stretched along x so the bands wander as a flat-sawn board's do, with a
    slower colour drift between lighter and darker wood (`dressing.TABLE_*`)."""
    material = materials.principled("vint_table", dressing.TABLE_WOOD)
    tree = material.node_tree
    coords = tree.nodes.new("ShaderNodeTexCoord")
    wave = tree.nodes.new("ShaderNodeTexWave")
    wave.wave_type = "BANDS"
    wave.bands_direction = "Y"
    wave.wave_profile = "SAW"
    for key, value in dressing.TABLE_GRAIN.items():
        wave.inputs[key].default_value = value
    drift = tree.nodes.new("ShaderNodeTexNoise")
    drift.inputs["Scale"].default_value = 3.0
    ramp = tree.nodes.new("ShaderNodeMix")
    ramp.data_type = "RGBA"
    ramp.inputs["A"].default_value = dressing.TABLE_WOOD_LIGHT
    ramp.inputs["B"].default_value = dressing.TABLE_WOOD_DARK
    grain = tree.nodes.new("ShaderNodeMath")
    grain.operation = "MULTIPLY_ADD"
    grain.inputs[1].default_value = 0.6
    stretch = tree.nodes.new("ShaderNodeMapping")  # grain runs along x: its bends are long there
    stretch.inputs["Scale"].default_value = dressing.TABLE_GRAIN_STRETCH
    tree.links.new(coords.outputs["Object"], stretch.inputs["Vector"])
    tree.links.new(stretch.outputs["Vector"], wave.inputs["Vector"])
    tree.links.new(coords.outputs["Object"], drift.inputs["Vector"])
    tree.links.new(wave.outputs["Fac"], grain.inputs[0])
    tree.links.new(drift.outputs["Fac"], grain.inputs[2])
    tree.links.new(grain.outputs["Value"], ramp.inputs["Factor"])
    bsdf = tree.nodes["Principled BSDF"]
    tree.links.new(ramp.outputs["Result"], bsdf.inputs["Base Color"])
    return material


def _lowest_z(obj: bpy.types.Object) -> float:
    """The lowest world z of `obj`'s mesh vertices."""
    return float(_world_vertices(obj)[:, 2].min())


def _world_vertices(obj: bpy.types.Object) -> npt.NDArray[np.float64]:
    """`obj`'s mesh vertices in world coordinates, n×3."""
    mesh = obj.data
    co = np.empty(3 * len(mesh.vertices), np.float64)
    mesh.vertices.foreach_get("co", co)
    world = np.asarray(obj.matrix_world, dtype=np.float64)
    points: npt.NDArray[np.float64] = co.reshape(-1, 3) @ world[:3, :3].T + world[:3, 3]
    return points


def _rebuilt_mesh(spec: ObjectSpec) -> tuple[np.ndarray, np.ndarray]:
    mesh = build_model(spec, where="grasps.json object").mesh
    return mesh.vertices, mesh.faces


def _drawn(geoms: Sequence[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    """The geoms of a hand link that are drawn: its visual ones when it has any (a user's hand;
    the colliding ones are what the physics felt, often cruder), else every one; a fully
    transparent geom never."""
    visual = [g for g in geoms if g.get("visual")]
    return [g for g in visual or geoms if "rgba" not in g or float(g["rgba"][3]) > 0.0]


def _colour_slot(slots: list[bpy.types.Material], rgba: Sequence[float]) -> int:
    """The slot of the hand material in colour `rgba` (opaque, the hand's plastic), added to
    `slots` when new; one material per colour for every hand the engine shows."""
    r, g, b = (min(1.0, max(0.0, float(v))) for v in rgba[:3])
    name = f"vint_hand_rgb_{r:.4f}_{g:.4f}_{b:.4f}"
    material = bpy.data.materials.get(name)
    if material is None:
        material = materials.principled(name, {**materials.HAND, "Base Color": (r, g, b, 1.0)})
        material.use_fake_user = True  # kept when no hand shows it, so the name always finds it
    if material not in slots:
        slots.append(material)
    return slots.index(material)


def _looked_mesh(spec: ObjectSpec, look: SurfaceLook) -> bpy.types.Mesh:
    """The Blender mesh of a user's surface with its colour: texture coordinates per corner and
    the image as a packed-in Blender image, or a colour attribute per corner; its material is
    the tag's with that base colour."""
    mesh = meshes.triangle_mesh(f"object_{spec.name}", look.vertices, look.faces, SHARP_EDGE_DEG)
    image = None
    attribute = None
    if look.corner_uv is not None and look.image is not None:
        uv = mesh.uv_layers.new(name="UVMap")
        uv.data.foreach_set("uv", look.corner_uv.astype(np.float32).reshape(-1))
        height, width = look.image.shape[:2]
        image = bpy.data.images.new(f"object_{spec.name}_texture", width, height, alpha=True)
        # Blender's rows run bottom-up; the file's top-down. Byte images hold sRGB as given.
        image.pixels.foreach_set((look.image[::-1].astype(np.float32) / 255.0).reshape(-1))
        image.pack()
    elif look.corner_colours is not None:
        attribute = "Col"
        colours = mesh.color_attributes.new(attribute, "FLOAT_COLOR", "CORNER")
        linear = look.corner_colours.copy()
        srgb = linear[..., :3]
        linear[..., :3] = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
        colours.data.foreach_set("color", linear.astype(np.float32).reshape(-1))
    mesh.materials.append(materials.surface_material(spec.name, spec.material, image, attribute))
    return mesh


def _remove_mesh(mesh: bpy.types.Mesh) -> None:
    """Free an object mesh (and its material and texture image) once nothing shows it."""
    if mesh.users == 0:
        used = [m for m in mesh.materials if m is not None]
        bpy.data.meshes.remove(mesh)
        for material in used:
            if material.users == 0:
                images = [n.image for n in material.node_tree.nodes if n.type == "TEX_IMAGE" and n.image]
                bpy.data.materials.remove(material)
                for image in images:
                    if image.users == 0:
                        bpy.data.images.remove(image)


def _remove_object(obj: bpy.types.Object) -> None:
    mesh = obj.data
    bpy.data.objects.remove(obj)
    if isinstance(mesh, bpy.types.Mesh) and mesh.users == 0:
        bpy.data.meshes.remove(mesh)
