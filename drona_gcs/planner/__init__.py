"""Safe plan generators: the exact A* (default) and the Z3 baseline (:mod:`.smt`).

The A* searches safe intervals (:mod:`.sipp`) when every primitive costs the
same, as in the paper, and either the skew window is at least one step or the
fleet is dense; otherwise it searches space-time ``(cell, step)`` states
(:mod:`.astar`).

:class:`SafePlanner` is the one entry point the stack uses. It keeps its
reservation table and heuristics between plans, so a drone (or a benchmark)
that plans over and over against a slowly changing fleet pays only for what
changed::

    planner = SafePlanner(workspace)
    plan = planner.plan(start, goal, start_step, others)   # others: {id: Trajectory}
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass

from drona_gcs.planner import _native

#: Whether the hot modules (``_native.HOT``) run compiled by mypyc; chosen before they are imported.
NATIVE = _native.select()

from drona_gcs.errors import ProblemError  # noqa: E402
from drona_gcs.motion import Primitive, Trajectory  # noqa: E402
from drona_gcs.planner.astar import BudgetExceeded, search  # noqa: E402
from drona_gcs.planner.grid import GridIndex  # noqa: E402
from drona_gcs.planner.heuristic import DistanceGraph, GoalDistance  # noqa: E402
from drona_gcs.planner.layers import TimeLayers  # noqa: E402
from drona_gcs.planner.reservations import ReservationTable  # noqa: E402
from drona_gcs.planner.sealing import find_seal  # noqa: E402
from drona_gcs.workspace import Cell, Workspace  # noqa: E402

__all__ = ["Plan", "SafePlanner", "check_endpoints"]

#: Expansions after which a search stops to look for a seal (plus terms for path and grid size).
_SEAL_AFTER = 64
#: More for the safe-interval search: one of its expansions stands for a whole run of waiting,
#: and on the bench workload it rarely needs the seal (a seal costs a few BFS over the grid).
_INTERVAL_SEAL_EXTRA = 236
#: Drones per free cell from which the safe-interval search pays at Delta 0 too. Plans then wait
#: often, and the space-time search keeps a state per step waited. Measured over the bench streams
#: of seeds 2017, 1, 2 and 3 (time, alternating in one process): 0.88 of the space-time search's at
#: 32x32/32 (3.9%), 0.93 at 16x16/16 (7.8%), 0.97 at 16x16/8 (3.9%); but 1.01 at 32x32/16 (2%),
#: 1.15 at 64x64/64 (1.6%) and 1.42 at 64x64/32 (0.8%), where plans rarely wait.
DENSE_FLEET = 0.03


@dataclass(frozen=True)
class Plan:
    """A safe plan: its timed trajectory, primitives and cost."""

    trajectory: Trajectory
    primitives: tuple[Primitive, ...]
    cost: float
    expansions: int = 0


class SafePlanner:
    """Space-time A* planner for one workspace, skew window and cost table."""

    #: Expansions (plus terms for path and grid size) after which a search restarts with seal
    #: pruning and the time-layered heuristic. Both keep the search exact; tests set it to
    #: -10**9 to take that path every time.
    seal_after = _SEAL_AFTER

    def __init__(self, workspace: Workspace, delta: int | None = None,
                 costs: Mapping[Primitive, float] | None = None, heuristic_cache: int = 32,
                 fleet_size: int | None = None, intervals: bool | None = None) -> None:
        """``fleet_size`` (default: the workspace's drones) picks the search at Delta 0;
        ``intervals`` forces one (True needs uniform costs)."""
        self.workspace = workspace
        self.delta = workspace.delta if delta is None else delta
        if self.delta < 0:
            raise ProblemError(f"delta must be >= 0, got {self.delta}")
        self.grid = GridIndex.build(workspace, costs)
        drones = len(workspace.drones) if fleet_size is None else fleet_size
        self.intervals = self._searches_intervals(drones, intervals)
        # Only the space-time search reads vertex keys, and keeping them costs on every plan.
        self.table = ReservationTable(workspace, self.delta, vertex_keys=not self.intervals)
        self.graph = DistanceGraph(self.grid)
        self._heuristics: OrderedDict[tuple[int, frozenset[int]], GoalDistance] = OrderedDict()
        self._cache_size = heuristic_cache

    def _searches_intervals(self, drones: int, forced: bool | None) -> bool:
        """Whether searches run over safe intervals: only with uniform costs; then with a skew
        window of at least one step, or a fleet dense enough that plans often wait. At Delta 0 a
        drone reserves each cell for a single step, and in a sparse fleet plans rarely wait: there
        the space-time search is cheaper (see :data:`DENSE_FLEET`)."""
        if self.grid.uniform_cost is None:
            if forced:
                raise ProblemError("the safe-interval search needs every primitive to cost the same")
            return False
        if forced is not None:
            return forced
        return self.delta >= 1 or drones >= DENSE_FLEET * sum(self.grid.free)

    def __deepcopy__(self, memo: dict[int, object]) -> SafePlanner:
        # A planner is a cache over immutable inputs: copies of a simulated fleet share it.
        return self

    def plan(self, start: Cell, goal: Cell, start_step: int, others: Mapping[str, Trajectory],
             max_length: int | None = None) -> Plan:
        """A minimum-cost safe plan from ``start`` at ``start_step`` to ``goal``.

        Raises :class:`~drona_gcs.errors.NoPlanFound` when no safe plan of at
        most ``max_length`` (default: the workspace's L_max) steps exists.
        """
        check_endpoints(self.workspace, start, goal)
        limit = self.workspace.plan_length_limit if max_length is None else max_length
        if limit < 0:
            raise ProblemError(f"max_length must be >= 0, got {limit}")
        self.table.sync(others)
        ws = self.workspace
        start_id, goal_id = ws.cell_id(start), ws.cell_id(goal)
        heuristic = self._heuristic(goal_id, self.table.blocked_throughout(start_step))
        args = (self.grid, self.table, heuristic, start_id, goal_id, start_step, limit)
        # Looking for a seal costs a few BFS over the grid: worth it once the search has
        # spent about as much, or a few times the straight path's work.
        intervals = self.intervals
        budget = self.seal_after + 4 * int(heuristic.get(start_id) / self.grid.min_cost if self.grid.min_cost else 0) \
            + len(self.grid.coords) // 20 + (_INTERVAL_SEAL_EXTRA if intervals else 0)
        try:
            found = search(*args, budget=max(1, budget))
        except BudgetExceeded:
            # A long search: drones parking for good may have sealed the goal off,
            # and pruning on that can end a search that would otherwise visit all space-time.
            seal = find_seal(self.graph, self.table, start_id, goal_id, start_step)
            # In space-time, drones parking in the way also make long detours: a
            # heuristic that knows where they will park keeps the search from flooding behind
            # them. Safe intervals do not flood in time, and the layers cost them more than they save.
            layers = None if intervals else TimeLayers(self.graph, self.table, goal_id, start_step, heuristic)
            found = search(*args, seal=seal, layers=layers)
        return Plan(found.trajectory, found.primitives, found.cost, found.stats.expansions)

    def _heuristic(self, goal: int, blocked: frozenset[int]) -> GoalDistance:
        """Distances to ``goal``; recent goals are cached, since drones often replan to them."""
        key = (goal, blocked)
        found = self._heuristics.get(key)
        if found is None:
            found = self.graph.distances(goal, blocked)
            self._heuristics[key] = found
            if len(self._heuristics) > self._cache_size:
                self._heuristics.popitem(last=False)
        else:
            self._heuristics.move_to_end(key)
        return found


def check_endpoints(workspace: Workspace, start: Cell, goal: Cell) -> None:
    """Refuse a start or goal outside the grid or on an obstacle, naming which."""
    for name, cell in (("start", start), ("goal", goal)):
        if not workspace.in_bounds(cell):
            raise ProblemError(f"{name} {list(cell)} is outside the grid {list(workspace.size)}")
        if cell in workspace.obstacles:
            raise ProblemError(f"{name} {list(cell)} is on an obstacle")
