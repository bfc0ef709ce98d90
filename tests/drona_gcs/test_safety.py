"""The safe-trajectory checker on small hand-made trajectories.

The grid is 5 x 5 x 1 with one obstacle at (2, 2). Cells are written (x, y);
``traj(n, ...)`` is the trajectory that starts at step ``n``.
"""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drona_gcs.errors import UnsafeTrajectory
from drona_gcs.motion import Trajectory
from drona_gcs.safety import (
    Violation,
    ViolationKind,
    assert_safe,
    check_fleet,
    check_pair,
    check_path,
    check_trajectory,
)
from drona_gcs.verify.separation import meetings
from drona_gcs.workspace import Cell, Workspace

COLLISION, SWAP = ViolationKind.COLLISION, ViolationKind.SWAP


def traj(start_step: int, *cells: tuple[int, int]) -> Trajectory:
    return Trajectory(start_step, tuple((x, y, 0) for x, y in cells))


@pytest.fixture
def ws() -> Workspace:
    return Workspace.build(size=(5, 5, 1), obstacles=frozenset({(2, 2, 0)}))


# ------------------------------------------------------------ two drones
def test_a_clean_pair_passes(ws: Workspace) -> None:
    a = traj(0, (0, 0), (1, 0), (2, 0), (3, 0))
    b = traj(0, (0, 4), (1, 4), (2, 4), (3, 4))
    for delta in (0, 1, 3):
        assert check_trajectory(ws, a, {"b": b}, delta, goal=(3, 0, 0)) == []
        assert check_trajectory(ws, b, {"a": a}, delta, goal=(3, 4, 0)) == []
    assert_safe(ws, a, {"b": b}, 3, goal=(3, 0, 0))


def test_same_cell_at_the_same_step_is_a_collision(ws: Workspace) -> None:
    a = traj(0, (0, 1), (1, 1), (2, 1))  # through (1, 1) at step 1
    b = traj(0, (1, 0), (1, 1), (1, 2))  # through (1, 1) at step 1
    assert check_trajectory(ws, a, {"b": b}, 0) == [Violation(COLLISION, 1, (1, 1, 0), "b", 1)]
    assert check_trajectory(ws, b, {"a": a}, 0) == [Violation(COLLISION, 1, (1, 1, 0), "a", 1)]


@pytest.mark.parametrize(("b_step", "delta", "expected"), [
    (2, 0, []),  # one step apart: safe without clock skew
    (2, 1, [Violation(COLLISION, 1, (1, 1, 0), "b", 2)]),
    (3, 1, []),  # two steps apart: outside a window of 1
    (3, 2, [Violation(COLLISION, 1, (1, 1, 0), "b", 3)]),
])
def test_the_skew_window_delta(ws: Workspace, b_step: int, delta: int, expected: list[Violation]) -> None:
    a = traj(0, (0, 1), (1, 1), (2, 1), (3, 1))  # through (1, 1) at step 1
    b = traj(b_step - 1, (1, 0), (1, 1), (1, 2))  # through (1, 1) at b_step
    assert check_trajectory(ws, a, {"b": b}, delta) == expected


def test_following_one_cell_behind_is_safe_only_without_skew(ws: Workspace) -> None:
    lead = traj(0, (1, 0), (2, 0), (3, 0))
    follower = traj(0, (0, 0), (1, 0), (2, 0))  # enters each cell the step the leader leaves it
    assert check_pair(follower, lead, 0) == []
    found = check_pair(follower, lead, 1)
    assert found and {v.kind for v in found} == {COLLISION}
    assert Violation(COLLISION, 1, (1, 0, 0), "other", 0) in found


def test_head_on_swap_is_found_even_at_delta_zero(ws: Workspace) -> None:
    a = traj(0, (1, 0), (2, 0))
    b = traj(0, (2, 0), (1, 0))
    assert check_trajectory(ws, a, {"b": b}, 0) == [Violation(SWAP, 0, (1, 0, 0), "b", 0)]
    assert check_trajectory(ws, b, {"a": a}, 0) == [Violation(SWAP, 0, (2, 0, 0), "a", 0)]


def test_swap_later_in_a_trajectory(ws: Workspace) -> None:
    a = traj(3, (0, 3), (1, 3), (2, 3), (3, 3))  # (1, 3) -> (2, 3) at steps 4 -> 5
    b = traj(4, (2, 3), (1, 3), (1, 4))  # (2, 3) -> (1, 3) at the same steps
    found = check_trajectory(ws, a, {"b": b}, 0)
    assert found == [Violation(SWAP, 4, (1, 3, 0), "b", 4)]


def test_a_drone_waits_at_its_first_cell_before_it_starts(ws: Workspace) -> None:
    a = traj(0, (0, 3), (1, 3), (2, 3), (3, 3))  # through (1, 3) at step 1
    late = traj(5, (1, 3), (1, 4))  # sits at (1, 3) until step 5
    assert check_trajectory(ws, a, {"late": late}, 0) == [Violation(COLLISION, 1, (1, 3, 0), "late", 1)]
    # Starting from a cell nobody else uses, the same flight is safe.
    assert check_trajectory(ws, a, {"late": traj(5, (0, 4), (1, 4))}, 0) == []


def test_a_drone_stays_at_its_last_cell_forever(ws: Workspace) -> None:
    parked = traj(0, (4, 0), (4, 1), (4, 2))  # reaches (4, 2) at step 2 and stays
    visitor = traj(20, (3, 1), (4, 1), (4, 2), (4, 3), (4, 4))  # through (4, 2) at step 22
    found = check_trajectory(ws, visitor, {"parked": parked}, 0)
    assert found == [Violation(COLLISION, 22, (4, 2, 0), "parked", 22)]
    assert found[0].other_step is not None and found[0].other_step > parked.end_step
    # The drone that parked first is checked past its own end, so it sees the visitor too.
    assert check_trajectory(ws, parked, {"visitor": visitor}, 0) == [Violation(COLLISION, 22, (4, 2, 0), "visitor", 22)]
    # Parking on the cell where another drone parked long ago is a collision as well.
    arrives = traj(10, (3, 3), (4, 3), (4, 2))
    assert Violation(COLLISION, 12, (4, 2, 0), "parked", 12) in check_trajectory(ws, arrives, {"parked": parked}, 0)


def test_collision_long_after_both_ended_within_the_window(ws: Workspace) -> None:
    a = traj(0, (0, 0), (0, 1))  # parks at (0, 1) from step 1
    b = traj(40, (1, 1), (0, 1))  # arrives there at step 41
    assert check_trajectory(ws, b, {"a": a}, 2)[0] == Violation(COLLISION, 41, (0, 1, 0), "a", 39)


# ------------------------------------------------------------ one path
def test_obstacle_is_reported(ws: Workspace) -> None:
    path = traj(0, (1, 2), (2, 2), (3, 2))
    assert check_path(ws, path) == [Violation(ViolationKind.OBSTACLE, 1, (2, 2, 0))]


@pytest.mark.parametrize(("inside", "outside"), [
    ((0, 0, 0), (-1, 0, 0)), ((4, 0, 0), (5, 0, 0)), ((0, 4, 0), (0, 5, 0)),
    ((0, 0, 0), (0, 0, 1)), ((0, 0, 0), (0, 0, -1)),
])
def test_out_of_bounds_is_reported(ws: Workspace, inside: Cell, outside: Cell) -> None:
    path = Trajectory(7, (inside, outside, inside))
    assert check_path(ws, path) == [Violation(ViolationKind.OUT_OF_BOUNDS, 8, outside)]


@pytest.mark.parametrize("cells", [
    [(0, 0), (2, 0)],  # two cells along x
    [(0, 0), (1, 0), (2, 1)],  # diagonal
    [(0, 0), (0, 1), (4, 4)],  # teleport
])
def test_jump_is_reported(ws: Workspace, cells: list[tuple[int, int]]) -> None:
    path = traj(3, *cells)
    assert check_path(ws, path) == [Violation(ViolationKind.JUMP, 3 + len(cells) - 1, path.last)]


def test_hold_and_single_moves_are_not_jumps(ws: Workspace) -> None:
    assert check_path(ws, traj(0, (0, 0), (0, 0), (1, 0), (1, 1), (1, 1), (0, 1))) == []
    assert check_path(Workspace.build(size=(2, 2, 2)), Trajectory(0, ((0, 0, 0), (0, 0, 1), (0, 1, 1)))) == []


def test_a_path_with_several_faults_reports_each(ws: Workspace) -> None:
    path = traj(0, (1, 2), (2, 2), (4, 2), (5, 2))
    kinds = [(v.kind, v.step) for v in check_path(ws, path)]
    assert kinds == [(ViolationKind.OBSTACLE, 1), (ViolationKind.JUMP, 2), (ViolationKind.OUT_OF_BOUNDS, 3)]


def test_not_ending_at_the_goal_is_reported(ws: Workspace) -> None:
    path = traj(4, (0, 0), (1, 0), (2, 0))
    assert check_trajectory(ws, path, {}, 0, goal=(2, 0, 0)) == []
    assert check_trajectory(ws, path, {}, 0, goal=(3, 0, 0)) == [Violation(ViolationKind.GOAL, 6, (2, 0, 0))]
    # Passing through the goal is not ending there.
    assert check_trajectory(ws, path, {}, 0, goal=(1, 0, 0))[0].kind is ViolationKind.GOAL


# ------------------------------------------------------------ fleets and assert_safe
def test_check_fleet_names_the_colliding_pair(ws: Workspace) -> None:
    fleet = {
        "a": traj(0, (0, 4), (1, 4), (2, 4)),
        "b": traj(0, (0, 1), (1, 1), (2, 1)),  # through (1, 1) at step 1
        "c": traj(0, (1, 0), (1, 1), (1, 2)),  # through (1, 1) at step 1
    }
    found = check_fleet(ws, fleet, 0)
    assert found == [Violation(COLLISION, 1, (1, 1, 0), "b~c", 1)]
    assert check_fleet(ws, {k: fleet[k] for k in ("a", "b")}, 0) == []
    assert check_fleet(ws, {k: fleet[k] for k in ("a", "c")}, 0) == []


def test_check_fleet_checks_every_pair_and_every_path(ws: Workspace) -> None:
    fleet = {
        "a": traj(0, (0, 0), (1, 0), (2, 0)),
        "b": traj(0, (4, 4), (3, 4), (3, 3)),
        "c": traj(0, (3, 1), (3, 0), (3, 0), (2, 0), (2, 1)),  # into (2, 0), where a has parked
        "d": traj(0, (3, 2), (2, 2)),  # into the obstacle
    }
    found = check_fleet(ws, fleet, 0)
    pairs = {v.other for v in found if v.kind in (COLLISION, SWAP)}
    assert pairs == {"a~c"}
    assert Violation(ViolationKind.OBSTACLE, 1, (2, 2, 0)) in found


def test_check_fleet_with_skew_and_staggered_starts(ws: Workspace) -> None:
    fleet = {
        "a": traj(0, (0, 3), (1, 3), (2, 3)),  # through (1, 3) at step 1
        "b": traj(3, (1, 4), (1, 3), (0, 3)),  # through (1, 3) at step 4
        "c": traj(0, (4, 0)),
    }
    assert check_fleet(ws, fleet, 1) == []
    found = check_fleet(ws, fleet, 3)
    assert found and {v.other for v in found} == {"a~b"}


def test_assert_safe_raises_with_the_violations(ws: Workspace) -> None:
    a = traj(0, (1, 0), (2, 0))
    b = traj(0, (2, 0), (1, 0))
    with pytest.raises(UnsafeTrajectory) as info:
        assert_safe(ws, a, {"b": b}, 0, goal=(3, 0, 0))
    expected = [Violation(ViolationKind.GOAL, 1, (2, 0, 0)), Violation(SWAP, 0, (1, 0, 0), "b", 0)]
    assert info.value.violations == expected
    assert str(info.value) == ("unsafe trajectory: goal at step 1 in cell [2, 0, 0]; "
                               "swap at step 0 in cell [1, 0, 0] with drone 'b' at its step 0")


def test_unsafe_trajectory_message_shows_five_violations_at_most(ws: Workspace) -> None:
    a = traj(0, (0, 0), (0, 0), (0, 0), (0, 0), (0, 0), (0, 0), (0, 0))
    with pytest.raises(UnsafeTrajectory) as info:
        assert_safe(ws, a, {"b": traj(0, (0, 0))}, 0)
    assert len(info.value.violations) == 8  # steps 0..6 and the horizon step 7
    assert str(info.value).endswith("(+3 more)")


_WALK = st.lists(st.tuples(st.integers(0, 2), st.integers(0, 2)), min_size=1, max_size=12)


@given(a=_WALK, b=_WALK, t=st.integers(-2, 14), delta=st.integers(0, 3))
@settings(max_examples=400, deadline=None)
def test_the_checker_and_the_testers_own_monitor_find_the_same_meetings(
        a: list[tuple[int, int]], b: list[tuple[int, int]], t: int, delta: int) -> None:
    """Two separate statements of the separation rule (the checker skips steps in no cell of the
    other's; the monitor walks every step) agree on small grids, where drones meet often."""
    mine, other = traj(0, *a), traj(0, *b)
    found = {(v.kind.value, v.step, v.cell, v.other_step)
             for v in check_pair(mine, other, delta, "b", from_step=t, until=t)}
    judged = {(m.kind, m.step, m.cell, m.other_step) for m in meetings(list(mine.cells), list(other.cells), t, delta)}
    assert found == judged
