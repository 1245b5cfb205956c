"""A user's mesh as the render engine shows it: the same surface as the model (`model.py`: welded
by position, in the object frame, outward) with what its file says about its colour — texture
coordinates and a base-colour image (OBJ + MTL + PNG/JPEG, PLY with BOP's `comment TextureFile`
and `texture_u/texture_v` or `s/t`, glTF/GLB), or vertex or face colours.

The render task stages the user's original files (the mesh and the sidecars its spec entry
lists) for this; the grasp engine's `object.ply` keeps geometry alone. trimesh reads references
from those files only (`meshio.SidecarResolver`). Must not import Blender.
"""

from __future__ import annotations

import posixpath
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
import trimesh

from vint_engines.objects import meshio

Array = npt.NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class SurfaceLook:
    """The object's surface with its colour: welded positions (metres, object frame), outward
    triangles, and per corner (triangle × 3) either texture coordinates into `image` or colours."""

    vertices: Array
    faces: npt.NDArray[np.int64]
    corner_uv: Array | None  # (faces, 3, 2); v up, as OBJ and Blender count it
    image: npt.NDArray[np.uint8] | None  # (height, width, 4) RGBA, top row first
    corner_colours: Array | None  # (faces, 3, 4) sRGB in 0..1


@dataclass(frozen=True)
class MeshSource:
    """Where a user's textured mesh was staged: the mesh file, its unit scale, and its sidecars by
    the name the mesh's references use (a path relative to the mesh's directory in the spec).
    `key` (the files' SHA-256s) identifies the content."""

    path: Path
    scale: float
    sidecars: tuple[tuple[str, Path], ...]
    key: str

    @staticmethod
    def staged(
        mesh_path: Path, mesh_spec_path: str, scale: float, files: Mapping[str, tuple[str, Path]]
    ) -> MeshSource:
        """From the staged mesh (`mesh_spec_path` as the spec names it) and the other staged files
        (SHA-256 → (spec path, staged path))."""
        base = posixpath.dirname(mesh_spec_path)
        sidecars = tuple(
            sorted((posixpath.relpath(spec_path, base or "."), path) for spec_path, path in files.values())
        )
        return MeshSource(mesh_path, scale, sidecars, ",".join(sorted(files)))

    def load(self, where: str) -> SurfaceLook:
        return load_look(self.path, self.scale, where, dict(self.sidecars))


def load_look(path: Path, scale: float, where: str, sidecars: Mapping[str, Path]) -> SurfaceLook:
    """The mesh file's surface and colour, placed in the object frame as `model.build_model`
    places its model (bounding-box centre), triangles turned outward as `meshio.load_mesh` turns
    them."""
    loaded = meshio.read_scene(path, where, sidecars)
    raw = np.asarray(loaded.vertices, dtype=np.float64)
    split_faces = np.asarray(loaded.faces, dtype=np.int64)
    faces = meshio.weld(raw)[split_faces]
    keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    faces, split_faces = faces[keep], split_faces[keep]
    used, compact = np.unique(faces, return_inverse=True)
    vertices = raw[used] * scale
    faces = compact.reshape(-1, 3)
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    vertices = vertices - (low + high) / 2
    corner_uv, image = _texture(loaded.visual)
    corner_uv = corner_uv[split_faces] if corner_uv is not None else None
    colours = None
    if image is None and isinstance(loaded.visual, trimesh.visual.ColorVisuals):
        if loaded.visual.kind == "vertex":
            colours = _unit(loaded.visual.vertex_colors)[split_faces]
        elif loaded.visual.kind == "face":
            colours = _unit(loaded.visual.face_colors)[keep][:, None, :].repeat(3, axis=1)
    if meshio._signed_volume(vertices, faces) < 0:  # inside out: flip every triangle with its corners
        faces = faces[:, ::-1].copy()
        corner_uv = corner_uv[:, ::-1].copy() if corner_uv is not None else None
        colours = colours[:, ::-1].copy() if colours is not None else None
    return SurfaceLook(vertices, faces, corner_uv, image, colours)


def _texture(visual: trimesh.visual.base.Visuals) -> tuple[Array | None, npt.NDArray[np.uint8] | None]:
    """Per-vertex texture coordinates and the base-colour image, when the file has both."""
    if not isinstance(visual, trimesh.visual.TextureVisuals) or visual.uv is None:
        return None, None
    material = visual.material
    picture = getattr(material, "baseColorTexture", None) or getattr(material, "image", None)
    if picture is None:
        return None, None
    image = np.asarray(picture.convert("RGBA"), dtype=np.uint8)
    return np.asarray(visual.uv, dtype=np.float64)[:, :2], image


def _unit(rgba: npt.ArrayLike) -> Array:
    """Colours as bytes to sRGB in 0..1."""
    return np.asarray(rgba, dtype=np.float64)[:, :4] / 255.0
