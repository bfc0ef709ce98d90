"""Exact distance-to-goal heuristic: one breadth-first search in C per goal.

The space-time search needs the true static distance to the goal (with the
Manhattan bound it floods space-time wherever obstacles force a detour). A
lazy backward A* (reverse resumable A*) was tried first: on 20% random grids
it settles most of the start-goal bounding box, thousands of cells per plan
in Python. scipy's ``breadth_first_order`` visits the whole 256x256 grid in
about 1.6 ms, so we run it once per goal and turn BFS order into levels.
When moves cost differently (for example a costlier climb) Dijkstra is used.

``blocked`` cells are obstacles for this plan only: drones parked there for
every step of the plan. They are cut out of the graph by turning their
out-edges into self-loops, so the heuristic stays admissible and the forward
search does not flood behind them. A cut stays until a search with other
blocked cells changes it (only the difference is touched), and :meth:`whole`
gives the graph back uncut.
"""

from __future__ import annotations

import math
from typing import cast

import numpy as np
from scipy.sparse import csgraph, csr_matrix

from drona_gcs.planner.grid import GridIndex

#: Distance of a cell that cannot reach the goal.
UNREACHABLE = 1 << 40


def as_int_if_whole(cost: float) -> float:
    """``cost`` as an int when it is a whole number (the default costs are 1.0).

    Distances and f values then stay ints: int arithmetic, comparisons and hashing
    cost the searches' inner loops less than float ones, and ints mixed with
    floats (such as :data:`UNREACHABLE`) less still. Compiled by mypyc, it gives a
    float all the same (the annotation says so), which compiled code keeps unboxed.
    """
    return int(cost) if math.isfinite(cost) and cost == int(cost) else cost


class DistanceGraph:
    """The reversed move graph of one :class:`GridIndex`, ready for scipy."""

    def __init__(self, grid: GridIndex) -> None:
        n = len(grid.coords)
        rows, cols, costs = [], [], []
        for src, moves in enumerate(grid.moves):
            for dst, cost, _ in moves:
                rows.append(dst)  # reversed: search from the goal along incoming moves
                cols.append(src)
                costs.append(cost)
        self.n = n
        move_costs = set(costs)
        #: the common cost of every move, when BFS levels times it are exact distances
        self.unit = move_costs.pop() if len(move_costs) == 1 else None
        self.matrix = csr_matrix((np.asarray(costs, dtype=float), (rows, cols)), shape=(n, n))
        self.matrix.sort_indices()
        self._ptr: list[int] = self.matrix.indptr.tolist()
        self._cut: frozenset[int] = frozenset()  #: cells cut out of ``matrix`` now
        self._saved: dict[int, np.ndarray] = {}  #: a cut row's original edges

    def distances(self, goal: int, blocked: frozenset[int]) -> GoalDistance:
        """Cost from every cell to ``goal`` avoiding ``blocked``; UNREACHABLE where none."""
        cut = frozenset(blocked - {goal} if goal in blocked else blocked)  # kept: never a caller's set
        self._cut_to(cut)
        result = self._search(goal)
        known = result.known
        for cell in cut:  # so the search never enters a parked drone's cell
            known[cell] = UNREACHABLE
        return result

    def whole(self) -> csr_matrix:
        """The move graph with no cell cut out (for searches that must see every move); valid
        until the next :meth:`distances`, which cuts it in place."""
        self._cut_to(frozenset())
        return self.matrix

    def _cut_to(self, cells: frozenset[int]) -> None:
        """Cut exactly ``cells`` out of the graph, touching only rows that differ from the last cut.

        Parked drones change little from one plan to the next, while a fleet of 128
        parks about 27 at a time: re-cutting them all for every plan cost more than the BFS.
        A cut row's edges become self-loops: a parked cell keeps its distance but leads nowhere.
        """
        if cells == self._cut:
            return
        if cells and (min(cells) < 0 or max(cells) >= self.n):
            # Checked before any row changes: a half-made cut would outlive this call.
            raise ValueError(f"cells to cut must be ids 0..{self.n - 1}, got {min(cells)}..{max(cells)}")
        indices, ptr, saved = self.matrix.indices, self._ptr, self._saved
        for row in self._cut - cells:
            indices[ptr[row]:ptr[row + 1]] = saved.pop(row)
        for row in cells - self._cut:
            lo, hi = ptr[row], ptr[row + 1]
            saved[row] = indices[lo:hi].copy()
            indices[lo:hi] = row
        self._cut = cells

    def _search(self, goal: int) -> GoalDistance:
        return self._bfs(goal) if self.unit is not None else self._dijkstra(goal)

    def _bfs(self, goal: int) -> GoalDistance:
        order, pred = csgraph.breadth_first_order(self.matrix, goal, directed=True,
                                                  return_predecessors=True)
        assert self.unit is not None
        return GoalDistance(goal, order, memoryview(pred), as_int_if_whole(self.unit))

    def _dijkstra(self, goal: int) -> GoalDistance:
        dist = csgraph.dijkstra(self.matrix, directed=True, indices=goal)
        finite = np.isfinite(dist)
        dist[~finite] = UNREACHABLE
        # memoryview[float]: a bare memoryview's items are typed int, and mypyc checks them
        return GoalDistance(goal, np.flatnonzero(finite), None, 0.0, cast("memoryview[float]", memoryview(dist)))


class GoalDistance:
    """Distance of each cell to one goal, read off the BFS tree on demand.

    Turning the whole BFS order into levels costs more than the search itself
    at 256x256, while the search asks for a few hundred cells. So a cell's
    distance is its depth in the predecessor tree, found by walking up to a
    cell already known and memoised on the way back down. ``known`` is public
    so the search's inner loop can try a plain dict lookup first.
    """

    __slots__ = ("_full", "_pred", "_unit", "known", "reached")

    def __init__(self, goal: int, reached: np.ndarray, pred: memoryview | None, unit: float,
                 full: memoryview[float] | None = None) -> None:
        self.known: dict[int, float] = {goal: 0}
        self.reached = reached  #: every cell with a finite distance
        self._pred = pred
        self._unit = unit
        self._full = full

    def tree_path(self, cell: int) -> list[int] | None:
        """A shortest path from ``cell`` to the goal (the BFS tree's), or None without a tree."""
        pred = self._pred
        if pred is None or self.get(cell) >= UNREACHABLE:
            return None
        path = [cell]
        while pred[cell] >= 0:
            cell = pred[cell]
            path.append(cell)
        return path

    def get(self, cell: int) -> float:
        found = self.known.get(cell)
        if found is not None:
            return found
        if self._full is not None:
            value = self._full[cell]
            self.known[cell] = value
            return value
        known, pred, walk = self.known, self._pred, []
        assert pred is not None
        while cell not in known:
            parent = pred[cell]
            walk.append(cell)
            if parent < 0:  # not reached by the BFS
                for c in walk:
                    known[c] = UNREACHABLE
                return UNREACHABLE
            cell = parent
        depth = known[cell]
        for c in reversed(walk):
            depth += self._unit
            known[c] = depth
        return depth
