"""The Blender scene of the render engine: built once, then only moved.

Owns all Blender datablocks: render settings, the world (one environment texture node whose image
is swapped between bundled HDRIs, each loaded once), one camera, the hand's link objects (rebuilt
only when the hand geometry changes) and the object: one Blender object whose mesh is swapped
between object meshes, each made once per object name (with its material) from the grasp engine's
model PLY or, without one, from the shape in the catalog entry. Knows nothing about tasks or files
beyond the pass scratch directory and the model PLY it is handed.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import addon_utils
import bpy
import numpy as np
from mathutils import Matrix

from vint_engines.objects import ObjectSpec, build_model
from vint_engines.objects.meshio import read_ply_m
from vint_engines.poses import pose_matrix
from vint_engines.protocol import BadInput
from vint_engines.render import materials, meshes
from vint_engines.render.camera import CameraPose, Intrinsics
from vint_engines.render.passes import Passes, add_pass_outputs, read_passes

OBJECT_PASS_INDEX = 1
HAND_PASS_INDEX = 2
RGB_FILE = "rgb.png"
ENVIRONMENT_MAP_RESOLUTION = 256  # importance map for the HDRI: 0.3 s to build instead of ~2 s
OBJECT_MESH_CAPACITY = 64  # object meshes kept for reuse (the catalog has fewer objects)
SHARP_EDGE_DEG = 30.0  # model meshes shade smooth except across edges sharper than this


def environment_dir() -> Path:
    return Path(bpy.utils.system_resource("DATAFILES", path="studiolights/world"))


def environments() -> list[str]:
    return sorted(path.stem for path in environment_dir().glob("*.exr"))


def check_environment(name: str, where: str) -> None:
    """BadInput unless `name` is a bundled HDRI; `where` names the parameter in the message."""
    if name not in environments():  # a name, never a path
        raise BadInput(f"{where}: unknown environment {name!r} (have {environments()})")


class BlenderScene:
    def __init__(self, scratch: Path) -> None:
        self.scratch = scratch
        bpy.ops.wm.read_factory_settings(use_empty=True)
        addon_utils.enable("cycles")
        self.scene = bpy.context.scene
        self._configure_render()
        self.camera = self._add_camera()
        self._environment_node = self._add_world()
        self._environment_images: dict[str, bpy.types.Image] = {}
        self.environment: str | None = None
        add_pass_outputs(self.scene, scratch)
        self._hand_key: str | None = None
        self._links: dict[str, bpy.types.Object] = {}
        self._object: bpy.types.Object | None = None
        self._object_meshes: dict[str, tuple[str, bpy.types.Mesh]] = {}  # name → (content key, mesh)
        self._hand_material = materials.principled("vint_hand", materials.HAND)

    def _configure_render(self) -> None:
        scene = self.scene
        scene.render.engine = "CYCLES"
        scene.cycles.device = "CPU"
        scene.cycles.use_denoising = False
        scene.cycles.use_adaptive_sampling = False
        scene.cycles.use_animated_seed = False
        scene.render.use_persistent_data = True  # re-renders after moves are several times faster
        scene.render.resolution_percentage = 100
        scene.view_settings.view_transform = "Standard"  # plain sRGB output
        settings = scene.render.image_settings
        settings.media_type = "IMAGE"
        settings.file_format = "PNG"
        settings.color_mode = "RGB"
        settings.color_depth = "8"

    def _add_camera(self) -> bpy.types.Object:
        data = bpy.data.cameras.new("vint_camera")
        data.sensor_fit = "HORIZONTAL"
        data.clip_start = 0.01
        data.clip_end = 100.0
        camera = bpy.data.objects.new("vint_camera", data)
        self.scene.collection.objects.link(camera)
        self.scene.camera = camera
        return camera

    def _add_world(self) -> bpy.types.ShaderNodeTexEnvironment:
        world = bpy.data.worlds.new("vint_world")
        world.use_nodes = True
        world.cycles.sampling_method = "MANUAL"
        world.cycles.sample_map_resolution = ENVIRONMENT_MAP_RESOLUTION
        tree = world.node_tree
        node = tree.nodes.new("ShaderNodeTexEnvironment")
        tree.links.new(node.outputs["Color"], tree.nodes["Background"].inputs["Color"])
        self.scene.world = world
        return node

    # -- scene content ---------------------------------------------------------------------------

    def set_environment(self, name: str) -> None:
        """Light the scene with the bundled HDRI `name`. Each HDRI is loaded on first use and kept,
        so switching between views only swaps the texture's image."""
        if name == self.environment:
            return
        image = self._environment_images.get(name)
        if image is None:
            check_environment(name, "environment")
            image = bpy.data.images.load(str(environment_dir() / f"{name}.exr"), check_existing=True)
            self._environment_images[name] = image
        self._environment_node.image = image
        self.environment = name

    def set_hand(self, hand: Mapping[str, Any]) -> None:
        """Create the hand's link objects, unless this exact geometry is already loaded."""
        key = json.dumps(hand.get("links"), sort_keys=True)
        if key == self._hand_key:
            return
        for obj in self._links.values():
            _remove_object(obj)
        self._links, self._hand_key = {}, None
        try:
            for link in hand["links"]:
                geoms = [(g["type"], g["size"], meshes.geom_matrix(g["p"], g["q"])) for g in link["geoms"]]
                obj = self._add_object(f"link_{link['name']}", geoms, self._hand_material, HAND_PASS_INDEX)
                self._links[link["name"]] = obj
        except (KeyError, TypeError, ValueError) as exc:
            raise BadInput(f"grasps.json: malformed hand geometry ({exc!r})") from exc
        self._hand_key = key

    def set_object(self, obj: Mapping[str, Any], model_ply: Path | None = None) -> None:
        """Show the object of a grasps.json entry: its model mesh `model_ply` (the grasp engine's
        object.ply, millimetres) when given, else its shape rebuilt from the entry — the same mesh
        either way. Each object name keeps its mesh and material; they are remade only when the
        mesh bytes or the entry's shape or material change."""
        spec = ObjectSpec.parse(obj, "grasps.json object")
        source = hashlib.sha256(model_ply.read_bytes()).hexdigest() if model_ply else spec.to_json()
        key = json.dumps({"mesh": source, "material": spec.material}, sort_keys=True)
        cached = self._object_meshes.pop(spec.name, None)  # re-inserted last: least recently used first
        if cached is not None and cached[0] == key:
            mesh = cached[1]
        else:
            vertices, faces = read_ply_m(model_ply) if model_ply else _rebuilt_mesh(spec)
            mesh = meshes.triangle_mesh(f"object_{spec.name}", vertices, faces, SHARP_EDGE_DEG)
            mesh.materials.append(materials.object_material(spec.name, spec.material))
        self._object_meshes[spec.name] = (key, mesh)
        if self._object is None:
            self._object = bpy.data.objects.new("object", mesh)
            self._object.pass_index = OBJECT_PASS_INDEX
            self.scene.collection.objects.link(self._object)
        else:
            self._object.data = mesh
        if cached is not None and cached[1] is not mesh:
            _remove_mesh(cached[1])
        self._evict_object_meshes()

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

    # -- rendering -------------------------------------------------------------------------------

    def render(
        self, camera: CameraPose, intrinsics: Intrinsics, samples: int, seed: int, rgb: bool
    ) -> Passes:
        """Render one view and return its passes (with the 8-bit sRGB image when `rgb`)."""
        scene = self.scene
        scene.render.resolution_x = intrinsics.width
        scene.render.resolution_y = intrinsics.height
        self.camera.data.angle = math.radians(intrinsics.fov_deg)
        self.camera.matrix_world = Matrix(camera.blender_matrix_world().tolist())
        scene.cycles.samples = samples
        scene.cycles.seed = seed % 2**31  # Cycles takes a 32-bit signed seed
        scene.render.filepath = str(self.scratch / RGB_FILE)
        bpy.ops.render.render(write_still=rgb)
        return read_passes(self.scratch, rgb_file=RGB_FILE if rgb else None)

    # -- helpers ---------------------------------------------------------------------------------

    def _add_object(
        self, name: str, geoms: Sequence[tuple[str, Sequence[float], Matrix]], material: Any, pass_index: int
    ) -> bpy.types.Object:
        mesh = meshes.new_mesh(name, geoms)
        mesh.materials.append(material)
        obj = bpy.data.objects.new(name, mesh)
        obj.pass_index = pass_index
        self.scene.collection.objects.link(obj)
        return obj


def _rebuilt_mesh(spec: ObjectSpec) -> tuple[np.ndarray, np.ndarray]:
    mesh = build_model(spec, where="grasps.json object").mesh
    return mesh.vertices, mesh.faces


def _remove_mesh(mesh: bpy.types.Mesh) -> None:
    """Free an object mesh (and its material) once nothing shows it."""
    if mesh.users == 0:
        used = [m for m in mesh.materials if m is not None]
        bpy.data.meshes.remove(mesh)
        for material in used:
            if material.users == 0:
                bpy.data.materials.remove(material)


def _remove_object(obj: bpy.types.Object) -> None:
    mesh = obj.data
    bpy.data.objects.remove(obj)
    if isinstance(mesh, bpy.types.Mesh) and mesh.users == 0:
        bpy.data.meshes.remove(mesh)
