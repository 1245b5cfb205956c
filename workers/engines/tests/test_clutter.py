"""Where distractors stand (`render/clutter.py`), checked on the numbers alone: outside the grasp's
footprint by the gap, apart from one another, on the table top, and the same for the same seed."""

from __future__ import annotations

import math

from vint_engines.render import clutter
from vint_engines.render.clutter import Footprint

NAMES = [f"thing_{i}" for i in range(12)]
FOOTPRINTS = {
    name: Footprint((1.0, 0.0, 0.0, 0.0), 0.01 * (i + 1), 0.02 + 0.01 * i) for i, name in enumerate(NAMES)
}
CENTRE = (0.3, -0.2)
KEEP_OUT = 0.12
TOP = 0.75
HALF = (0.8, 0.5)


def placed(seed: int, count: int) -> list[clutter.Placed]:
    return clutter.place(seed, NAMES, FOOTPRINTS.__getitem__, count, CENTRE, KEEP_OUT, TOP, HALF)


def test_distractors_stand_clear_of_the_grasp_and_of_each_other_on_the_table() -> None:
    for seed in range(20):
        stands = placed(seed, 6)
        assert len(stands) == 6
        assert len({s.name for s in stands}) == 6
        for i, a in enumerate(stands):
            ra = FOOTPRINTS[a.name].radius
            x, y, z = a.position
            assert math.dist((x, y), CENTRE) >= KEEP_OUT + clutter.GAP_M + ra - 1e-12
            assert math.dist((x, y), CENTRE) <= KEEP_OUT + clutter.GAP_M + ra + clutter.REACH_M + 1e-12
            assert abs(x - CENTRE[0]) <= HALF[0] - ra and abs(y - CENTRE[1]) <= HALF[1] - ra
            assert math.isclose(z, TOP + FOOTPRINTS[a.name].height)
            assert math.isclose(sum(q * q for q in a.quat), 1.0)
            for b in stands[i + 1 :]:
                rb = FOOTPRINTS[b.name].radius
                assert math.dist(a.position[:2], b.position[:2]) >= ra + rb + clutter.GAP_M - 1e-12


def test_the_layout_is_a_function_of_the_seed() -> None:
    assert placed(7, 4) == placed(7, 4)
    assert placed(7, 4) != placed(8, 4)
    assert (
        placed(7, 0) == []
        and clutter.place(7, [], FOOTPRINTS.__getitem__, 3, CENTRE, KEEP_OUT, TOP, HALF) == []
    )


def test_a_crowded_bench_leaves_out_what_does_not_fit() -> None:
    tight = clutter.place(3, NAMES, FOOTPRINTS.__getitem__, 12, CENTRE, 0.4, TOP, (0.55, 0.55))
    assert len(tight) < 12
    for stand in tight:
        assert (
            math.dist(stand.position[:2], CENTRE)
            >= 0.4 + clutter.GAP_M + FOOTPRINTS[stand.name].radius - 1e-12
        )
