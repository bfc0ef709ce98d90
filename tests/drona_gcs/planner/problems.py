"""Planning problems for the planner's property tests (test_properties.py, test_sipp.py): Hypothesis
strategies that draw them, the brute force that solves them, and the checks of a plan.

The other drones come three ways: planned in turn by the A* (a consistent
fleet, as the protocol makes), random walks the checker accepts as a fleet,
and "interferers" timed to cross, meet head-on or linger on my shortest route.
Hypothesis runs derandomized, so CI sees the same examples every time.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TypeVar

from hypothesis import HealthCheck, assume, event, settings
from hypothesis import strategies as st

from drona_gcs.errors import NoPlanFound
from drona_gcs.motion import MotionModel, Primitive, Trajectory
from drona_gcs.planner import Plan, SafePlanner
from drona_gcs.planner.smt import plan_smt
from drona_gcs.safety import check_fleet, check_pair, check_trajectory
from drona_gcs.workspace import Cell, Workspace

P = Primitive
R = TypeVar("R")
MOVES = (P.XP, P.XM, P.YP, P.YM, P.ZP, P.ZM)
UNIT: dict[Primitive, float] = {}
COST_TABLES: list[dict[Primitive, float]] = [
    UNIT,
    {P.HOLD: 1.0, **dict.fromkeys(MOVES, 2.0)},  # moving costs twice as much as hovering
    {P.ZP: 3.0},  # a costly climb
    {P.HOLD: 0.5},  # cheap hover
    {P.HOLD: 3.0, P.XP: 2.0},  # dear hover, and one dearer direction
]


def _settings(examples: int) -> settings:
    return settings(max_examples=examples, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])


@dataclass(frozen=True)
class Problem:
    ws: Workspace
    start: Cell
    goal: Cell
    start_step: int
    others: Mapping[str, Trajectory]
    delta: int
    max_length: int | None = None
    costs: Mapping[Primitive, float] = field(default_factory=dict)

    def astar(self) -> Plan:
        planner = SafePlanner(self.ws, delta=self.delta, costs=self.costs)
        return planner.plan(self.start, self.goal, self.start_step, self.others, self.max_length)

    def z3(self) -> Plan:
        return plan_smt(self.ws, self.start, self.goal, self.start_step, self.others, self.delta,
                        self.max_length, self.costs)

    def violations(self, traj: Trajectory) -> list[object]:
        return list(check_trajectory(self.ws, traj, self.others, self.delta, self.goal))


def assert_valid(problem: Problem, plan: Plan) -> None:
    """The plan is safe for the checker, starts where asked and reports its true cost."""
    traj = plan.trajectory
    assert problem.violations(traj) == [], (problem, traj)
    assert traj.start_step == problem.start_step and traj.first == problem.start
    assert plan.primitives == traj.primitives()
    limit = problem.ws.plan_length_limit if problem.max_length is None else problem.max_length
    assert len(plan.primitives) <= limit
    assert math.isclose(plan.cost, MotionModel(problem.ws, problem.costs).plan_cost(plan.primitives))


def outcome(solve: Callable[[], R]) -> R | None:
    try:
        return solve()
    except NoPlanFound:
        return None


# ------------------------------------------------------------------ brute force
def brute_force(problem: Problem) -> tuple[float, Trajectory] | None:
    """The cheapest safe trajectory of at most ``max_length`` primitives, by enumeration.

    Every primitive sequence is tried, in depth-first order. A prefix is cut
    only when (a) it leaves the free cells, (b) the checker already reports a
    collision or swap at a step before the prefix's last one (those steps and
    the next cell are the same in every extension, so no extension can remove
    it), or (c) even a straight Manhattan run to the goal would be too long or
    no cheaper than the best found. Each candidate ending at the goal is judged
    by :func:`check_trajectory`, the one authority.
    """
    ws, goal, n, limit = problem.ws, problem.goal, problem.start_step, problem.max_length
    assert limit is not None
    model = MotionModel(ws, problem.costs)
    min_move = min(model.cost(p) for p in model.primitives if p is not P.HOLD)
    best: tuple[float, Trajectory] | None = None
    visited = 0

    def dist(cell: Cell) -> int:
        return sum(abs(a - b) for a, b in zip(cell, goal, strict=True))

    def permanent_violation(traj: Trajectory) -> bool:
        last = traj.end_step - 1  # the newest step whose verdict can no longer change
        for other in problem.others.values():
            if any(v.step == last for v in check_pair(traj, other, problem.delta, from_step=last)):
                return True
        return False

    def walk(cells: tuple[Cell, ...], cost: float) -> None:
        nonlocal best, visited
        visited += 1
        assert visited < 400_000, "the brute force exploded: shrink the problem"
        traj = Trajectory(n, cells)
        if len(cells) > 1 and permanent_violation(traj):
            return
        here = cells[-1]
        if best is not None and cost + dist(here) * min_move >= best[0] - 1e-9:
            return
        if here == goal and not problem.violations(traj):
            best = (cost, traj)
        if len(cells) - 1 + dist(here) + (here == goal) > limit:
            return  # the goal can no longer be reached, or left and re-reached, in time
        for prim in model.primitives:
            nxt = model.post(here, prim)
            if ws.is_free(nxt):
                walk((*cells, nxt), cost + model.cost(prim))

    if limit >= dist(problem.start):
        walk((problem.start,), 0.0)
    return best


# ------------------------------------------------------------------ strategies
def manhattan(a: Cell, b: Cell) -> int:
    return sum(abs(u - v) for u, v in zip(a, b, strict=True))


def bfs_route(ws: Workspace, start: Cell, goal: Cell) -> list[Cell]:
    """A shortest route through free cells ignoring other drones; just ``[start]`` when there is none."""
    parent: dict[Cell, Cell | None] = {start: None}
    queue = deque([start])
    while queue and goal not in parent:
        cell = queue.popleft()
        for nxt in ws.neighbours(cell):
            if nxt not in parent:
                parent[nxt] = cell
                queue.append(nxt)
    if goal not in parent:
        return [start]
    route = [goal]
    while (prev := parent[route[-1]]) is not None:
        route.append(prev)
    return route[::-1]


@st.composite
def workspaces(draw: st.DrawFn, side: tuple[int, int], layers: tuple[int, ...], max_cells: int = 10_000,
               density: float = 0.3) -> Workspace:
    nx, ny = draw(st.integers(*side)), draw(st.integers(*side))
    nz = draw(st.sampled_from(layers))
    assume(nx * ny * nz <= max_cells)
    cells = [(x, y, z) for z in range(nz) for y in range(ny) for x in range(nx)]
    blocked = draw(st.sets(st.sampled_from(cells), max_size=int(density * len(cells))))
    ws = Workspace(size=(nx, ny, nz), obstacles=frozenset(blocked))
    assume(len(ws.free_cells) >= 3)
    return ws


@st.composite
def tasks_on(draw: st.DrawFn, ws: Workspace, count: int, max_step: int = 4) -> list[tuple[Cell, Cell, int]]:
    """``count`` tasks ``(start, goal, start_step)`` with distinct starts; the first is mine.

    The others start and end mostly near a shortest route of mine, so that they get in my way.
    """
    free = list(ws.free_cells)
    start, goal = draw(st.sampled_from(free)), draw(st.sampled_from(free))
    route = [c for c in free if manhattan(start, c) + manhattan(c, goal) <= manhattan(start, goal) + 2]
    tasks = [(start, goal, draw(st.integers(0, max_step)))]
    used = {start}
    for _ in range(count - 1):
        near = [c for c in route if c not in used] if draw(st.booleans()) else []
        pool = near or [c for c in free if c not in used]
        if not pool:
            break
        other_start = draw(st.sampled_from(pool))
        used.add(other_start)
        near_goal = [c for c in route if c != goal]  # parking on my goal would only make it unreachable
        far_goal = [c for c in free if c != goal]
        lean = draw(st.booleans())
        other_goal = draw(st.sampled_from(near_goal if near_goal and lean else far_goal or free))
        tasks.append((other_start, other_goal, draw(st.integers(0, max_step))))
    return tasks


def plan_in_turn(ws: Workspace, tasks: list[tuple[Cell, Cell, int]], delta: int,
                 max_length: int | None = None, costs: Mapping[Primitive, float] = UNIT,
                 fleet: Mapping[str, Trajectory] | None = None, planner: SafePlanner | None = None,
                 ) -> tuple[dict[str, Trajectory], list[tuple[Problem, Plan]]]:
    """Plan each task against ``fleet`` and the tasks planned before it, as the protocol does.

    One planner serves every task, so its incremental reservation table is under test too.
    """
    planner = planner or SafePlanner(ws, delta=delta, costs=costs)
    planned = dict(fleet or {})
    plans: list[tuple[Problem, Plan]] = []
    for i, (start, goal, step) in enumerate(tasks):
        problem = Problem(ws, start, goal, step, dict(planned), delta, max_length, costs)
        try:
            plan = planner.plan(start, goal, step, problem.others, max_length)
        except NoPlanFound:
            continue
        plans.append((problem, plan))
        planned[f"d{i}"] = plan.trajectory
    return planned, plans


def keep_if_safe(ws: Workspace, fleet: dict[str, Trajectory], name: str, delta: int,
                 *candidates: Trajectory) -> None:
    """Add the first candidate the checker accepts alongside ``fleet`` (none if it accepts none)."""
    for traj in candidates:
        if not check_fleet(ws, {**fleet, name: traj}, delta):
            fleet[name] = traj
            return


@st.composite
def walks(draw: st.DrawFn, ws: Workspace, starts: list[Cell], delta: int,
          max_len: int = 8) -> dict[str, Trajectory]:
    """Random walks from distinct cells; one the checker rejects against the fleet so far
    becomes hovering at its start, or is dropped when even that is unsafe."""
    model = MotionModel(ws)
    fleet: dict[str, Trajectory] = {}
    for i, start in enumerate(starts):
        cells = [start]
        for prim in draw(st.lists(st.sampled_from(model.primitives), max_size=max_len)):
            nxt = model.post(cells[-1], prim)
            cells.append(nxt if ws.is_free(nxt) else cells[-1])
        step = draw(st.integers(0, 4))
        keep_if_safe(ws, fleet, f"w{i}", delta, Trajectory(step, tuple(cells)), Trajectory.stationary(start, step))
    return fleet


@st.composite
def interferers(draw: st.DrawFn, ws: Workspace, start: Cell, goal: Cell, n: int, delta: int,
                count: int) -> dict[str, Trajectory]:
    """Drones aimed at a shortest route of mine, timed to meet me there (give or take the window):
    crossing it, flying it head-on, or lingering on it until they start and then leaving."""
    route = bfs_route(ws, start, goal)
    fleet: dict[str, Trajectory] = {}
    for i in range(count):
        j = draw(st.integers(min(1, len(route) - 1), len(route) - 1))  # not my start: that is no plan
        cell, side = route[j], sorted(ws.neighbours(route[j]))
        when = max(1, n + j + draw(st.integers(-delta - 1, delta + 1)))  # when it is in `cell`
        kind = draw(st.sampled_from(["cross", "head-on", "linger"]))
        if kind == "head-on" and j + 1 < len(route):
            tail = route[j:][::-1]
            traj = Trajectory(max(0, when - len(tail) + 1), tuple(tail))
        elif side:
            a, b = draw(st.sampled_from(side)), draw(st.sampled_from(side))
            traj = Trajectory(when - 1, (a, cell, b)) if kind == "cross" else Trajectory(when, (cell, b))
        else:
            traj = Trajectory.stationary(cell, when)
        keep_if_safe(ws, fleet, f"i{i}", delta, traj)
    return fleet


@st.composite
def problems(draw: st.DrawFn, side: tuple[int, int], layers: tuple[int, ...], max_others: int,
             max_length: st.SearchStrategy[int | None], max_cells: int = 10_000,
             costs: st.SearchStrategy[dict[Primitive, float]] | None = None,
             deltas: tuple[int, int] = (0, 2)) -> Problem:
    """My task and the others' trajectories: planned in turn by the A*, random walks, or interferers."""
    ws = draw(workspaces(side, layers, max_cells))
    delta = draw(st.integers(*deltas))
    tasks = draw(tasks_on(ws, 1 + draw(st.sampled_from(range(1, max_others + 1)))))
    (start, goal, step), rest = tasks[0], tasks[1:]
    mode = draw(st.sampled_from(["interferers", "planned", "walks"]))
    event(f"others: {mode}")
    if mode == "planned":  # they know I hover at my start until I leave, as in the protocol
        others, _ = plan_in_turn(ws, rest, delta, fleet={"me": Trajectory.stationary(start, step)})
        others.pop("me", None)
    elif mode == "walks":
        others = draw(walks(ws, [s for s, _, _ in rest], delta))
    else:
        others = draw(interferers(ws, start, goal, step, delta, len(rest)))
    table = draw(costs) if costs is not None else UNIT
    return Problem(ws, start, goal, step, others, delta, draw(max_length), table)


# ------------------------------------------------------------------ properties
def describe(problem: Problem, plan: Plan | None) -> None:
    """Hypothesis statistics (--hypothesis-show-statistics): how varied the examples are."""
    event(f"{len(problem.others)} other drones")
    direct = manhattan(problem.start, problem.goal)
    hover = Trajectory.stationary(problem.start, problem.start_step)
    if plan is not None:
        event("plan with detours or waits" if len(plan.primitives) > direct else "direct plan")
    elif any(v.step == problem.start_step
             for v in check_trajectory(problem.ws, hover, problem.others, problem.delta)):
        event("no plan: start taken")
    elif any(o.last == problem.goal for o in problem.others.values()):
        event("no plan: goal taken for good")
    elif problem.max_length is not None and problem.max_length < direct:
        event("no plan: max_length below the distance")
    else:
        event("no plan: in the way")
