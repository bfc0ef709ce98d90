"""Property tests of the plan generators, judged by the trusted checker :mod:`drona_gcs.safety`.

* Every A* plan is safe: random 2-D and 3-D grids with obstacles, skew windows
  0..2, unit and mixed costs, up to four drones planned one after another by
  the A* itself (then each replanned against all the others), among drones
  aimed at the first one's route.
* The A* and the Z3 baseline agree on the optimal cost, with unit and mixed costs.
* The A* finds no plan exactly when an exhaustive enumeration of primitive
  sequences, each judged by the checker, finds none; otherwise both costs match.
* Hand-built situations: a goal another drone crosses later, a drone that
  starts later than me, and head-on swaps at delta 0.

The problems and the other drones are drawn by :mod:`tests.drona_gcs.planner.problems`.
Hypothesis runs derandomized, so CI sees the same examples every time; run
with ``--hypothesis-show-statistics`` to see how many examples needed detours.
"""

from __future__ import annotations

import contextlib
import math
from unittest.mock import patch

import pytest
from hypothesis import event, given
from hypothesis import strategies as st

from drona_gcs.errors import NoPlanFound
from drona_gcs.motion import Primitive, Trajectory
from drona_gcs.planner import Plan, SafePlanner
from drona_gcs.planner.sealing import find_seal
from drona_gcs.safety import ViolationKind, check_trajectory
from drona_gcs.workspace import Cell, Workspace
from tests.drona_gcs.planner.problems import (
    COST_TABLES,
    UNIT,
    Problem,
    _settings,
    assert_valid,
    brute_force,
    describe,
    interferers,
    outcome,
    plan_in_turn,
    problems,
    tasks_on,
    workspaces,
)


@_settings(300)
@given(data=st.data(), layers=st.sampled_from([(1,), (2, 3)]), costs=st.sampled_from(COST_TABLES))
def test_every_astar_plan_is_safe(data: st.DataObject, layers: tuple[int, ...],
                                  costs: dict[Primitive, float]) -> None:
    side = (3, 8) if layers == (1,) else (3, 5)
    ws = data.draw(workspaces(side, layers))
    delta = data.draw(st.integers(0, 2))
    tasks = data.draw(tasks_on(ws, data.draw(st.sampled_from([1, 2, 3, 4]))))
    start, goal, step = tasks[0]
    fleet = data.draw(interferers(ws, start, goal, step, delta, data.draw(st.integers(0, 2))))
    max_length = data.draw(st.none() | st.integers(0, 20))
    planner = SafePlanner(ws, delta=delta, costs=costs)
    with patch("drona_gcs.planner.find_seal", wraps=find_seal) as seal:
        planned, plans = plan_in_turn(ws, tasks, delta, max_length, costs, fleet, planner)
        # Each drone replans its task against all the others, as after a new task: the table
        # now drops and re-adds drones instead of only adding them.
        for i, (start, goal, step) in enumerate(tasks):
            others = {d: t for d, t in planned.items() if d != f"d{i}"}
            problem = Problem(ws, start, goal, step, others, delta, max_length, costs)
            with contextlib.suppress(NoPlanFound):
                plans.append((problem, planner.plan(start, goal, step, others, max_length)))
    event(f"{len(plans)} plans")
    if seal.called:
        event("the search needed the seal pruning")
    for problem, plan in plans:
        assert_valid(problem, plan)
        assert plan.cost == problem.astar().cost  # a fresh planner agrees with the reused one


@_settings(150)
@given(problems((3, 5), (1, 2), max_others=2, max_length=st.integers(0, 10), max_cells=24,
                costs=st.sampled_from(COST_TABLES)))
def test_astar_and_z3_agree_on_the_optimal_cost(problem: Problem) -> None:
    astar, z3 = outcome(problem.astar), outcome(problem.z3)
    describe(problem, astar)
    assert (astar is None) == (z3 is None), (problem, astar, z3)
    if astar is not None and z3 is not None:
        assert_valid(problem, astar)
        assert_valid(problem, z3)
        assert math.isclose(astar.cost, z3.cost), (problem, astar, z3)


@_settings(500)
@given(problems((2, 4), (1, 2), max_others=3, max_length=st.integers(2, 8), max_cells=16,
                costs=st.sampled_from(COST_TABLES)))
def test_astar_finds_no_plan_only_when_none_exists(problem: Problem) -> None:
    astar, truth = outcome(problem.astar), brute_force(problem)
    describe(problem, astar)
    assert (astar is None) == (truth is None), (problem, astar, truth)
    if astar is not None and truth is not None:
        assert_valid(problem, astar)
        assert math.isclose(astar.cost, truth[0]), (problem, astar, truth)


# ------------------------------------------------------------------ situations
def agree_with_brute_force(problem: Problem) -> Plan | None:
    """A*, Z3 and the brute force agree; returns the A* plan."""
    astar, z3, truth = outcome(problem.astar), outcome(problem.z3), brute_force(problem)
    assert (astar is None) == (z3 is None) == (truth is None), (astar, z3, truth)
    if astar is None or z3 is None or truth is None:
        return None
    assert_valid(problem, astar)
    assert_valid(problem, z3)
    assert math.isclose(astar.cost, truth[0]) and math.isclose(z3.cost, truth[0])
    return astar


def kinds(problem: Problem, cells: tuple[Cell, ...]) -> set[ViolationKind]:
    return {v.kind for v in check_trajectory(problem.ws, Trajectory(problem.start_step, cells),
                                             problem.others, problem.delta, problem.goal)}


@pytest.mark.parametrize("costs", [UNIT, COST_TABLES[1]], ids=["unit", "moves-2"])
@pytest.mark.parametrize("delta", [0, 1, 2])
@pytest.mark.parametrize("other_start", [0, 2, 4])
def test_waits_for_a_drone_crossing_the_goal_later(delta: int, other_start: int,
                                                    costs: dict[Primitive, float]) -> None:
    # The other drone flies along row 0 through my goal (1,0,0) two steps after it starts.
    ws = Workspace(size=(4, 2, 1))
    crossing = Trajectory(other_start, ((3, 0, 0), (2, 0, 0), (1, 0, 0), (0, 0, 0), (0, 1, 0)))
    problem = Problem(ws, (1, 1, 0), (1, 0, 0), 0, {"x": crossing}, delta, max_length=9, costs=costs)
    assert ViolationKind.COLLISION in kinds(problem, ((1, 1, 0), (1, 0, 0)))  # going straight fails
    plan = agree_with_brute_force(problem)
    assert plan is not None
    assert plan.trajectory.end_step > other_start + 2 + delta  # arrives after the crossing's window


@pytest.mark.parametrize("delta", [0, 1, 2])
@pytest.mark.parametrize("other_start", [2, 4])
def test_avoids_a_drone_that_starts_later(delta: int, other_start: int) -> None:
    # The other drone sits in the corridor's middle until it starts, then leaves into the side bay.
    ws = Workspace(size=(3, 2, 1), obstacles=frozenset({(0, 1, 0), (2, 1, 0)}))
    later = Trajectory(other_start, ((1, 0, 0), (1, 1, 0)))
    problem = Problem(ws, (0, 0, 0), (2, 0, 0), 0, {"late": later}, delta, max_length=9)
    straight = ((0, 0, 0), (1, 0, 0), (2, 0, 0))
    assert ViolationKind.COLLISION in kinds(problem, straight)  # it is there before it starts
    plan = agree_with_brute_force(problem)
    assert plan is not None
    passes = [s for s in range(plan.trajectory.end_step + 1) if plan.trajectory.at(s) == (1, 0, 0)]
    assert passes and min(passes) > other_start + delta


@pytest.mark.parametrize("step", [0, 3])
def test_no_head_on_swap_at_delta_0(step: int) -> None:
    # Two lanes; the other comes at me along lane 0, so the straight run swaps cells with it.
    ws = Workspace(size=(4, 2, 1))
    oncoming = Trajectory(step, ((2, 0, 0), (1, 0, 0), (0, 0, 0)))
    problem = Problem(ws, (1, 0, 0), (3, 0, 0), step, {"o": oncoming}, 0, max_length=7)
    straight = ((1, 0, 0), (2, 0, 0), (3, 0, 0))
    # Only the swap rule stops it: the cells differ at every common step.
    assert kinds(problem, straight) == {ViolationKind.SWAP}
    plan = agree_with_brute_force(problem)
    assert plan is not None and len(plan.primitives) > 2


@pytest.mark.parametrize("delta", [0, 1])
def test_no_plan_through_a_single_lane_head_on(delta: int) -> None:
    # One lane; the other drone comes at me and parks between me and my goal.
    ws = Workspace(size=(4, 1, 1))
    oncoming = Trajectory(0, ((3, 0, 0), (2, 0, 0), (1, 0, 0)))
    problem = Problem(ws, (0, 0, 0), (3, 0, 0), 0, {"o": oncoming}, delta, max_length=8)
    assert agree_with_brute_force(problem) is None
