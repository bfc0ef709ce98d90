"""A sharper heuristic for long searches: distances that know where drones will park.

The plain heuristic walls off only the cells of drones parked already. A
drone still flying will park for good at its last cell from a known step on,
so for states at or after that step its cell is a wall too. These fields
are exact static distances with more walls, so they are admissible at their
step and later; and since each later field has more walls, the heuristic grows
with time and stays consistent (a move costs at least the drop in distance).
Each field costs a BFS, so they are built lazily, and only for searches that
have already run long (see :class:`~drona_gcs.planner.SafePlanner`).
"""

from __future__ import annotations

from bisect import bisect_right

from drona_gcs.planner.heuristic import DistanceGraph, GoalDistance
from drona_gcs.planner.reservations import ReservationTable

#: At most this many fields besides the current one.
MAX_LAYERS = 2


class TimeLayers:
    def __init__(self, graph: DistanceGraph, table: ReservationTable, goal: int, step: int,
                 now: GoalDistance) -> None:
        self._graph, self._goal, self._now = graph, goal, now
        self._parks = dict(table.perm)
        times = sorted({t for t in self._parks.values() if t > step})
        # A few layers catch most of the detours; one per parking time would cost a BFS each.
        picks = {times[(i * len(times)) // MAX_LAYERS] for i in range(1, MAX_LAYERS)} if times else set()
        self.thresholds = sorted(picks | set(times[-1:]))
        self._fields: list[GoalDistance | None] = [None] * len(self.thresholds)

    def at(self, step: int) -> GoalDistance:
        """The field for states at ``step``: every drone parked by then is a wall."""
        k = bisect_right(self.thresholds, step) - 1
        if k < 0:
            return self._now
        found = self._fields[k]
        if found is None:
            walls = frozenset(c for c, t in self._parks.items() if t <= self.thresholds[k])
            found = self._fields[k] = self._graph.distances(self._goal, walls)
        return found
