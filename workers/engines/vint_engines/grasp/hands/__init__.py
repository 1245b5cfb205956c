"""The hands vint models (`trx3`, `allegro`) and the catalog entry of each (`catalog/hands.toml`),
and users' hands from MJCF (`mjcf.py`).

`hand_dims(name)` is the one lookup: an unknown name is `BadInput`. The catalog file names each
hand's taxel layout; `tests/test_hands.py` keeps it and these models in agreement.
"""

from __future__ import annotations

from vint_engines.grasp.hands.allegro import ALLEGRO
from vint_engines.grasp.hands.mjcf import MjcfHand, load_mjcf_hand
from vint_engines.grasp.hands.model import Finger, GraspHand, HandDims, Joint, Link
from vint_engines.grasp.hands.trx3 import TRX3
from vint_engines.protocol import BadInput

HANDS: dict[str, HandDims] = {hand.name: hand for hand in (TRX3, ALLEGRO)}


def hand_dims(name: str) -> HandDims:
    try:
        return HANDS[name]
    except KeyError:
        raise BadInput(f"params.hand.name: unknown hand {name!r} (known: {sorted(HANDS)})") from None


__all__ = [
    "ALLEGRO",
    "HANDS",
    "TRX3",
    "Finger",
    "GraspHand",
    "HandDims",
    "Joint",
    "Link",
    "MjcfHand",
    "hand_dims",
    "load_mjcf_hand",
]
