"""`trx3`: our three-finger hand (loosely Barrett-like), 8 DoF.

Two fingers on one edge of the palm and an opposing thumb on the other, all growing along the palm
normal and curling in the palm's xz-plane, so a closing hand wraps around an upright cylinder held
against the palm. DoF layout (8): fingers f0 and f1 have three flexion joints each (prox, mid,
tip); the thumb f2 has two (a longer prox and the tip). An earlier 9-DoF version had a three-link
thumb; the opposing thumb of a Barrett-like hand needs no middle joint to wrap a can, and the real
Trx hand is described with 8 actuated joints.

Numbers are our own design, sized for YCB objects: palm 110 × 70 × 24 mm (0.30 kg: aluminium frame
and electronics); finger links are capsules of radius 9 mm, 45/35/25 mm long, 45/30/20 g (each
carries a micro gear-motor), thumb links 55/40 mm, 55/30 g; round fingertips of radius 10 mm (8 g).
Inertias are MuJoCo's, inferred from each capsule with its explicit mass (uniform density). Joint
limits -0.5…1.6 rad (prox), 0…1.9 (mid), 0…1.7 (tip); position servos with kp 6 N·m/rad and torque
limits 0.8/0.6/0.4 N·m (the thumb, which opposes two fingers, is twice as strong). In the
pre-grasp (`Joint.pregrasp`) the proximal joints lean out to their -0.5 rad limit: the fingertips
then stand ~180 mm apart and straddle an object approached from any side (open at -0.25 rad,
130 mm, they landed on a 102 mm can's cap or a mug's side before the palm came near; 2 of 8 such
grasps touched the can). The taxel layout is generated in the open pose.
"""

from __future__ import annotations

from vint_engines.grasp.hands.model import Finger, HandDims, Joint, Link

RADIUS = 0.009
KP = 6.0


# name, length (m), mass (kg), range (rad), torque (N·m), open and closed targets (rad)
LinkRow = tuple[str, float, float, tuple[float, float], float, float, float]


def _finger(x: float, y: float, palmar_x: float, strength: float, links: tuple[LinkRow, ...]) -> Finger:
    return Finger(
        name="thumb" if palmar_x < 0 else "finger",
        base=(x, y, 0.012),
        grow=(0.0, 0.0, 1.0),
        palmar=(palmar_x, 0.0, 0.0),
        links=tuple(
            Link(
                name,
                length,
                RADIUS,
                mass,
                Joint("flex", rng, torque * strength, KP * strength, op, cl, pregrasp=PREGRASP.get(name)),
            )
            for name, length, mass, rng, torque, op, cl in links
        ),
        tip_radius=0.010,
        tip_mass=0.008,
    )


PREGRASP = {"prox": -0.5}

FINGER_LINKS: tuple[LinkRow, ...] = (
    ("prox", 0.045, 0.045, (-0.5, 1.6), 0.8, -0.25, 1.5),
    ("mid", 0.035, 0.030, (0.0, 1.9), 0.6, 0.1, 1.8),
    ("tip", 0.025, 0.020, (0.0, 1.7), 0.4, 0.1, 1.6),
)
THUMB_LINKS: tuple[LinkRow, ...] = (
    ("prox", 0.055, 0.055, (-0.5, 1.6), 0.8, -0.25, 1.5),
    ("tip", 0.040, 0.030, (0.0, 1.9), 0.5, 0.1, 1.8),
)

TRX3 = HandDims(
    name="trx3",
    palm_half=(0.055, 0.035, 0.012),
    palm_mass=0.30,
    fingers=(
        _finger(-0.047, 0.022, 1.0, 1.0, FINGER_LINKS),
        _finger(-0.047, -0.022, 1.0, 1.0, FINGER_LINKS),
        _finger(0.047, 0.0, -1.0, 2.0, THUMB_LINKS),
    ),
    armature=0.002,
    damping=0.08,
    # Barrett-like: the arm's flange sits on the back of the palm, opposite the fingers.
    mount=((0.0, 0.0, -0.012), (0.0, 0.0, -1.0)),
)
