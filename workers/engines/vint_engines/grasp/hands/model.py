"""What a hand is, as plain data: a palm box and fingers made of hinge links with round fingertips.

The builder (`grasp/hand.py`) turns a `HandDims` into MuJoCo bodies; the taxel generator
(`grasp/skin.py`) reads the same description back from the compiled model. This module holds no
MuJoCo code and no particular hand (those are `trx3.py` and `allegro.py`).

Frames. The palm frame has its origin at the centre of the palm box, +z along the palm normal (the
palmar face is at z = +palm_half[2] and faces the object), +y "up" across the palm and +x from the
finger edge to the thumb edge. A finger's link frames have +z along the link (the link runs from
its joint at the origin to the next joint at (0, 0, length)) and +x on the palmar side (the side
that curls towards the object and carries the pulp taxels). A `flex` joint turns about the link's
+y, so a positive angle curls +z towards +x; an `abduct` joint turns about the link's +x (the
palmar direction), swinging the finger sideways.

Names: links `palm`, `f{i}_{link}` (e.g. `f0_prox`); joints `f{i}_j{k}`; actuators `f{i}_a{k}`
(k counts from the finger's base). The link that carries the round fingertip is always `f{i}_tip`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Protocol

Vec3 = tuple[float, float, float]
JointKind = Literal["flex", "abduct"]


@dataclass(frozen=True)
class Joint:
    """A position-controlled hinge at a link's origin."""

    kind: JointKind
    range: tuple[float, float]  # rad
    torque: float  # N·m: the actuator's force limit
    kp: float  # N·m/rad: the position servo's gain
    open: float  # rad: target while placing the hand
    closed: float  # rad: target while grasping (beyond contact, so the finger presses)
    # A joint that sets the hand's finger spread (an abduction) instead of closing: each trial
    # draws the spread s in [0, 1] and holds this joint at spread[0] + s · (spread[1] - spread[0])
    # through the pre-grasp and the close; `open` and `closed` are then unused.
    spread: tuple[float, float] | None = None
    # Target while the hand approaches the object (the pre-grasp) when it differs from `open`
    # (the pose the taxel layout is generated in): None means `open`.
    pregrasp: float | None = None


@dataclass(frozen=True)
class Link:
    """One finger link: a capsule of `radius` from its joint to (0, 0, length), of `mass` kg."""

    name: str
    length: float
    radius: float
    mass: float
    joint: Joint


@dataclass(frozen=True)
class Finger:
    """A chain of links leaving the palm at `base` (palm frame). Straight and at zero angles, the
    finger grows along `grow` and its palmar side faces `palmar` (both unit, palm frame)."""

    name: str
    base: Vec3
    grow: Vec3
    palmar: Vec3
    links: tuple[Link, ...]
    tip_radius: float  # the round fingertip: a sphere at the end of the last link
    tip_mass: float


@dataclass(frozen=True)
class HandDims:
    name: str
    palm_half: Vec3  # half extents of the palm box (m)
    palm_mass: float
    fingers: tuple[Finger, ...]
    armature: float  # kg·m², reflected rotor inertia of every joint
    damping: float  # N·m·s/rad, every joint
    # Where on the palmar face (palm x, y) a power grasp centres the object's axis: near the
    # finger bases when the fingers are long next to the palm (the thumb then has room to wrap).
    grasp_centre: tuple[float, float] = (0.0, 0.0)
    # Where the hand meets the robot arm, in the palm frame: a point on the palm's surface and the
    # direction the arm leaves in. Only the renderer reads it (the arm's flange is never simulated).
    mount: tuple[Vec3, Vec3] | None = None

    def __post_init__(self) -> None:
        for finger in self.fingers:
            if not finger.links or finger.links[-1].name != "tip":
                raise ValueError(f"{self.name}.{finger.name}: the last link must be called 'tip'")

    @property
    def dof(self) -> int:
        return sum(len(finger.links) for finger in self.fingers)

    @property
    def mass(self) -> float:
        links = sum(link.mass for finger in self.fingers for link in finger.links)
        return self.palm_mass + links + sum(finger.tip_mass for finger in self.fingers)

    def joints(self) -> list[tuple[str, Joint]]:
        """Every joint with its name, finger by finger, base to tip (the actuator order)."""
        return [
            (f"f{i}_j{k}", link.joint)
            for i, finger in enumerate(self.fingers)
            for k, link in enumerate(finger.links)
        ]

    def joint_names(self) -> list[str]:
        return [name for name, _ in self.joints()]

    def link_names(self) -> list[str]:
        return [
            "palm",
            *(f"f{i}_{link.name}" for i, finger in enumerate(self.fingers) for link in finger.links),
        ]

    def open_pose(self) -> list[float]:
        return [joint.open for _, joint in self.joints()]

    def closed_pose(self) -> list[float]:
        return [joint.closed for _, joint in self.joints()]

    def pregrasp_pose(self) -> list[float]:
        return [joint.open if joint.pregrasp is None else joint.pregrasp for _, joint in self.joints()]

    def spread_ranges(self) -> list[tuple[float, float] | None]:
        return [joint.spread for _, joint in self.joints()]

    @property
    def finger_count(self) -> int:
        return len(self.fingers)

    def reach(self) -> float:
        """The longest finger's length, base joint to fingertip."""
        return max(sum(link.length for link in f.links) + f.tip_radius for f in self.fingers)

    def close_phases(self) -> list[float]:
        """Per joint (actuator order), when it starts closing: 0 at a finger's base, 1 at its tip."""
        return [k / max(1, len(f.links) - 1) for f in self.fingers for k in range(len(f.links))]

    def fingertips(self) -> list[str]:
        return [f"f{i}_tip" for i in range(len(self.fingers))]

    def fingertip_radius(self) -> float:
        return min(finger.tip_radius for finger in self.fingers)


class GraspHand(Protocol):
    """What a grasp trial reads of a hand: a built-in `HandDims` or a user's `mjcf.MjcfHand`.

    `palm_half` bounds the palm in the palm frame (the palmar face at z = palm_half[2]);
    `grasp_centre` is where on that face a power grasp centres the object; `reach` is the longest
    finger's length (the scale of standoffs); `close_phases` orders the staggered close. Poses and
    phases follow `joint_names()`; `link_names()` starts with `palm`.
    """

    @property
    def name(self) -> str: ...
    @property
    def palm_half(self) -> Vec3: ...
    @property
    def grasp_centre(self) -> tuple[float, float]: ...
    @property
    def mount(self) -> tuple[Vec3, Vec3] | None:
        """Where the arm meets the palm (point, direction; palm frame), if the hand says."""
        ...

    @property
    def dof(self) -> int: ...
    @property
    def finger_count(self) -> int: ...
    def link_names(self) -> list[str]: ...
    def joint_names(self) -> list[str]: ...
    def open_pose(self) -> list[float]: ...
    def closed_pose(self) -> list[float]: ...
    def pregrasp_pose(self) -> list[float]:
        """Joint targets while the hand approaches; the closing path starts from it."""
        ...

    def spread_ranges(self) -> list[tuple[float, float] | None]:
        """Per joint: the angles (rad) between which a trial's finger spread sets it, or None for
        a joint that follows the closing path."""
        ...

    def reach(self) -> float: ...
    def close_phases(self) -> list[float]: ...
    def fingertips(self) -> list[str]:
        """The links at the ends of the fingers."""
        ...

    def fingertip_radius(self) -> float:
        """The smallest fingertip's radius."""
        ...
