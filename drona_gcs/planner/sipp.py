"""Exact safe-interval path planning (SIPP, Phillips and Likhachev 2011) for uniform costs.

When every primitive, hold included, costs the same, a plan's cost is its
length, so the cheapest plan is the one that reaches the goal for good at the
earliest step. Then the space-time A* (:mod:`.astar`) wastes most of its work
on states that differ only by how long a drone has waited: ``(cell, t)`` and
``(cell, t + 1)`` in the same free stretch of time lead to the same futures,
and the later one can only be worse.

SIPP keeps one state per *safe interval*: a maximal run of steps in which a
cell is free (:meth:`ReservationTable.safe_intervals`). The state's ``g`` is
the earliest arrival in that interval; from there the drone may wait until
the interval ends, so every arrival in a neighbour's interval is reachable by
waiting first and moving at the last possible moment. An earlier arrival in
the same interval can do everything a later one can (wait), which is why
keeping only the earliest is exact; the plan length bound ``L_max`` is exact
for the same reason. The goal is reached for good in its last interval, the
one that never ends.

What carries over from the A*: the heuristic (static distance, raised by the
wait for the goal to clear), the seal pruning (``hopeless`` only grows with
time, so pruning the earliest arrival of an interval prunes all of it), and
the expansion budget. The time-layered fields do not: they fight flooding in
time, which safe intervals do not do, and reading them per arrival cost more
than they saved on the bench workload.

One difference: the wait bound makes the heuristic depend on the arrival, not
only on the state, so a later arrival can tie on f with an earlier one and be
expanded first. A state is therefore reopened whenever an earlier arrival
turns up. f = max(elapsed + distance, wait for the goal) never decreases with
the arrival, so the usual A* argument holds: until the goal is expanded, some
state of an optimal plan is open with an arrival no later than that plan's,
and so with f no more than the optimum.

Head-on swaps (only reserved at ``delta == 0``) are edge constraints: the
move leaves at the first departure step the swap table allows.
"""

from __future__ import annotations

from collections.abc import Callable
from heapq import heappop, heappush
from itertools import pairwise

from drona_gcs.errors import NoPlanFound
from drona_gcs.planner.grid import GridIndex
from drona_gcs.planner.heuristic import UNREACHABLE, GoalDistance, as_int_if_whole
from drona_gcs.planner.reservations import ALWAYS_FREE, FOREVER, ReservationTable
from drona_gcs.planner.result import BudgetExceeded, SearchResult, SearchStats


def search_intervals(grid: GridIndex, table: ReservationTable, heuristic: GoalDistance,
                     start: int, goal: int, n: int, max_length: int, goal_ready: int,
                     hopeless: Callable[[int, int], bool] | None = None,
                     budget: int | None = None) -> SearchResult:
    """SIPP from ``start`` at step ``n``; the caller has checked that ``start`` is free at ``n``.

    States are ints ``interval_index * num_cells + cell`` (indices into
    :meth:`ReservationTable.safe_intervals`); ``g`` holds the earliest known
    arrival as steps after ``n``.
    """
    assert grid.uniform_cost is not None, "SIPP needs every primitive to cost the same"
    unit = as_int_if_whole(grid.uniform_cost)
    n_cells, last_step, moves, swaps = table.n, n + max_length, grid.next_cells, table.swaps
    intervals, cache = table.safe_intervals, table.interval_cache
    first = next((j for j, (lo, hi) in enumerate(intervals(start)) if lo <= n <= hi), None)
    if first is None:  # the caller's check, kept: a bare StopIteration would name nothing
        raise NoPlanFound("the start cell is taken by another drone at the start step")
    start_key = first * n_cells + start
    known, get_h = heuristic.known, heuristic.get  # parked drones' cells are UNREACHABLE there
    g: dict[int, int] = {start_key: 0}
    closed: dict[int, int] = {}  #: the arrival each state was last expanded with
    parent: dict[int, int] = {}
    f0 = max(get_h(start), (goal_ready - n) * unit)
    buckets: dict[float, list[int]] = {f0: [start_key]}
    fheap = [f0]
    expansions = generated = 0
    while fheap:
        f = fheap[0]
        bucket = buckets[f]
        key = bucket.pop()
        if not bucket:
            heappop(fheap)
            del buckets[f]
        elapsed = g[key]
        if closed.get(key) == elapsed:
            continue  # a stale entry: expanded already with this arrival
        closed[key] = elapsed
        expansions += 1
        if expansions == budget:
            raise BudgetExceeded(expansions)
        idx, cell = divmod(key, n_cells)
        hi = (cache[cell] or intervals(cell))[idx][1]
        if cell == goal and hi == FOREVER:
            return _result(grid, table, key, start_key, g, parent, n, elapsed, expansions, generated)
        arrival = n + elapsed
        leave_by = hi if hi < last_step else last_step - 1  # the last step I may still be here
        if arrival > leave_by:
            continue
        for nxt in moves[cell]:
            h_now = known.get(nxt)
            if h_now is None:
                h_now = get_h(nxt)
            if h_now >= UNREACHABLE:
                continue  # a parked drone's cell, or cut off from the goal for good
            ivs = cache[nxt] or intervals(nxt)
            if ivs is ALWAYS_FREE:  # most cells, no other drone ever comes by: the loop below, inlined
                # No head-on swap either: the other drone would be in `nxt` as I leave for it.
                t = arrival + 1
                if hopeless is not None and hopeless(nxt, t):
                    continue
                e1 = t - n
                if e1 >= g.get(nxt, FOREVER):
                    continue
                wait = (goal_ready - t) * unit
                f1 = e1 * unit + (h_now if h_now > wait else wait)
                g[nxt] = e1
                parent[nxt] = key
                generated += 1
                bucket1 = buckets.get(f1)
                if bucket1 is None:
                    buckets[f1] = [nxt]
                    heappush(fheap, f1)
                else:
                    bucket1.append(nxt)
                continue
            for j, (lo2, hi2) in enumerate(ivs):
                if hi2 <= arrival:
                    continue
                t = arrival + 1 if lo2 <= arrival else lo2  # earliest arrival in this interval
                if t - 1 > leave_by:
                    break  # later intervals open later still
                # A head-on swap needs the other drone in `nxt` at t - 1: only an arrival as the
                # interval opens can be one.
                if swaps and t == lo2 and ((t - 1) * n_cells + cell) * n_cells + nxt in swaps:
                    t = _swap_free_arrival(swaps, n_cells, cell, nxt, t + 1, min(hi2, leave_by + 1))
                    if t < 0:
                        continue
                if hopeless is not None and hopeless(nxt, t):
                    break  # hopelessness only grows with time: later intervals are hopeless too
                k1 = j * n_cells + nxt
                e1 = t - n
                if e1 >= g.get(k1, FOREVER):
                    continue  # an arrival as early is known (reopening a closed state is allowed)
                wait = (goal_ready - t) * unit
                f1 = e1 * unit + (h_now if h_now > wait else wait)
                g[k1] = e1
                parent[k1] = key
                generated += 1
                bucket1 = buckets.get(f1)
                if bucket1 is None:
                    buckets[f1] = [k1]
                    heappush(fheap, f1)
                else:
                    bucket1.append(k1)
    raise NoPlanFound(f"no safe plan reaches the goal within {max_length} steps")


def _swap_free_arrival(swaps: dict[int, int], n_cells: int, cell: int, nxt: int, t: int,
                       latest: int) -> int:
    """The first arrival ``>= t`` and ``<= latest`` whose move is no head-on swap; -1 if none."""
    while t <= latest:
        if ((t - 1) * n_cells + cell) * n_cells + nxt not in swaps:
            return t
        t += 1
    return -1


def _result(grid: GridIndex, table: ReservationTable, key: int, start: int, g: dict[int, int],
            parent: dict[int, int], n: int, elapsed: int, expansions: int,
            generated: int) -> SearchResult:
    """Unroll the interval states into cells, waiting in each until the move on."""
    n_cells = table.n
    chain = [key]
    while chain[-1] != start:
        chain.append(parent[chain[-1]])
    chain.reverse()
    cells: list[int] = []
    for here, there in pairwise(chain):
        arrive_next = g[there]
        cells.extend([here % n_cells] * (arrive_next - len(cells)))
    cells.append(key % n_cells)
    assert len(cells) == elapsed + 1
    traj, primitives = grid.trajectory(n, cells)
    assert grid.uniform_cost is not None
    return SearchResult(traj, primitives, grid.uniform_cost * len(primitives),
                        SearchStats(expansions, generated))

