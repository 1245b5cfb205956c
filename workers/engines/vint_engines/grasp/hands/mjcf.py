"""A user's hand from an MJCF model: loaded, checked against vint's hand conventions
(`docs/hands.md`) and described as the trial code needs it.

The model is compiled on its own first, so every value read here is MuJoCo's final one (radians,
`fromto` resolved, inertias computed); `grasp/hand.py` then copies the palm's subtree from the
compiled model into the scene. Conventions, each checked (a violation is `BadInput` naming it):

- The worldbody holds one body, `palm`, without joints, in the palm frame of the built-in hands
  (`model.py`: +z the palm normal towards the object, +y up across the palm, +x from the finger
  edge to the thumb edge). Its pose in the file is ignored: the arm places it.
- Every other joint is a limited hinge in the palm's subtree, driven by exactly one position
  actuator (`<position>`) with a force limit (`forcerange`); no other actuators, tendons or
  equality constraints.
- Geoms are primitives (box, sphere, capsule, cylinder) or meshes. A geom with `contype` and
  `conaffinity` both 0 is visual (the renderer draws those when the hand has any); every other
  geom collides — a mesh through MuJoCo's convex hull of it — and carries the skin. A mesh's file
  (`<mesh file=…>`, found as MuJoCo does, through `meshdir`/`assetdir` and `strippath`, relative to
  the MJCF) is one of the job's files, staged with the MJCF (`mjcf_files.mesh_file_path` is the
  rule; the client follows the same one, `services/vintctl/src/mjcf.rs`). Textures are dropped (a
  material keeps its rgba). Any other file reference (includes, models, height fields, skins),
  a path that leaves the spec's directory and a DOCTYPE are refused before MuJoCo reads the text
  (`mjcf_files.py`).
- Optional `<custom><numeric>` entries: `vint_open` and `vint_closed` (one target per hinge, in
  the model's joint order; default: each actuator's ctrlrange low and high end), `vint_grasp_centre`
  (x y on the palmar face; default 0 0), `vint_palm_half` (half extents; default: the palm geoms'
  bounding box, the palmar face at its +z side) and `vint_finger_length` (m; default: the farthest
  geom point of a finger from its base).
"""

from __future__ import annotations

import dataclasses
import math
import posixpath
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from vint_engines.grasp.hands.mjcf_files import check_references, mesh_file_path
from vint_engines.grasp.hands.model import Vec3
from vint_engines.protocol import BadInput

PRIMITIVES = {
    int(mujoco.mjtGeom.mjGEOM_BOX): "box",
    int(mujoco.mjtGeom.mjGEOM_SPHERE): "sphere",
    int(mujoco.mjtGeom.mjGEOM_CAPSULE): "capsule",
    int(mujoco.mjtGeom.mjGEOM_CYLINDER): "cylinder",
}
GEOM_TYPES = {**PRIMITIVES, int(mujoco.mjtGeom.mjGEOM_MESH): "mesh"}
MESH_EXTENSIONS = (".stl", ".obj", ".msh")
# Names the scene gives its own elements.
RESERVED_BODIES = ("object", "hand_target")
RESERVED_JOINTS = ("object_free", "hand_free")
NUMERICS = ("vint_open", "vint_closed", "vint_grasp_centre", "vint_palm_half", "vint_finger_length")


@dataclass(frozen=True, eq=False)
class MjcfHand:
    """A user's hand: its compiled MJCF model and what a trial reads of a hand (see
    `model.GraspHand`). `links` is the palm then its subtree in model order; `joints` are the
    hinges in model order, which is also the order of `open`, `closed` and `phases`."""

    name: str
    model: mujoco.MjModel
    palm_half: Vec3
    grasp_centre: tuple[float, float]
    links: tuple[str, ...]
    joints: tuple[str, ...]
    open: tuple[float, ...]
    closed: tuple[float, ...]
    ctrl_ranges: tuple[tuple[float, float], ...]  # each actuator's control range (its joint's when unset)
    phases: tuple[float, ...]
    finger_count: int
    finger_length: float
    tips: tuple[str, ...]  # the last body of every chain
    tip_radius: float  # the smallest fingertip geom's radius (a box's or mesh's smallest half extent)
    mount: tuple[Vec3, Vec3] | None = None  # a user's hand shows no arm flange
    mesh_files: tuple[str, ...] = ()  # spec paths of the mesh files the model read

    @property
    def dof(self) -> int:
        return len(self.joints)

    def link_names(self) -> list[str]:
        return list(self.links)

    def joint_names(self) -> list[str]:
        return list(self.joints)

    def open_pose(self) -> list[float]:
        return list(self.open)

    def closed_pose(self) -> list[float]:
        return list(self.closed)

    def pregrasp_pose(self) -> list[float]:
        return list(self.open)

    def spread_ranges(self) -> list[tuple[float, float] | None]:
        return [None] * len(self.joints)  # every hinge follows the closing path

    def reach(self) -> float:
        return self.finger_length

    def close_phases(self) -> list[float]:
        return list(self.phases)

    def fingertips(self) -> list[str]:
        return list(self.tips)

    def fingertip_radius(self) -> float:
        return self.tip_radius

    def visual_geoms(self) -> list[int]:
        """Geoms that take part in no contact (`contype` = `conaffinity` = 0): drawn, not felt."""
        return [g for g in range(self.model.ngeom) if is_visual(self.model, g)]

    def bodies(self) -> list[int]:
        """Body ids of the links in the compiled user model (parents before children)."""
        return [self.model.body(link).id for link in self.links]

    def actuator_of(self, joint: int) -> int:
        """The actuator driving hinge `joint` (ids in the user model)."""
        trn = self.model.actuator_trnid[:, 0]
        return int(np.flatnonzero(trn == joint)[0])


def load_mjcf_hand(
    name: str, xml: str, where: str, mjcf_path: str = "", files: Mapping[str, Path] | None = None
) -> MjcfHand:
    """Load and check a hand MJCF document; `where` names it in errors (e.g. `params.hand.mjcf`).
    `mjcf_path` is the document's path as the spec names it and `files` the job's staged files by
    their spec paths: a `<mesh file=…>` is looked up there (`mesh_file_path`); nothing else that
    names a file is read (`check_references`, before MuJoCo parses the text)."""
    check_references(xml, where, mjcf_path)
    try:
        spec = mujoco.MjSpec.from_string(xml)
    except Exception as exc:  # MuJoCo raises ValueError and others on malformed XML
        raise BadInput(f"{where}: not a valid MJCF model: {exc}") from exc
    _drop_textures(spec)
    used = _stage_meshes(spec, where, mjcf_path, files or {})
    try:
        model = spec.compile()
    except Exception as exc:
        raise BadInput(f"{where}: MuJoCo cannot compile the model: {exc}") from exc
    return dataclasses.replace(describe(name, model, where), mesh_files=tuple(sorted(set(used))))


def _drop_textures(spec: mujoco.MjSpec) -> None:
    """Textures are not carried: materials keep their rgba, which is what the renderer paints."""
    for material in spec.materials:
        material.textures = [""] * len(material.textures)
    for texture in list(spec.textures):
        spec.delete(texture)


def _stage_meshes(spec: mujoco.MjSpec, where: str, mjcf_path: str, files: Mapping[str, Path]) -> list[str]:
    """Point every mesh file at the staged file its spec path names, through MuJoCo's in-memory
    assets (the staged file is named by its hash; the name MuJoCo sees keeps the extension)."""
    assets: dict[str, bytes] = {}
    used = []
    for i, mesh in enumerate(spec.meshes):
        if not mesh.file:
            continue
        path = mesh_file_path(mjcf_path, spec.meshdir, mesh.file, bool(spec.strippath))
        if path is None:
            raise BadInput(
                f"{where}: mesh {mesh.name!r} names {mesh.file!r} (meshdir {spec.meshdir!r}), which "
                "leaves the spec's directory; a hand's mesh files lie beside or below the spec"
            )
        if not path.lower().endswith(MESH_EXTENSIONS):
            raise BadInput(f"{where}: mesh {mesh.name!r}: {path!r} is not one of {list(MESH_EXTENSIONS)}")
        if path not in files:
            raise BadInput(f"{where}: mesh {mesh.name!r} names {path!r}, which the task did not stage")
        staged = f"vint_mesh_{i}{posixpath.splitext(path)[1].lower()}"
        assets[staged] = files[path].read_bytes()
        mesh.file = staged
        used.append(path)
    spec.meshdir = ""
    spec.strippath = False
    spec.assets = assets
    return used


def describe(name: str, model: mujoco.MjModel, where: str) -> MjcfHand:
    palm = _palm(model, where)
    subtree = [b for b in range(model.nbody) if _under(model, b, palm)]
    links = tuple(model.body(b).name for b in subtree)
    _check_names(model, subtree, where)
    _check_geoms(model, subtree, where)
    if model.ntendon or model.neq:
        raise BadInput(f"{where}: tendons and equality constraints are not supported in a hand")
    if model.body_jntnum[palm]:
        raise BadInput(f"{where}: body 'palm' must have no joint (the arm moves the palm)")
    if model.body_mass[palm] <= 0:
        raise BadInput(f"{where}: body 'palm' has no mass (give it geoms or an <inertial>)")
    joints = list(range(model.njnt))
    for j in joints:
        _check_joint(model, j, where)
    _check_actuators(model, where)
    numerics = _numerics(model, where)
    ctrl = {
        int(model.actuator_trnid[a, 0]): model.actuator_ctrlrange[a]
        if model.actuator_ctrllimited[a]
        else model.jnt_range[int(model.actuator_trnid[a, 0])]
        for a in range(model.nu)
    }
    open_pose = _targets(numerics, "vint_open", [float(ctrl[j][0]) for j in joints], model, where)
    closed_pose = _targets(numerics, "vint_closed", [float(ctrl[j][1]) for j in joints], model, where)
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    roots = [b for b in subtree if model.body_parentid[b] == palm and _joints_below(model, b)]
    tips = [b for b in subtree if b != palm and not np.any(model.body_parentid == b)]
    radii = [
        _radius(model, g)
        for g in range(model.ngeom)
        if int(model.geom_bodyid[g]) in tips and not is_visual(model, g)
    ]
    return MjcfHand(
        name=name,
        model=model,
        palm_half=_vec3(numerics, "vint_palm_half", where) or _palm_half(model, palm, where),
        grasp_centre=_pair(numerics, "vint_grasp_centre", where),
        links=links,
        joints=tuple(model.joint(j).name for j in joints),
        open=tuple(open_pose),
        closed=tuple(closed_pose),
        ctrl_ranges=tuple((float(ctrl[j][0]), float(ctrl[j][1])) for j in joints),
        phases=tuple(_phase(model, j, palm) for j in joints),
        finger_count=len(roots),
        finger_length=_finger_length(numerics, model, data, roots, where),
        tips=tuple(model.body(b).name for b in tips),
        tip_radius=min(radii, default=0.0),
    )


def is_visual(model: mujoco.MjModel, geom: int) -> bool:
    return not model.geom_contype[geom] and not model.geom_conaffinity[geom]


def _radius(model: mujoco.MjModel, geom: int) -> float:
    kind = int(model.geom_type[geom])
    if kind == mujoco.mjtGeom.mjGEOM_MESH:
        return float(min(model.geom_aabb[geom, 3:]))
    size = model.geom_size[geom]
    return float(min(size) if kind == mujoco.mjtGeom.mjGEOM_BOX else size[0])


def _palm(model: mujoco.MjModel, where: str) -> int:
    try:
        palm = model.body("palm").id
    except KeyError:
        raise BadInput(f"{where}: no body named 'palm' (the hand's root body)") from None
    others = [model.body(b).name for b in range(1, model.nbody) if model.body_parentid[b] == 0 and b != palm]
    if model.body_parentid[palm] != 0 or others:
        raise BadInput(f"{where}: the worldbody must hold exactly one body, 'palm' (also found {others})")
    if np.any(model.geom_bodyid == 0):
        raise BadInput(f"{where}: the worldbody must hold no geoms of its own (only the palm body)")
    return palm


def _under(model: mujoco.MjModel, body: int, root: int) -> bool:
    while body != 0:
        if body == root:
            return True
        body = int(model.body_parentid[body])
    return False


def _check_names(model: mujoco.MjModel, bodies: list[int], where: str) -> None:
    for b in bodies:
        name = model.body(b).name
        if not name or name in RESERVED_BODIES:
            raise BadInput(f"{where}: body {b} needs a name other than {list(RESERVED_BODIES)}, got {name!r}")
    for j in range(model.njnt):
        name = model.joint(j).name
        if not name or name in RESERVED_JOINTS:
            raise BadInput(
                f"{where}: joint {j} needs a name other than {list(RESERVED_JOINTS)}, got {name!r}"
            )


def _check_geoms(model: mujoco.MjModel, bodies: list[int], where: str) -> None:
    for g in range(model.ngeom):
        if int(model.geom_type[g]) not in GEOM_TYPES:
            kind = mujoco.mjtGeom(int(model.geom_type[g])).name.removeprefix("mjGEOM_").lower()
            body = model.body(int(model.geom_bodyid[g])).name
            raise BadInput(
                f"{where}: geom {g} of body {body!r} is a {kind}; hand geoms must be one of "
                f"{sorted(GEOM_TYPES.values())}"
            )
        if int(model.geom_bodyid[g]) not in bodies:
            raise BadInput(f"{where}: geom {g} lies outside the palm's subtree")


def _check_joint(model: mujoco.MjModel, j: int, where: str) -> None:
    name = model.joint(j).name
    if model.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE:
        raise BadInput(f"{where}: joint {name!r} is not a hinge (a hand's joints are hinges)")
    if not model.jnt_limited[j]:
        raise BadInput(f'{where}: joint {name!r} needs a range (limited="true")')
    driving = np.flatnonzero(
        (model.actuator_trntype == mujoco.mjtTrn.mjTRN_JOINT) & (model.actuator_trnid[:, 0] == j)
    )
    if len(driving) != 1:
        raise BadInput(
            f"{where}: joint {name!r} must be driven by exactly one position actuator, found {len(driving)}"
        )


def _check_actuators(model: mujoco.MjModel, where: str) -> None:
    for a in range(model.nu):
        name = model.actuator(a).name or f"#{a}"
        if model.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT:
            raise BadInput(f"{where}: actuator {name!r} must drive a joint")
        kp = float(model.actuator_gainprm[a, 0])
        position = (
            model.actuator_dyntype[a] == mujoco.mjtDyn.mjDYN_NONE
            and model.actuator_gaintype[a] == mujoco.mjtGain.mjGAIN_FIXED
            and model.actuator_biastype[a] == mujoco.mjtBias.mjBIAS_AFFINE
            and kp > 0
            and math.isclose(float(model.actuator_biasprm[a, 1]), -kp)
        )
        if not position:
            raise BadInput(f"{where}: actuator {name!r} must be a position actuator (<position kp=…>)")
        low, high = model.actuator_forcerange[a]
        if not model.actuator_forcelimited[a] or not low < 0 < high:
            raise BadInput(f'{where}: actuator {name!r} needs a force limit (forcerange="-f f")')


def _numerics(model: mujoco.MjModel, where: str) -> dict[str, list[float]]:
    out = {}
    for i in range(model.nnumeric):
        numeric = model.numeric(i)
        if numeric.name.startswith("vint_") and numeric.name not in NUMERICS:
            raise BadInput(f"{where}: unknown custom numeric {numeric.name!r} (known: {list(NUMERICS)})")
        out[numeric.name] = [float(v) for v in numeric.data]
    return out


def _targets(
    numerics: dict[str, list[float]], key: str, default: list[float], model: mujoco.MjModel, where: str
) -> list[float]:
    values = numerics.get(key, default)
    if len(values) != model.njnt:
        raise BadInput(
            f"{where}: numeric {key!r} needs one value per hinge ({model.njnt}), got {len(values)}"
        )
    for j, value in enumerate(values):
        low, high = model.jnt_range[j]
        if not low <= value <= high:
            raise BadInput(
                f"{where}: numeric {key!r}: {value} for joint {model.joint(j).name!r} is outside its range "
                f"[{low}, {high}]"
            )
    return values


def _vec3(numerics: dict[str, list[float]], key: str, where: str) -> Vec3 | None:
    values = numerics.get(key)
    if values is None:
        return None
    if len(values) != 3 or min(values) <= 0:
        raise BadInput(f"{where}: numeric {key!r} needs 3 positive values, got {values}")
    return (values[0], values[1], values[2])


def _pair(numerics: dict[str, list[float]], key: str, where: str) -> tuple[float, float]:
    values = numerics.get(key, [0.0, 0.0])
    if len(values) != 2:
        raise BadInput(f"{where}: numeric {key!r} needs 2 values, got {values}")
    return (values[0], values[1])


def _palm_half(model: mujoco.MjModel, palm: int, where: str) -> Vec3:
    """Half extents of the palm geoms' bounding box in the palm frame; z is its palmar (+z) side."""
    corners = []
    for g in np.flatnonzero(model.geom_bodyid == palm):
        if is_visual(model, g):
            continue
        centre, half = model.geom_aabb[g, :3], model.geom_aabb[g, 3:]
        signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
        rotation = np.zeros(9)
        mujoco.mju_quat2Mat(rotation, model.geom_quat[g])
        corners.append((centre + signs * half) @ rotation.reshape(3, 3).T + model.geom_pos[g])
    if not corners:
        raise BadInput(
            f"{where}: body 'palm' has no colliding geoms; give its extent as numeric 'vint_palm_half'"
        )
    points = np.vstack(corners)
    low, high = points.min(axis=0), points.max(axis=0)
    if high[2] <= 0:
        raise BadInput(f"{where}: the palm's geoms lie below its frame's z = 0; +z must be the palm normal")
    return (float(max(-low[0], high[0])), float(max(-low[1], high[1])), float(high[2]))


def _joints_below(model: mujoco.MjModel, root: int) -> bool:
    return any(_under(model, int(model.jnt_bodyid[j]), root) for j in range(model.njnt))


def _phase(model: mujoco.MjModel, joint: int, palm: int) -> float:
    """Where a joint starts closing in the staggered close: 0 at its finger's base, 1 at the last
    joint of the finger's longest chain (as the built-in hands do it)."""
    finger = int(model.jnt_bodyid[joint])
    while model.body_parentid[finger] != palm:
        finger = int(model.body_parentid[finger])

    def depth(j: int) -> int:
        """Hinges on the path from the finger's root to joint j, j excluded."""
        body, count = int(model.jnt_bodyid[j]), 0
        count += int(j - model.body_jntadr[body])  # earlier joints of the same body
        body = int(model.body_parentid[body])
        while _under(model, body, finger):
            count += int(model.body_jntnum[body])
            body = int(model.body_parentid[body])
        return count

    longest = max(depth(j) for j in range(model.njnt) if _under(model, int(model.jnt_bodyid[j]), finger))
    return depth(joint) / max(1, longest)


def _finger_length(
    numerics: dict[str, list[float]], model: mujoco.MjModel, data: mujoco.MjData, roots: list[int], where: str
) -> float:
    if "vint_finger_length" in numerics:
        values = numerics["vint_finger_length"]
        if len(values) != 1 or values[0] <= 0:
            raise BadInput(f"{where}: numeric 'vint_finger_length' needs one positive value, got {values}")
        return values[0]
    if not roots:
        raise BadInput(f"{where}: the palm has no jointed finger")
    reach = 0.0
    for root in roots:
        base = data.xpos[root]
        for g in range(model.ngeom):
            if _under(model, int(model.geom_bodyid[g]), root):
                far = float(np.linalg.norm(data.geom_xpos[g] - base)) + float(model.geom_rbound[g])
                reach = max(reach, far)
    return reach
