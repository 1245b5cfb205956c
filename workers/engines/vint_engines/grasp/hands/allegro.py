"""`allegro`: a four-finger, 16-DoF hand built from the Allegro Hand's published geometry.

Sources: Wonik Robotics' Allegro Hand v4 datasheet (16 DoF, ~1.1 kg, ~0.7 N·m joint torque) and
the link lengths, joint limits and link masses published in its ROS description
(`allegro_hand_description`). We model the geometry with primitives of our own, not the vendor's
meshes: the palm is a 95 × 113 × 40.8 mm box (wrist to knuckles × across × thick); a finger is a
16.4 mm abduction link and three phalanges of 54 / 38.4 / 26.7 mm (capsules of radius 9.8 mm, half
the 19.6 mm finger width) ending in a round fingertip of radius 12 mm, so the distal link reaches
~44 mm. Finger joint 0 abducts (±0.47 rad); joints 1–3 flex (-0.196…1.61, -0.174…1.709,
-0.227…1.618 rad). Fingers sit 43.5 mm apart along the knuckle edge, their axes 11.1 mm behind
the palmar face.

Assumptions (ours): the thumb's first joint sits where the real one does, 46 mm from the knuckle
edge and 19 mm off centre on the index side, here on the palmar face; straight, the thumb points
towards the wrist edge. Its joints are a swing out of the palm plane (Allegro joint 12,
0.263…1.396 rad), an abduction (joint 13, -0.105…1.163) and two flexions (joints 14–15,
-0.189…1.644 and -0.162…1.719), over links of 48.5 (the joint 12→13 offset) / 17.7 / 51.4 /
42.3 mm. The index/ring fingers' 5° splay is left out. Link masses are the published ones
(11.9 / 65 / 35.5 / 9.6 g per finger, 17.6 / 11.9 / 38 / 38.8 g for the thumb, 16.8 g per
fingertip); the palm is 0.54 kg so that the hand totals 1.08 kg (the published palm link,
0.415 kg, leaves out the wrist electronics). Inertias are MuJoCo's, inferred from each capsule with
its mass. Servos: kp 4 N·m/rad, torque limit 0.7 N·m; armature 0.002 kg·m² stands for the geared
motors' reflected inertia. A power grasp centres the object 35 mm from the palm's centre towards
the knuckles (`grasp_centre`), across the finger bases, as a hand holds a can: the 54 mm proximal
phalanges then wrap it and the thumb closes on the other side.
"""

from __future__ import annotations

from dataclasses import replace

from vint_engines.grasp.hands.model import Finger, HandDims, Joint, JointKind, Link

RADIUS = 0.0098
TORQUE = 0.7
KP = 4.0
FINGER_Z = 0.0204 - 0.0111  # finger axes lie 11.1 mm behind the palmar face


def _link(
    name: str, length: float, mass: float, kind: JointKind, rng: tuple[float, float], op: float, cl: float
) -> Link:
    return Link(name, length, RADIUS, mass, Joint(kind, rng, TORQUE, KP, op, cl))


# The finger spread (`Joint.spread`) each trial draws: index and ring abduct from slightly together
# (0.1 rad towards the middle finger) to spread apart (0.4 rad, within the ±0.47 rad limits; a
# positive angle turns a finger towards the palm's -y), the middle finger stays straight, and the
# thumb's abduction turns from 0 to 0.5 rad (limits -0.105…1.163).
INDEX_SPREAD = (0.1, -0.4)
THUMB_SPREAD = (0.0, 0.5)

FINGER_LINKS = (
    _link("base", 0.0164, 0.0119, "abduct", (-0.47, 0.47), 0.0, 0.0),
    _link("prox", 0.054, 0.065, "flex", (-0.196, 1.61), 0.0, 1.6),
    _link("mid", 0.0384, 0.0355, "flex", (-0.174, 1.709), 0.0, 1.7),
    _link("tip", 0.0267, 0.0096, "flex", (-0.227, 1.618), 0.0, 1.6),
)
THUMB_LINKS = (
    _link("base", 0.0485, 0.0176, "flex", (0.263, 1.396), 0.263, 1.396),
    _link("prox", 0.0177, 0.0119, "abduct", (-0.105, 1.163), 0.0, 0.0),
    _link("mid", 0.0514, 0.038, "flex", (-0.189, 1.644), 0.0, 1.6),
    _link("tip", 0.0423, 0.0388, "flex", (-0.162, 1.719), 0.0, 1.7),
)


def _spread(link: Link, spread: tuple[float, float] | None) -> Link:
    return replace(link, joint=replace(link.joint, spread=spread))


def _finger(name: str, y: float, spread: tuple[float, float] | None) -> Finger:
    return Finger(
        name=name,
        base=(-0.0475, y, FINGER_Z),
        grow=(-1.0, 0.0, 0.0),
        palmar=(0.0, 0.0, 1.0),
        links=(_spread(FINGER_LINKS[0], spread), *FINGER_LINKS[1:]),
        tip_radius=0.012,
        tip_mass=0.0168,
    )


ALLEGRO = HandDims(
    name="allegro",
    palm_half=(0.0475, 0.0565, 0.0204),
    palm_mass=0.54,
    fingers=(
        _finger("index", 0.0435, INDEX_SPREAD),
        _finger("middle", 0.0, None),
        _finger("ring", -0.0435, (-INDEX_SPREAD[0], -INDEX_SPREAD[1])),
        Finger(
            name="thumb",
            base=(-0.0015, 0.019, 0.0204),
            grow=(1.0, 0.0, 0.0),
            palmar=(0.0, 0.0, 1.0),
            links=(THUMB_LINKS[0], _spread(THUMB_LINKS[1], THUMB_SPREAD), *THUMB_LINKS[2:]),
            tip_radius=0.012,
            tip_mass=0.0168,
        ),
    ),
    armature=0.002,
    damping=0.1,
    grasp_centre=(-0.035, 0.0),
    # The wrist: the palm's edge opposite the knuckles, where the Allegro's mount plate meets the arm.
    mount=((0.0475, 0.0, 0.0), (1.0, 0.0, 0.0)),
)
