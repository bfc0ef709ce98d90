"""The plan executor: one setpoint per step boundary along a timed trajectory, completion once."""

from __future__ import annotations

import pytest

from drona_gcs.errors import ProtocolViolation
from drona_gcs.motion import Trajectory
from drona_gcs.stack.executor import Completed, ExecutorAction, ExecutorState, PlanExecutor, Setpoint


def cell(x: int, y: int = 0) -> tuple[int, int, int]:
    return (x, y, 0)


def setpoint(actions: list[ExecutorAction]) -> Setpoint:
    """A tick's setpoint: its first action."""
    first = actions[0]
    assert isinstance(first, Setpoint), actions
    return first


#: From (0, 0) at step 3: east, hover one step, then north; it reaches (1, 1) at step 6.
PLAN = Trajectory(3, (cell(0), cell(1), cell(1), cell(1, 1)))


def test_ticks_follow_the_trajectory_cell_by_cell() -> None:
    ex = PlanExecutor(cell(0))
    ex.start(PLAN)
    out = {step: ex.tick(step) for step in range(10)}
    # before the start step it holds the first cell
    for step in (0, 1, 2, 3):
        assert out[step] == [Setpoint(step, cell(0), moving=False)]
    assert out[4] == [Setpoint(4, cell(1), moving=True)]
    assert out[5] == [Setpoint(5, cell(1), moving=False)]  # the hold in the plan
    assert out[6] == [Setpoint(6, cell(1, 1), moving=True), Completed(PLAN)]
    for step in (7, 8, 9):  # then it holds the last cell, and reports nothing more
        assert out[step] == [Setpoint(step, cell(1, 1), moving=False)]
    assert ex.cell == cell(1, 1) and ex.state is ExecutorState.HOLDING and ex.trajectory is None


def test_completed_is_reported_exactly_once_at_the_end_step() -> None:
    ex = PlanExecutor(cell(0))
    ex.start(PLAN)
    done = [step for step in range(20) for action in ex.tick(step) if isinstance(action, Completed)]
    assert done == [PLAN.end_step] == [6]


def test_a_one_cell_trajectory_completes_at_its_start_step() -> None:
    ex = PlanExecutor(cell(2))
    ex.tick(0)
    here = Trajectory.stationary(cell(2), 2)
    ex.start(here)
    assert ex.tick(1) == [Setpoint(1, cell(2), moving=False)]
    assert ex.tick(2) == [Setpoint(2, cell(2), moving=False), Completed(here)]


def test_holding_without_a_trajectory() -> None:
    ex = PlanExecutor(cell(4))
    assert [ex.tick(s) for s in (7, 8)] == [[Setpoint(7, cell(4), False)], [Setpoint(8, cell(4), False)]]
    assert ex.state is ExecutorState.HOLDING and not ex.flying


def test_flying_is_false_before_the_start_step_and_true_from_it() -> None:
    ex = PlanExecutor(cell(0))
    assert not ex.flying
    ex.start(PLAN)
    seen = {}
    for step in range(PLAN.end_step):  # up to the step before completion
        ex.tick(step)
        seen[step] = ex.flying
    assert seen == {0: False, 1: False, 2: False, 3: True, 4: True, 5: True}
    ex.tick(PLAN.end_step)  # completed: holding again
    assert not ex.flying


def test_it_refuses_a_trajectory_whose_start_step_has_passed() -> None:
    ex = PlanExecutor(cell(0))
    for step in range(4):
        ex.tick(step)
    late = Trajectory(3, PLAN.cells)  # starts at the boundary already taken
    with pytest.raises(ProtocolViolation, match="starts at step 3"):
        ex.start(late)
    with pytest.raises(ProtocolViolation):
        ex.start(Trajectory(1, PLAN.cells))
    assert (ex.state, ex.trajectory) == (ExecutorState.HOLDING, None)
    ex.start(Trajectory(4, PLAN.cells))  # the next boundary is still to come
    assert ex.state is ExecutorState.EXECUTING


def test_it_refuses_a_trajectory_that_does_not_start_at_the_held_cell() -> None:
    ex = PlanExecutor(cell(1))
    with pytest.raises(ProtocolViolation, match="holds"):
        ex.start(PLAN)  # starts at (0, 0)
    assert ex.trajectory is None
    # after a flight the held cell is where it ended
    ex = PlanExecutor(cell(0))
    ex.start(PLAN)
    for step in range(PLAN.end_step + 1):
        ex.tick(step)
    with pytest.raises(ProtocolViolation):
        ex.start(Trajectory(10, (cell(0), cell(1))))
    ex.start(Trajectory(10, (cell(1, 1), cell(1, 2))))


@pytest.mark.parametrize("steps", [(0, 2), (0, 1, 1), (5, 4), (3, 4, 6)])
def test_it_refuses_out_of_order_ticks(steps: tuple[int, ...]) -> None:
    ex = PlanExecutor(cell(0))
    for step in steps[:-1]:
        ex.tick(step)
    last = ex.step
    with pytest.raises(ProtocolViolation, match="in order"):
        ex.tick(steps[-1])
    assert ex.step == last  # a refused tick changes nothing
    ex.tick(last + 1)


def test_a_new_rest_of_the_trajectory_flown_is_taken_mid_flight() -> None:
    """A rerouted plan is the one flown until its new rest starts (Trajectory.spliced): taken as is;
    one that differs from what was flown is refused."""
    flown = Trajectory(1, ((0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0)))
    executor = PlanExecutor((0, 0, 0))
    executor.start(flown)
    for step in range(3):
        executor.tick(step)
    rest = flown.spliced(Trajectory(3, ((2, 0, 0), (2, 1, 0), (3, 1, 0))))
    assert rest.cells[:3] == flown.cells[:3]
    executor.start(rest)
    assert [setpoint(executor.tick(s)).cell for s in range(3, 6)] == [(2, 0, 0), (2, 1, 0), (3, 1, 0)]
    other = PlanExecutor((0, 0, 0))
    other.start(flown)
    for step in range(3):
        other.tick(step)
    with pytest.raises(ProtocolViolation):
        other.start(Trajectory(1, ((0, 0, 0), (0, 1, 0), (1, 1, 0), (2, 1, 0))))
