"""Safe-interval search (:mod:`drona_gcs.planner.sipp`): its intervals and its plans.

* The safe intervals the reservation table hands out are exactly the steps at
  which :meth:`ReservationTable.conflicts` finds a cell free, also after drones
  are replaced and removed (the intervals are cached per cell).
* A planner forced onto its second path (safe intervals, seal pruning) finds
  the same optimal cost as an exhaustive enumeration, and no plan only when
  there is none: the properties of :mod:`tests.test_planner_properties` again.
* On the bench workload the safe-interval search and the space-time A* agree
  on every cost, also where equal-f ties make the search reopen states.
"""

from __future__ import annotations

import math
import random
from functools import partial
from itertools import pairwise

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drona_gcs.errors import NoPlanFound
from drona_gcs.motion import Trajectory
from drona_gcs.planner import SafePlanner
from drona_gcs.planner.astar import search
from drona_gcs.planner.reservations import ALWAYS_FREE, FOREVER, ReservationTable
from drona_gcs.planner.result import SearchResult
from drona_gcs.safety import check_trajectory
from drona_gcs.workload import TaskStream, random_workspace
from tests.drona_gcs.planner.problems import (
    Problem,
    _settings,
    assert_valid,
    brute_force,
    describe,
    outcome,
    problems,
    walks,
    workspaces,
)


def _since(step: int | None, first: int) -> int | None:
    """A step, with every step up to ``first`` (the first one asked about) counted as one."""
    return None if step is None else max(step, first)


def _free_at(intervals: tuple[tuple[int, int], ...], step: int) -> bool:
    return any(lo <= step <= hi for lo, hi in intervals)


@_settings(200)
@given(data=st.data(), delta=st.integers(0, 2))
def test_safe_intervals_are_the_steps_without_conflict(data: st.DataObject, delta: int) -> None:
    ws = data.draw(workspaces((2, 6), (1, 2), density=0.2))
    free = sorted(ws.free_cells)
    starts = data.draw(st.lists(st.sampled_from(free), min_size=1, max_size=4, unique=True))
    table, keys = ReservationTable(ws, delta, vertex_keys=False), ReservationTable(ws, delta)
    fleets = [data.draw(walks(ws, starts, delta)) for _ in range(3)]
    fleets.append({k: v for k, v in fleets[-1].items() if data.draw(st.booleans())})
    for fleet in fleets:  # each sync replaces or drops drones: cached intervals must follow
        table.sync(fleet)
        keys.sync(fleet)
        horizon = max((t.end_step for t in fleet.values()), default=0) + delta + 3
        # Searches start ever later, or sometimes earlier again: the intervals may forget
        # the past, and must be right from the first step asked about on.
        since = data.draw(st.none() | st.integers(-3, horizon), label="look from")
        if since is not None:
            table.look_from(since)
        first = max(-3, table.horizon)
        horizon = max(horizon, first)
        fresh = ReservationTable(ws, delta, vertex_keys=False)  # nothing cached at an earlier horizon
        fresh.sync(fleet)
        fresh.look_from(first)
        for cell in free:
            cid = ws.cell_id(cell)
            intervals = table.safe_intervals(cid)
            runs = [(lo, hi) for lo, hi in intervals]
            assert runs == sorted(runs)
            assert all(lo <= hi for lo, hi in runs)
            assert all(a[1] + 1 < b[0] for a, b in pairwise(runs)), runs  # maximal
            taken = [step for step in range(first, horizon + 1) if keys.conflicts(cid, step)]
            for step in range(first, horizon + 1):  # judged by the vertex keys
                assert _free_at(intervals, step) == (step not in taken), (cell, step, runs)
                assert table.conflicts(cid, step) == (step in taken)
            # Past the horizon nothing changes any more: the last run is open-ended or ends before.
            assert (runs[-1][1] == FOREVER) == (not keys.conflicts(cid, horizon)) if runs else True
            # A cell taken only before the first step asked about is on the search's fast path
            # (once its intervals are worked out again: what was cut for an earlier step stays).
            assert (fresh.safe_intervals(cid) is ALWAYS_FREE) == (not taken), (cell, first, runs)
            assert all(hi >= first for _, hi in fresh.safe_intervals(cid)), (cell, first)  # no dead runs
            assert intervals is not ALWAYS_FREE or not taken
            # Both views agree on when the cell is free for good.
            assert _since(table.goal_free_from(cid), first) == _since(keys.goal_free_from(cid), first), cell
        # The search skips the swap test for cells free from the first step on: a swap's target
        # cell is never one (the other drone sits there as I would leave for it).
        for key in table.swaps:
            if key // table.n // table.n >= first:
                assert table.safe_intervals(key % table.n) is not ALWAYS_FREE


def forced(problem: Problem) -> SafePlanner:
    """The safe-interval search (unit costs: it refuses others), straight to its second path."""
    planner = SafePlanner(problem.ws, delta=problem.delta, costs=problem.costs, intervals=True)
    planner.seal_after = -10**9  # with seal pruning
    return planner


def test_a_dense_fleet_at_delta_0_searches_safe_intervals() -> None:
    ws = random_workspace(16, 16, random.Random(5))
    assert SafePlanner(ws, 0, fleet_size=16).intervals
    assert not SafePlanner(ws, 0, fleet_size=2).intervals
    assert SafePlanner(ws, 1, fleet_size=2).intervals


@_settings(500)
@given(problems((2, 4), (1, 2), max_others=3, max_length=st.integers(2, 8), max_cells=16, deltas=(0, 2)))
def test_interval_search_finds_no_plan_only_when_none_exists(problem: Problem) -> None:
    planner = forced(problem)
    found = outcome(lambda: planner.plan(problem.start, problem.goal, problem.start_step,
                                         problem.others, problem.max_length))
    truth = brute_force(problem)
    describe(problem, found)
    assert (found is None) == (truth is None), (problem, found, truth)
    if found is not None and truth is not None:
        assert_valid(problem, found)
        assert math.isclose(found.cost, truth[0]), (problem, found, truth)


@_settings(200)
@given(problems((3, 7), (1, 2), max_others=4, max_length=st.none() | st.integers(0, 20)))
def test_interval_search_agrees_with_the_space_time_astar(problem: Problem) -> None:
    planner, ws = SafePlanner(problem.ws, delta=problem.delta), problem.ws
    start, goal = ws.cell_id(problem.start), ws.cell_id(problem.goal)
    limit = ws.plan_length_limit if problem.max_length is None else problem.max_length
    found: list[SearchResult | None] = []
    for intervals in (False, True):
        table = ReservationTable(ws, problem.delta, vertex_keys=not intervals)
        table.sync(problem.others)
        heuristic = planner.graph.distances(goal, table.blocked_throughout(problem.start_step))
        args = (planner.grid, table, heuristic, start, goal, problem.start_step, limit)
        found.append(outcome(partial(search, *args)))  # the table picks the search
    timed, by_interval = found
    assert (timed is None) == (by_interval is None), (problem, timed, by_interval)
    if timed is not None and by_interval is not None:
        assert timed.cost == by_interval.cost
        assert problem.violations(by_interval.trajectory) == []


@pytest.mark.parametrize(("width", "drones", "seed", "delta"),
                         [(16, 16, 2017, 1), (16, 16, 3, 1), (12, 12, 1, 1), (16, 16, 2017, 0), (32, 32, 3, 0)])
def test_interval_search_matches_astar_on_the_bench_stream(width: int, drones: int, seed: int, delta: int) -> None:
    # Dense fleets: many plans wait for the goal to clear, where every state ties on f
    # and an earlier arrival in an interval often turns up after a later one was expanded.
    # At delta 0 head-on swaps are edge constraints of the interval search.
    rng = random.Random(f"{seed}-{width}-{drones}-{delta}")
    ws = random_workspace(width, width, rng)
    planner = SafePlanner(ws, delta)
    tables = {flag: ReservationTable(ws, delta, vertex_keys=not flag) for flag in (False, True)}
    stream = TaskStream(ws, drones, rng)
    for _ in range(150):
        task = stream.next_task()
        start, goal = ws.cell_id(task.start), ws.cell_id(task.goal)
        results: list[SearchResult | None] = []
        for table in tables.values():  # space-time, then safe intervals
            table.sync(task.others)
            heuristic = planner.graph.distances(goal, table.blocked_throughout(task.start_step))
            args = (planner.grid, table, heuristic, start, goal, task.start_step, ws.plan_length_limit)
            try:
                results.append(search(*args))  # the table picks the search
            except NoPlanFound:
                results.append(None)
        timed, by_interval = results
        assert (timed is None) == (by_interval is None), task
        traj: Trajectory | None = None
        if timed is not None and by_interval is not None:
            assert timed.cost == by_interval.cost, task
            assert check_trajectory(ws, by_interval.trajectory, task.others, delta, task.goal) == []
            traj = timed.trajectory
        stream.complete(task, traj)
