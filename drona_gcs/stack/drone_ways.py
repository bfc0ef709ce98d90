"""Where a drone may go: the task planner's distances around resting drones, the spot a resting drone
makes way to, and each drone's own parking cell (see :mod:`drona_gcs.stack.drone`)."""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence
from functools import lru_cache

from drona_gcs.planner import SafePlanner
from drona_gcs.planner.heuristic import UNREACHABLE, GoalDistance
from drona_gcs.stack.mail import NO_WAY
from drona_gcs.workspace import Cell, Workspace


def yield_spot(workspace: Workspace, here: Cell, way: frozenset[Cell], taken: Collection[Cell]) -> Cell | None:
    """The nearest cell off ``way`` a drone resting in ``here`` can make way to: free, reachable
    around other resting drones, and no charger or parking cell (where drones come to rest) unless
    only those are left (boxed in, a drone would otherwise stay on the way)."""
    rest_spots = {*workspace.charging_stations, *workspace.parking}
    reach = workspace.distances_from(here, frozenset(taken) - {here})
    spots = [(cell in rest_spots, steps, cell) for cell, steps in reach.items()
             if cell not in way and cell not in taken]
    return min(spots)[2] if spots else None


def walled_behind(workspace: Workspace, here: Cell, asker: Cell, taken: Collection[Cell],
                  walls: Collection[Cell]) -> frozenset[Cell]:
    """The chargers a drone resting in ``here``, asked to make way by the drone resting in ``asker``,
    reaches only through the asker's cell, from which the asker has nowhere off the way to them to make
    way to in turn but through ``here``: until this drone leaves, neither can. ``taken``: cells drones
    rest on; ``walls``: cells nothing moves out of (vehicles down), which no way crosses."""
    around = workspace.distances_from(here, frozenset({asker, *walls}))
    others = (set(taken) - {asker}) | {here}
    behind = set()
    for charger in workspace.charging_stations:
        way = workspace.shortest_way(here, charger, walls)
        if charger not in around and way and yield_spot(workspace, asker, frozenset(way), others) is None:
            behind.add(charger)
    return frozenset(behind)


def own_parking(parking: Sequence[Cell], drones: Sequence[str], me: str) -> Sequence[Cell]:
    """With a parking cell for every drone, each has its own (the i-th drone the i-th cell): idle
    drones never race for one, which would cost whole coordination rounds that end in no plan."""
    if len(parking) >= len(drones):
        return (parking[drones.index(me)],)
    return parking


#: ways(a, b, resting_now, walls): steps from a to b (see _distance_function)
Ways = Callable[[Cell, Cell, frozenset[Cell], frozenset[Cell]], int]


def _distance_function(planner: SafePlanner, resting: Collection[Cell] = ()) -> Ways:
    """Steps of the shortest static path between cells, one cached BFS per target cell.

    ``resting``: cells other drones may rest on for good (chargers, their parking cells), and
    ``resting_now`` those they rest on now. The way goes around them, where it can: a budget
    that counted the way through a parked drone left a drone without the battery for the way
    around, stranded for good (found by the systematic tester). Either end may be such a cell.
    Where they wall the goal in, the way is through them: a drone at rest makes way. It never is
    through ``walls``, cells held for good (vehicles down), which nothing moves out of, nor to one.
    """
    ws, graph, grid = planner.workspace, planner.graph, planner.grid
    always = frozenset(ws.cell_id(c) for c in resting)

    @lru_cache(maxsize=256)
    def to(goal: Cell, avoid: frozenset[int]) -> GoalDistance:
        return graph.distances(ws.cell_id(goal), avoid)

    @lru_cache(maxsize=8)
    def ids(cells: frozenset[Cell]) -> frozenset[int]:
        return frozenset(ws.cell_id(c) for c in cells)

    def steps(a: Cell, b: Cell, around: bool, resting_now: frozenset[Cell], walls_now: frozenset[Cell]) -> float:
        walls = ids(walls_now)
        avoid = always | ids(resting_now) | walls if around else walls
        tree, start = to(b, avoid), ws.cell_id(a)
        if around and start in avoid and a != b:  # out of a resting cell: by its first move
            return min((cost + tree.get(cell) for cell, cost in grid.moves_only[start]), default=UNREACHABLE)
        return tree.get(start)

    def distance(a: Cell, b: Cell, resting_now: frozenset[Cell], walls: frozenset[Cell]) -> int:
        if a in walls or b in walls:
            return NO_WAY  # nothing gets into a vehicle down's cell (a pickup it sits on, a charger)
        d = steps(a, b, True, resting_now, walls)
        if d >= UNREACHABLE:
            d = steps(a, b, False, resting_now, walls)
        return int(d) if d < UNREACHABLE else NO_WAY

    return distance
