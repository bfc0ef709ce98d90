"""Deadline pruning for goals that drones parking for good will seal off.

When a drone is about to park for good in the only corridor to my goal (or
out of my pocket), no plan may exist, and proving it by search means visiting
every reachable ``(cell, step)`` up to the time the fleet stops moving: hundreds
of milliseconds. This module finds the earliest *seal time* ``T`` at which the
parked drones cut my start off from the goal, and the region ``R`` of cells
that can still reach the goal once they have. Every plan must be inside ``R``
from ``T`` on, so a state ``(c, t)`` is hopeless when

* ``t >= T`` and ``c`` is outside ``R``, or
* ``t < T`` and even the shortest way from ``c`` into ``R`` arrives after ``T``.

Both tests are necessary conditions, so pruning on them keeps the search exact.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import csgraph

from drona_gcs.planner.heuristic import UNREACHABLE, DistanceGraph, GoalDistance
from drona_gcs.planner.reservations import ReservationTable


@dataclass(frozen=True)
class Seal:
    time: int
    inside: GoalDistance  #: distances to the goal with every drone parked by ``time`` in place
    steps_in: memoryview  #: fewest steps from each cell into the region still connected to the goal

    def hopeless(self, cell: int, step: int) -> bool:
        if step >= self.time:
            return self.inside.get(cell) >= UNREACHABLE
        return step + self.steps_in[cell] > self.time


def find_seal(graph: DistanceGraph, table: ReservationTable, start: int, goal: int,
              step: int) -> Seal | None:
    """The earliest time parked drones cut ``start`` off from ``goal``; None if they never do."""
    times = sorted({t for t in table.perm.values() if t > step})
    if not times:
        return None

    def field(t: int) -> GoalDistance:
        return graph.distances(goal, frozenset(c for c, s in table.perm.items() if s <= t))

    if field(times[-1]).get(start) < UNREACHABLE:
        return None
    lo, hi = 0, len(times) - 1  # invariant: cut off at times[hi]
    while lo < hi:
        mid = (lo + hi) // 2
        if field(times[mid]).get(start) >= UNREACHABLE:
            hi = mid
        else:
            lo = mid + 1
    seal_time = times[hi]
    inside = field(seal_time)
    # Blocked cells next to the region count as inside: that only weakens the bound.
    steps = csgraph.dijkstra(graph.whole(), directed=True, indices=inside.reached, unweighted=True,
                             min_only=True)
    steps[~np.isfinite(steps)] = UNREACHABLE
    return Seal(seal_time, inside, memoryview(steps.astype(np.int64)))
