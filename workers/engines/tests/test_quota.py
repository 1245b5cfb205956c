"""A grasp task with a quota of accepted grasps runs its trials in order and stops at the quota."""

from __future__ import annotations

from typing import Any

import pytest

from vint_engines.grasp import engine


def fake_trial_accepting(accepted: set[int]) -> Any:
    """A test double for `run_trial`: accepts exactly the grasp indices in `accepted`."""

    def run(scene: Any, data: Any, physics: Any, skin: Any, index: int, seed: int) -> dict[str, Any]:
        return {"grasp_index": index, "seed": seed, "accepted": index in accepted}

    return run


@pytest.mark.parametrize(
    ("accept", "ran"),
    [
        (None, [0, 1, 2, 3, 4, 5]),
        (2, [0, 1, 2, 3]),
        (1, [0, 1]),
        (3, [0, 1, 2, 3, 4, 5]),
        (4, [0, 1, 2, 3, 4, 5]),
    ],
)
def test_trials_stop_at_the_quota(
    monkeypatch: pytest.MonkeyPatch, accept: int | None, ran: list[int]
) -> None:
    monkeypatch.setattr(engine, "run_trial", fake_trial_accepting({1, 3, 5}))
    trials = [(i, 100 + i) for i in range(6)]
    records = engine.run_trials(None, None, None, None, trials, accept)  # type: ignore[arg-type]
    assert [r["grasp_index"] for r in records] == ran
    assert [r["seed"] for r in records] == [100 + i for i in ran]


def test_the_quota_is_part_of_the_contract() -> None:
    base = {
        "object": {
            "name": "mug",
            "ycb_id": "025",
            "mass_kg": 0.118,
            "material": "ceramic",
            "description": "mug",
            "shape": {"type": "cylinder", "radius_m": 0.04, "height_m": 0.08},
        },
        "hand": {"name": "trx3"},
        "trials": [{"grasp_index": 0, "seed": 1}],
    }
    assert engine.GraspTask.parse(base).accept is None
    assert engine.GraspTask.parse({**base, "accept": 1}).accept == 1
    with pytest.raises(engine.BadInput, match="accept"):
        engine.GraspTask.parse({**base, "accept": 0})
