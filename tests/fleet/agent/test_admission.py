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


def _boundary(budget: TaskBudget, step: int, starts: int, longest_s: float | None, in_line: bool = False,
              peers: int = 30) -> int:
    """Boundary ``step``: ``starts`` drones with mail ask; those let start run rounds, the longest of which
    takes ``longest_s`` (None: none ends before the next boundary), or that much for each round ``in_line``.
    How many started."""
    started = 0
    for i in range(starts):
        if budget.may_start(step, peers, f"d{i}", waiting=True):
            budget.started(step)
            started += 1
    if longest_s is not None and started:
        longest = longest_s * started if in_line else longest_s
        budget.round_ended(longest / 2)
        budget.round_ended(longest)
    return started


def _fast_cpu_budget(target_s: float = 0.1) -> TaskBudget:
    budget = TaskBudget(0.125, target_s)
    budget.handled(1e-7)  # the CPU lets hundreds start: only the rounds' latency bounds them
    return budget


def test_rounds_well_within_their_target_let_one_more_task_start_at_each_boundary() -> None:
    budget = _fast_cpu_budget()
    assert [_boundary(budget, step, 10, 0.01) for step in range(6)] == [1, 2, 3, 4, 5, 6]


def test_one_more_start_is_let_only_if_one_more_round_in_line_still_fits_the_target() -> None:
    budget = _fast_cpu_budget()
    # Each round in line adds 30 ms: three take 90, a fourth would take 120.
    started = [_boundary(budget, step, 10, 0.03, in_line=True) for step in range(8)]
    assert started == [1, 2, 3, 3, 3, 3, 3, 3]


def test_a_round_longer_than_the_target_cuts_the_starts_in_proportion() -> None:
    budget = _fast_cpu_budget()
    assert [_boundary(budget, step, 10, 0.01) for step in range(8)] == [1, 2, 3, 4, 5, 6, 7, 8]
    assert _boundary(budget, 8, 10, 0.3) == 9  # three times the target: a third as many
    assert _boundary(budget, 9, 10, None) == 3
    _boundary(budget, 10, 10, 1.0)
    assert _boundary(budget, 11, 10, None) == 1  # never none


def test_a_window_not_filled_does_not_grow() -> None:
    budget = _fast_cpu_budget()
    assert [_boundary(budget, step, 10, 0.001) for step in range(3)] == [1, 2, 3]
    for step in range(3, 10):
        _boundary(budget, step, 1, 0.001)  # one drone with mail at a time: no word on more rounds at once
    assert budget.window == 4


@given(st.lists(st.tuples(st.integers(1, 20), st.one_of(st.none(), st.floats(0.0, 2.0))), min_size=1, max_size=30))
def test_the_starts_never_grow_after_a_round_over_the_target(boundaries: list[tuple[int, float | None]]) -> None:
    budget = _fast_cpu_budget()
    windows = [budget.window]  #: the window each boundary judged the one before it by
    for step, (asking, longest) in enumerate(boundaries):
        _boundary(budget, step, asking, longest)
        windows.append(budget.window)
    budget.may_start(len(boundaries), 30, "d0", waiting=False)  # the boundary after judges the last
    windows.append(budget.window)
    for k, (_, longest) in enumerate(boundaries):
        assert windows[k + 2] >= 1
        if longest is not None and longest > 0.1:
            assert windows[k + 2] <= windows[k + 1]
