"""What the camera sees besides the object and the hand's physics primitives: the hand's look, the
robot arm's flange at its wrist, and the table under the grasp. Plain data and numbers here; the
Blender objects are made by `scene.py`.

The hand's look. Physics keeps its primitives; the render dresses them as the real hands are
built: the palm box becomes a housing with rounded edges (`PALM_EDGE_RADIUS_M`), the links are
black anodised aluminium, and the round fingertips are pale, soft pads (the Allegro Hand v4's
fingertips are white elastomer over black links, per Wonik's product photographs; the Trx hand
follows the same scheme). The shapes stay within the physics primitives, so depth and segmentation
still match them to a fraction of a millimetre (the rounded edges move inwards by at most
r·(1 - 1/√2) ≈ 1.2 mm at a box's edge).

The sensor skin. The hands carry whole-hand taxel arrays (fingertips, pulps, palm: VinT-6D's
sensors); where the hand's taxel layout is a built-in one (`catalog/hands/<hand>/taxels.csv`,
named and hashed by grasps.json's `hand.taxels`), each taxel is drawn as a dark sensing element, a
disc of `TAXEL_RADIUS_M` standing `2 · TAXEL_HALF_HEIGHT_M` proud of the link surface, in the
link's own mesh and label. A user's layout is not staged for rendering, so its hand is drawn
without them. (An earlier skin made of bmesh's cones made a link's depth differ by one ULP at a
few pixels between a warm and a fresh engine — the same cause as the spheres': bmesh's face order
varied between processes. `meshes.add_discs` builds every disc vertex by vertex in a fixed order.)

The flange. A robot hand is never seen floating: it hangs off an arm. Each built-in hand names its
mount (where its wrist meets the arm, and the direction the arm leaves in, in the palm frame:
`mount` in grasps.json's hand); the renderer puts an ISO 9409-1-50-4-M6 tool flange there (Ø 63 mm
plate, 10 mm thick — the flange of most 5 kg-class arms) and the arm's last link behind it, a
Ø 75 mm, 100 mm painted cylinder (the size of a UR5-class wrist; no particular arm is claimed).
Both are seen, cast shadows, occlude the object, and are labelled in the segmentation
(`arm/flange`, `arm/link`); the physics never sees them (the grasp happens in free space).

The table. A wooden table top (`TABLE_SIZE_M`, 30 mm thick, procedural wood grain along its
length) lies level under the grasp, `table_gap_m` below the lowest point of the hand, the object
and the arm pieces, centred under the object; it catches their shadows and appears in depth and
segmentation (`scene/table`). It never hides the object from a camera above its top, which is every
camera of the default elevations; a camera at or below the top sees no table (the record says so).
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from vint_engines.grasp.taxels import TaxelLayout, parse_layout
from vint_engines.objects.catalog import CATALOG_DIR
from vint_engines.protocol import BadInput

Vec = npt.NDArray[np.float64]

PALM_EDGE_RADIUS_M = 0.004
TAXEL_RADIUS_M = 0.0018
TAXEL_HALF_HEIGHT_M = 0.0002
TABLE_SIZE_M = (1.6, 1.0, 0.03)
FLANGE_RADIUS_M = 0.0315
FLANGE_LENGTH_M = 0.010
ARM_LINK_RADIUS_M = 0.0375
ARM_LINK_LENGTH_M = 0.100

# Principled BSDF inputs of the dressed pieces.
ANODISED_BLACK = {
    "Base Color": (0.018, 0.018, 0.02, 1.0),
    "Metallic": 0.0,
    "Roughness": 0.5,
    "Specular IOR Level": 0.35,
}
FINGERTIP_PAD = {"Base Color": (0.78, 0.77, 0.72, 1.0), "Metallic": 0.0, "Roughness": 0.7}
TAXEL_SKIN = {"Base Color": (0.035, 0.05, 0.09, 1.0), "Metallic": 0.0, "Roughness": 0.55}
FLANGE_ALUMINIUM = {"Base Color": (0.8, 0.8, 0.82, 1.0), "Metallic": 1.0, "Roughness": 0.32}
ARM_PAINT = {"Base Color": (0.12, 0.125, 0.13, 1.0), "Metallic": 0.0, "Roughness": 0.5}
# The table: oiled oak-like wood (linear RGB), grain bands about 1 cm apart.
TABLE_WOOD = {"Metallic": 0.0, "Roughness": 0.55, "Specular IOR Level": 0.4}
TABLE_WOOD_LIGHT = (0.46, 0.3, 0.16, 1.0)
TABLE_WOOD_DARK = (0.24, 0.13, 0.06, 1.0)
TABLE_GRAIN = {
    "Scale": 20.0,
    "Distortion": 25.0,
    "Detail": 3.0,
    "Detail Scale": 0.5,
    "Detail Roughness": 0.55,
}
TABLE_GRAIN_STRETCH = (0.12, 1.0, 1.0)

# Material tags for the depth-noise model (catalog tags), by segmentation label. The hand's links:
# black anodised links and pale elastomer pads are both diffuse, dark-to-mid surfaces, nearest to
# the catalog's "rubber".
HAND_MATERIAL_TAG = "rubber"
MATERIAL_TAGS = {"arm/flange": "metal", "arm/link": "plastic", "scene/table": "wood"}


@dataclass(frozen=True)
class SceneDressing:
    """`render.scene` of a render task: fields, bounds and defaults are `RenderScene` in the stage
    contract."""

    table: bool = True
    table_gap_m: float = 0.05
    flange: bool = True
    distractors: int = 0  # catalog objects standing on the table around the grasp (`clutter.py`)


@dataclass(frozen=True)
class Mount:
    """Where the arm meets the hand: a point and the direction the arm leaves in, in the frame of
    link `link`."""

    link: str
    point: Vec
    axis: Vec

    @staticmethod
    def parse(obj: Any, links: Sequence[str], where: str) -> Mount:
        try:
            link = str(obj["link"])
            point = np.array(obj["p"], dtype=np.float64)
            axis = np.array(obj["axis"], dtype=np.float64)
        except (KeyError, TypeError, ValueError) as exc:
            raise BadInput(f"{where}: expected link, p (3 numbers) and axis (3 numbers) ({exc!r})") from exc
        if link not in links:
            raise BadInput(f"{where}.link: {link!r} is not a link of the hand ({list(links)})")
        if point.shape != (3,) or axis.shape != (3,) or not np.isfinite([*point, *axis]).all():
            raise BadInput(f"{where}: p and axis must be 3 finite numbers each")
        norm = float(np.linalg.norm(axis))
        if norm < 1e-9:
            raise BadInput(f"{where}.axis: must not be zero")
        return Mount(link, point, axis / norm)


def geom_role(link_name: str, geom: Mapping[str, Any]) -> str:
    """How a hand geom is dressed: `palm` (the housing), `pad` (a fingertip sphere) or `link`."""
    if link_name == "palm" and geom.get("type") == "box":
        return "palm"
    if link_name.endswith("_tip") and geom.get("type") == "sphere":
        return "pad"
    return "link"


ARM_PIECES = ("flange", "link")


def arm_pieces(mount: Mount) -> list[tuple[str, float, float, Vec, Vec]]:
    """The flange and the arm's last link as (name, radius, half length, centre, axis) cylinders in
    the mount link's frame, stacked along the mount's axis from its point."""
    flange_centre = mount.point + mount.axis * FLANGE_LENGTH_M / 2
    link_centre = mount.point + mount.axis * (FLANGE_LENGTH_M + ARM_LINK_LENGTH_M / 2)
    return [
        ("flange", FLANGE_RADIUS_M, FLANGE_LENGTH_M / 2, flange_centre, mount.axis),
        ("link", ARM_LINK_RADIUS_M, ARM_LINK_LENGTH_M / 2, link_centre, mount.axis),
    ]


def built_in_taxels(hand: Mapping[str, Any], links: Sequence[str]) -> TaxelLayout | None:
    """The hand's taxel layout when it is a built-in one whose file matches the hash grasps.json
    cites; None otherwise (a user's layout, or none)."""
    info = hand.get("taxels")
    if not isinstance(info, Mapping) or not isinstance(info.get("layout"), str):
        return None
    path = (CATALOG_DIR / info["layout"]).resolve()
    if CATALOG_DIR.resolve() not in path.parents or not path.is_file():
        return None
    data = path.read_bytes()
    if hashlib.sha256(data).hexdigest() != info.get("sha256"):
        return None
    return parse_layout(data.decode("utf-8"), links, str(path))


def table_top_z(lowest_z: float, gap_m: float) -> float:
    """The table top's height: `gap_m` below the lowest point of everything above it."""
    return lowest_z - gap_m


def camera_sees_table(camera_z: float, top_z: float) -> bool:
    """A camera sees the table top only from above it."""
    return camera_z > top_z + 1e-4
