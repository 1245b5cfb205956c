"""The Blender scene of the render engine: built once, then only moved.

Owns all Blender datablocks: render settings, the world (one environment texture node whose image
is swapped between bundled HDRIs, each loaded once), one camera, the hand's link objects (rebuilt
only when the hand geometry changes) and the object (rebuilt only when its shape changes). Knows
nothing about tasks or files beyond the pass scratch directory.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import addon_utils
import bpy
import numpy as np
from mathutils import Matrix

from vint_engines.poses import pose_matrix
from vint_engines.protocol import BadInput
from vint_engines.render import meshes
from vint_engines.render.camera import CameraPose, Intrinsics
from vint_engines.render.passes import Passes, add_pass_outputs, read_passes

OBJECT_PASS_INDEX = 1
HAND_PASS_INDEX = 2
RGB_FILE = "rgb.png"
ENVIRONMENT_MAP_RESOLUTION = 256  # importance map for the HDRI: 0.3 s to build instead of ~2 s

# Principled BSDF inputs per object material; unknown materials render as plastic.
MATERIALS: dict[str, dict[str, Any]] = {
    "metal": {"Base Color": (0.62, 0.09, 0.07, 1.0), "Metallic": 0.9, "Roughness": 0.3},
    "plastic": {"Base Color": (0.2, 0.35, 0.7, 1.0), "Metallic": 0.0, "Roughness": 0.4},
    "wood": {"Base Color": (0.55, 0.37, 0.2, 1.0), "Metallic": 0.0, "Roughness": 0.7},
    "paper": {"Base Color": (0.85, 0.82, 0.75, 1.0), "Metallic": 0.0, "Roughness": 0.9},
}
HAND_MATERIAL = {"Base Color": (0.08, 0.08, 0.09, 1.0), "Metallic": 0.0, "Roughness": 0.55}


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
        self._object_key: str | None = None
        self._object: bpy.types.Object | None = None
        self._hand_material = _material("vint_hand", HAND_MATERIAL)
        self._object_materials: dict[str, bpy.types.Material] = {}

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

    def set_object(self, obj: Mapping[str, Any]) -> None:
        """Create the object, unless this exact shape is already loaded (frame: centre, axis +z)."""
        key = json.dumps(obj, sort_keys=True)
        if key == self._object_key:
            return
        if self._object is not None:
            _remove_object(self._object)
            self._object, self._object_key = None, None
        if obj.get("shape") != "cylinder":
            raise BadInput(f"grasps.json: object shape {obj.get('shape')!r} cannot be rendered")
        try:
            size = [float(obj["radius"]), float(obj["height"]) / 2]
        except (KeyError, TypeError, ValueError) as exc:
            raise BadInput(f"grasps.json: object needs radius and height ({exc!r})") from exc
        material = self._object_material(str(obj.get("material", "plastic")))
        self._object = self._add_object("object", [("cylinder", size, Matrix())], material, OBJECT_PASS_INDEX)
        self._object_key = key

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

    def _object_material(self, name: str) -> bpy.types.Material:
        kind = name if name in MATERIALS else "plastic"
        if kind not in self._object_materials:
            self._object_materials[kind] = _material(f"vint_{kind}", MATERIALS[kind])
        return self._object_materials[kind]


def _material(name: str, inputs: Mapping[str, Any]) -> bpy.types.Material:
    material = bpy.data.materials.new(name)
    material.use_nodes = True
    bsdf = material.node_tree.nodes["Principled BSDF"]
    for key, value in inputs.items():
        bsdf.inputs[key].default_value = value
    return material


def _remove_object(obj: bpy.types.Object) -> None:
    mesh = obj.data
    bpy.data.objects.remove(obj)
    if isinstance(mesh, bpy.types.Mesh) and mesh.users == 0:
        bpy.data.meshes.remove(mesh)
