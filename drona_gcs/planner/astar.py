"""Exact space-time A* over ``(cell, step)`` (paper section 3.2.2, A*-based plan generator).

The search finds a minimum-cost plan from ``start`` at step ``n`` to ``goal``
that honours every rule of :mod:`drona_gcs.safety`, or proves that none
exists within ``L_max`` steps. :func:`search` is the entry point for both
searches: with uniform costs (the paper's) it can hand the problem, after the
shared checks and the free-shortest-path shortcut, to the safe-interval
search of :mod:`.sipp`, which gives the same costs with a state per safe
interval instead of per step (:class:`~drona_gcs.planner.SafePlanner` does so
when the skew window is at least one step). What keeps the space-time search
exact and fast:

* **States** are ints ``step * num_cells + cell``, the same keys as the
  reservation table, so a conflict test is one dict lookup.
* **Heuristic**: the exact static distance to the goal (lazy, see
  :mod:`.heuristic`), raised to ``(goal_free_from - step) * min_cost`` when
  another drone still crosses the goal later. Both bounds are consistent, and
  their maximum stops the search from flooding space-time while it waits for
  the goal to clear.
* **Time collapse**: from the step after which only parked drones remain
  (``static_from``), nothing changes with time any more, so every later step
  maps to that one layer. This bounds the state space by
  ``cells x (static_from - n + 1)`` even when no plan exists. It is exact when
  every primitive costs the same (cost then equals length, so ``L_max`` is a
  cost bound); with mixed costs, time is never collapsed.
* **Open list**: a bucket per f value, LIFO inside a bucket, so that among
  equal f the deepest state goes first and the search runs straight down a
  free corridor without heap operations.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable

from drona_gcs.errors import GoalCutOff, NoPlanFound
from drona_gcs.planner.grid import GridIndex
from drona_gcs.planner.heuristic import UNREACHABLE, GoalDistance
from drona_gcs.planner.layers import TimeLayers
from drona_gcs.planner.reservations import ALWAYS_FREE, ReservationTable, _add, _sub
from drona_gcs.planner.result import BudgetExceeded, SearchResult, SearchStats
from drona_gcs.planner.sealing import Seal
from drona_gcs.planner.sipp import search_intervals

INF = math.inf

__all__ = ["BudgetExceeded", "SearchResult", "SearchStats", "search"]


def search(grid: GridIndex, table: ReservationTable, heuristic: GoalDistance,
           start: int, goal: int, n: int, max_length: int, seal: Seal | None = None,
           budget: int | None = None, layers: TimeLayers | None = None) -> SearchResult:
    """Find a minimum-cost safe plan; raise :class:`NoPlanFound` when none exists.

    The table's kind decides the search: over safe intervals (:mod:`.sipp`) with a
    table built with ``vertex_keys=False`` (uniform costs only), otherwise over
    ``(cell, step)``.
    With a ``budget``, raise :class:`BudgetExceeded` after that many expansions,
    so the caller can compute the (costlier) seal pruning only when needed.
    ``layers`` only serve the space-time search.
    """
    if not table.keeps_vertex:
        table.look_from(n)
    goal_ready = table.goal_free_from(goal)
    if goal_ready is None:
        raise NoPlanFound("the goal is another drone's resting cell for good")
    goal_ready = max(goal_ready, n)  # free "since ever" (far in the past) reads as free from n
    if goal_ready > n + max_length:  # arriving earlier, another drone would still come by
        raise NoPlanFound(f"the goal is taken until step {goal_ready}, beyond the plan's {max_length} steps")
    if table.conflicts(start, n):
        raise NoPlanFound("the start cell is taken by another drone at the start step")
    if heuristic.get(start) >= UNREACHABLE:
        raise GoalCutOff("the goal cannot be reached from the start")
    hopeless = seal.hopeless if seal is not None else None
    if hopeless is not None and hopeless(start, n):
        raise GoalCutOff("drones parking for good seal the goal off before it can be reached")
    uniform = grid.uniform_cost
    if not table.keeps_vertex:
        if uniform is None:
            raise ValueError("the safe-interval search (a table without vertex keys) needs every "
                             "primitive to cost the same")
        found = _shortest_path_if_free(grid, table, heuristic, start, n, max_length, goal_ready)
        return found or search_intervals(grid, table, heuristic, start, goal, n, max_length, goal_ready,
                                         hopeless, budget)
    pre_keys = table.pre_keys(n)
    _add(table.vertex, pre_keys)  # drones still waiting to start, for this search only
    try:
        found = _shortest_path_if_free(grid, table, heuristic, start, n, max_length, goal_ready)
        if found is not None:
            return found
        # With uniform costs the layers from `static` on are one; otherwise never collapse.
        static = table.static_from(n) if uniform is not None else n + max_length + 1
        return _run(grid, table, heuristic, start, goal, n, max_length, static, goal_ready, hopeless, budget,
                    layers)
    finally:
        _sub(table.vertex, pre_keys)


def _shortest_path_if_free(grid: GridIndex, table: ReservationTable, heuristic: GoalDistance,
                           start: int, n: int, max_length: int, goal_ready: int) -> SearchResult | None:
    """The BFS tree's shortest path, when no other drone is in its way.

    Its cost equals the heuristic at the start, a lower bound on every plan's
    cost, so when it is safe it is optimal and the search can be skipped. On a
    sparse fleet that is most plans, and checking it costs one lookup a step
    (in the table's vertex keys, or in its safe intervals).
    """
    path = heuristic.tree_path(start)
    if path is None or len(path) - 1 > max_length or n + len(path) - 1 < goal_ready:
        return None
    taken = _taken_by_vertex(table) if table.keeps_vertex else _taken_by_interval(table)
    n_cells, swaps = table.n, table.swaps
    for k in range(1, len(path)):
        step, cell = n + k, path[k]
        if taken(step, cell) or (swaps and ((step - 1) * n_cells + path[k - 1]) * n_cells + cell in swaps):
            return None
    traj, primitives = grid.trajectory(n, path)
    cost = grid.uniform_cost * len(primitives) if grid.uniform_cost is not None else grid.model.plan_cost(primitives)
    return SearchResult(traj, primitives, cost, SearchStats(0, len(path)))


def _taken_by_vertex(table: ReservationTable) -> Callable[[int, int], bool]:
    n_cells, vertex, perm = table.n, table.vertex, table.perm
    return lambda step, cell: step * n_cells + cell in vertex or perm.get(cell, step + 1) <= step


def _taken_by_interval(table: ReservationTable) -> Callable[[int, int], bool]:
    cache, intervals = table.interval_cache, table.safe_intervals

    def taken(step: int, cell: int) -> bool:
        found = cache[cell] or intervals(cell)
        if found is ALWAYS_FREE:
            return False
        for lo, hi in found:  # noqa: SIM110 (free_at inlined: a generator costs more, every step of most plans)
            if lo <= step <= hi:
                return False
        return True

    return taken


def _run(grid: GridIndex, table: ReservationTable, heuristic: GoalDistance, start: int, goal: int,
         n: int, max_length: int, static: int, goal_ready: int,
         hopeless: Callable[[int, int], bool] | None, budget: int | None,
         layers: TimeLayers | None = None) -> SearchResult:
    """The search loop, kept flat and with local names: it runs a million times a second."""
    n_cells, uniform, min_cost = table.n, grid.uniform_cost or 1.0, grid.min_cost
    last_step = n + max_length
    with_hold, without_hold = grid.successors, grid.moves_only
    known, get_h = heuristic.known, heuristic.get  # parked drones' cells are UNREACHABLE there
    vertex, swaps = table.vertex, table.swaps
    later_perm = table.parking_after(n)  # drones that will park for good after step n
    start_key = n * n_cells + start
    # g[key] >= 0 for open states; closing a state stores -1 - g, so one lookup tells both.
    g: dict[int, float] = {start_key: 0.0}
    parent: dict[int, int] = {}
    f0 = max(heuristic.get(start), (goal_ready - n) * min_cost)
    buckets: dict[float, list[int]] = {f0: [start_key]}
    fheap = [f0]
    expansions = generated = 0
    while fheap:
        f = fheap[0]
        bucket = buckets[f]
        key = bucket.pop()
        if not bucket:
            heapq.heappop(fheap)
            del buckets[f]
        gk = g[key]
        if gk < 0:
            continue
        g[key] = -1.0 - gk
        expansions += 1
        if expansions == budget:
            raise BudgetExceeded(expansions)
        step, cell = divmod(key, n_cells)
        if step == static:  # collapsed layer: the true step follows from the cost
            step = n + round(gk / uniform)
        if cell == goal and step >= goal_ready:
            return _result(grid, key, start_key, parent, n, n_cells, gk, expansions, generated)
        nstep = step + 1
        if nstep > last_step:
            continue
        wait_bound = (goal_ready - nstep) * min_cost
        if layers is not None:  # the walls of drones parked by the next step
            field = layers.at(nstep)
            known, get_h = field.known, field.get
        # Holding in the collapsed layer would lead back to the same state.
        base = (nstep if nstep < static else static) * n_cells
        swap_base = (step * n_cells + cell) * n_cells
        for nxt, cost in (with_hold if step < static else without_hold)[cell]:
            k1 = base + nxt
            if k1 in vertex:
                continue
            g1 = gk + cost
            if g1 >= g.get(k1, INF):
                continue
            if later_perm and later_perm.get(nxt, INF) <= nstep:
                continue
            if swaps and swap_base + nxt in swaps:
                continue
            h1 = known.get(nxt)
            if h1 is None:
                h1 = get_h(nxt)
            if h1 >= UNREACHABLE or (hopeless is not None and hopeless(nxt, nstep)):
                continue
            if wait_bound > h1:  # noqa: PLR1730 (a call costs more in this loop)
                h1 = wait_bound
            g[k1] = g1
            parent[k1] = key
            f1 = g1 + h1
            generated += 1
            bucket1 = buckets.get(f1)
            if bucket1 is None:
                buckets[f1] = [k1]
                heapq.heappush(fheap, f1)
            else:
                bucket1.append(k1)
    raise NoPlanFound(f"no safe plan reaches the goal within {max_length} steps")


def _result(grid: GridIndex, key: int, start_key: int, parent: dict[int, int], n: int,
            n_cells: int, cost: float, expansions: int, generated: int) -> SearchResult:
    chain = [key]
    while chain[-1] != start_key:
        chain.append(parent[chain[-1]])
    chain.reverse()
    traj, primitives = grid.trajectory(n, [k % n_cells for k in chain])
    return SearchResult(traj, primitives, cost, SearchStats(expansions, generated))
