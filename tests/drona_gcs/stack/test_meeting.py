"""The protocol's quick separation check answers as the plain checker does."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from drona_gcs.motion import Trajectory
from drona_gcs.safety import check_pair
from drona_gcs.stack.protocol.meeting import meets

_WALK = st.lists(st.tuples(st.integers(0, 2), st.integers(0, 2), st.just(0)), min_size=1, max_size=12)


@given(a=_WALK, b=_WALK, a_start=st.integers(-3, 6), b_start=st.integers(-3, 6), since=st.integers(-5, 20),
       delta=st.integers(0, 4))
@settings(max_examples=1500, deadline=None)
def test_it_finds_a_meeting_exactly_when_the_checker_does(
        a: list[tuple[int, int, int]], b: list[tuple[int, int, int]], a_start: int, b_start: int, since: int,
        delta: int) -> None:
    """On a 3x3 grid drones meet often, before, within and after either plan (and walks jump: the
    rule holds for any cells)."""
    mine, other = Trajectory(a_start, tuple(a)), Trajectory(b_start, tuple(b))
    assert meets(mine, other, delta, since) == bool(check_pair(mine, other, delta, from_step=since))


def test_a_swap_alone_is_a_meeting() -> None:
    """Head on at delta 0: no shared cell at any one step, but the two pass through each other."""
    mine = Trajectory(0, ((0, 0, 0), (1, 0, 0)))
    other = Trajectory(0, ((1, 0, 0), (0, 0, 0)))
    assert check_pair(mine, other, 0, from_step=0)
    assert meets(mine, other, 0, 0)
    assert not meets(mine, Trajectory(5, ((1, 0, 0), (0, 0, 0))), 0, 6)


def test_two_drones_resting_in_one_cell_meet_however_late_the_look() -> None:
    """Both plans over long before ``since``: they share their last cell for good."""
    mine, other = Trajectory(0, ((0, 0, 0), (1, 0, 0))), Trajectory(0, ((2, 0, 0), (1, 0, 0)))
    assert meets(mine, other, 1, 50) and check_pair(mine, other, 1, from_step=50)
    assert not meets(mine, Trajectory(0, ((2, 0, 0),)), 1, 50)
