"""How many tasks a host's drones start at one boundary, and who goes first."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fleet.agent.admission import MESSAGES_PER_PEER, TaskBudget


@given(st.floats(1e-6, 0.1), st.integers(1, 500))
def test_a_host_starts_as_many_tasks_as_it_handles_within_its_bound_and_at_least_one(handling_s: float,
                                                                                      peers: int) -> None:
    budget = TaskBudget(0.125)
    budget.handled(handling_s)
    tasks = budget.per_boundary(peers)
    assert tasks is not None and tasks >= 1
    work = MESSAGES_PER_PEER * peers * handling_s
    assert tasks == 1 or tasks * work <= 0.125 + 1e-12
    assert (tasks + 1) * work > 0.125 - 1e-12


def test_a_host_with_nothing_measured_starts_one_task_and_one_with_no_peers_any() -> None:
    budget = TaskBudget(0.125)
    assert budget.per_boundary(10) == 1
    assert budget.per_boundary(0) is None
    assert budget.may_start(0, 0, "d1", waiting=True)


def test_a_drone_turned_away_goes_before_the_drones_that_ask_before_it() -> None:
    budget = TaskBudget(0.125)
    budget.handled(0.125 / MESSAGES_PER_PEER / 2)  # one task a boundary with 2 peers
    granted = []
    for step in range(3):
        for drone in ("a", "b", "c"):  # the same order at every boundary, each with mail
            if budget.may_start(step, 2, drone, waiting=True):
                budget.started(step)
                granted.append(drone)
    assert granted == ["a", "b", "c"]


@pytest.mark.parametrize("gone", ["asks with nothing to carry", "does not ask"])
def test_a_drone_turned_away_that_no_longer_waits_holds_no_start_back(gone: str) -> None:
    """A drone turned away whose mail went elsewhere, or that no longer asks (late, its vehicle lost),
    must not keep the others waiting for a start it will never take."""
    budget = TaskBudget(0.125)
    budget.handled(0.125 / MESSAGES_PER_PEER / 2)  # one task a boundary with 2 peers
    assert budget.may_start(0, 2, "a", waiting=True)
    budget.started(0)
    assert not budget.may_start(0, 2, "b", waiting=True)  # turned away: first at the next boundary
    if gone == "asks with nothing to carry":
        budget.may_start(1, 2, "b", waiting=False)
    assert budget.may_start(1, 2, "c", waiting=True) is (gone == "asks with nothing to carry")
    assert budget.may_start(2, 2, "c", waiting=True)
