"""The fleet's one rule for which drone takes a mail (used by `drona mail` and the service)."""

from __future__ import annotations

from drona_gcs.dispatch import Candidate, choose_drone

PICKUP = (5, 5, 0)


def test_no_candidate_no_drone() -> None:
    assert choose_drone([], PICKUP) is None


def test_preference_is_healthy_then_least_held_then_idle_then_nearest_then_name() -> None:
    near, far = (5, 4, 0), (0, 0, 0)
    ranked = [
        Candidate("h-near-idle", near, held=0, busy=False),
        Candidate("g-far-idle", far, held=0, busy=False),
        Candidate("f-near-busy", near, held=0, busy=True),
        Candidate("e-near-holding", near, held=1, busy=False),
        Candidate("d-sick", near, held=0, busy=False, healthy=False),
    ]
    for i in range(len(ranked)):
        assert choose_drone(ranked[i:], PICKUP) == ranked[i].drone
    twins = [Candidate("b", near, 0, False), Candidate("a", near, 0, False)]
    assert choose_drone(twins, PICKUP) == "a"


def test_the_distance_is_the_callers() -> None:
    walls = {"x": 3, "y": 30}
    candidates = [Candidate("x", (9, 9, 0), 0, False), Candidate("y", (5, 4, 0), 0, False)]
    cells = {c.cell: c.drone for c in candidates}
    assert choose_drone(candidates, PICKUP, lambda a, b: walls[cells[a]]) == "x"
