"""The Z3 plan generator: the paper's SMT baseline (section 3.2.2), with our safety rules.

The A* in :mod:`drona_gcs.planner.astar` is the planner the stack uses; this
one exists to cross-check it and to reproduce the paper's Table 1. For a plan
of ``k`` primitives applied from step ``n`` it asks Z3 for:

* **Positions**: integers ``x_q, y_q, z_q`` for ``q = 0..k``, the cell at step
  ``n + q``, bounded by the grid; ``id_q = x_q + nx * (y_q + ny * z_q)`` is the
  cell's id, a linear term.
* **Primitives**: an integer ``g_q`` per step ``q = 1..k`` choosing ``gamma_q``
  among the workspace's primitives (``+z``/``-z`` only when ``nz > 1``).
* **Eq. 2**: ``l_0`` is the start and ``l_k`` the goal.
* **Eq. 3**: ``g_q = i  =>  l_q = post(l_{q-1}, gamma_i)``.
* **Eq. 4**: obstacles are an uninterpreted predicate ``obstacle(x, y, z)``,
  asserted on every obstacle cell, and ``not obstacle(l_q)`` for every ``q``.
  A primitive's intermediate cells are its two ends, both on the trajectory.
* **Eq. 6**, with exactly the semantics of :mod:`drona_gcs.safety`: another
  drone's trajectory is known, so for my step ``t = n + q`` the cells it may
  hold at any of its steps ``p`` with ``|t - p| <= delta`` (its first cell
  before it starts, its last after it ends) form a constant set, and
  ``id_q`` must avoid it. **Swaps**: for each move ``a -> b`` the other makes
  from such a step ``p``, ``not (l_q = b and l_{q+1} = a)``.
* **Staying at the goal forever**: after step ``n + k`` my cell is the goal, a
  constant, so that part is checked in Python: ``n + k`` must reach the first
  step from which no other drone's window ever holds the goal (a drone that
  ends on my goal makes every ``k`` infeasible).
* **Corridor** (implied by Eq. 2-4, added only to help Z3): with ``ds``/``dg``
  the obstacle-aware distances from the start and to the goal, ``l_q`` is a
  cell with ``ds <= q`` and ``dg <= k - q``. Without it, proving that no plan
  of some length exists took Z3 minutes on a 32x32 grid; with it, a second.
* **Eq. 1**: minimise the total cost. ``k`` grows by one up to ``max_length``
  (default L_max). The paper starts at the Manhattan distance; every ``k``
  below the obstacle-aware distance has an empty corridor, so we start there.
  Once every other drone has stopped (step ``S``) the world is static, and a
  shortest path finishes any plan, so no ``k`` beyond ``S - n + |free cells|``
  is tried. When every primitive costs the same, the first satisfiable ``k``
  is optimal and a plain solver suffices; otherwise each ``k`` is a
  ``z3.Optimize`` problem asked for a plan cheaper than the best so far, and
  ``k`` grows while a length-``k`` plan could still be cheaper: it makes at
  least ``dg(start)`` moves, and every step costs at least ``min_cost``.

Each call uses its own Z3 context, so plans may run in parallel threads.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from drona_gcs.errors import DronaError, GoalCutOff, NoPlanFound, ProblemError
from drona_gcs.motion import MotionModel, Primitive, Trajectory
from drona_gcs.planner import Plan, check_endpoints
from drona_gcs.safety import assert_safe
from drona_gcs.workspace import Cell, Workspace

try:
    import z3
except ImportError as exc:  # pragma: no cover - depends on the installed extras
    raise DronaError("the Z3 planner needs the 'smt' extra: pip install 'drona-gcs[smt]'") from exc

__all__ = ["SmtTimeout", "plan_smt"]

#: Slack when comparing float costs.
_EPS = 1e-9


class SmtTimeout(NoPlanFound):
    """Z3 ran out of ``timeout_ms`` before deciding: no plan, but also no proof that none exists."""


def plan_smt(workspace: Workspace, start: Cell, goal: Cell, start_step: int,
             others: Mapping[str, Trajectory], delta: int, max_length: int | None = None,
             costs: Mapping[Primitive, float] | None = None, timeout_ms: int | None = None) -> Plan:
    """A minimum-cost safe plan found by Z3; raises :class:`NoPlanFound` when none exists.

    Same contract as :meth:`drona_gcs.planner.SafePlanner.plan`. ``timeout_ms``
    bounds each Z3 call (one per plan length; Z3 keeps the time, the core reads
    no clock); running out raises :class:`SmtTimeout`.
    """
    check_endpoints(workspace, start, goal)
    if delta < 0:
        raise ProblemError(f"delta must be >= 0, got {delta}")
    limit = workspace.plan_length_limit if max_length is None else max_length
    if limit < 0:
        raise ProblemError(f"max_length must be >= 0, got {limit}")
    model = MotionModel(workspace, dict(costs or {}))
    windows = _Windows(workspace, others, delta)
    if workspace.cell_id(start) in windows.forbidden(start_step):
        raise NoPlanFound("the start cell is taken by another drone at the start step")
    ready = _goal_free_from(goal, others, start_step, delta)
    if ready is None:
        raise NoPlanFound("the goal is another drone's resting cell for good")
    to_goal = workspace.distances_from(goal)
    if start not in to_goal:
        raise GoalCutOff("the goal cannot be reached from the start")
    prim_costs = [model.cost(p) for p in model.primitives]
    min_cost, uniform = min(prim_costs), len(set(prim_costs)) == 1
    min_move = min(model.cost(p) for p in model.primitives if p is not Primitive.HOLD)
    problem = _Problem(workspace, model, windows, start, goal, start_step,
                       workspace.distances_from(start), to_goal, uniform)
    stopped = max((o.end_step + delta + 1 for o in others.values()), default=start_step)
    useful = min(limit, max(0, stopped - start_step) + len(workspace.free_cells))
    best: Plan | None = None
    moves = to_goal[start]
    for k in range(moves, useful + 1):
        if best is not None and moves * min_move + (k - moves) * min_cost >= best.cost - _EPS:
            break  # no plan of k or more primitives can be cheaper
        if start_step + k < ready:
            continue  # I would sit on the goal while another drone still passes it
        found = _solve(problem, k, None if uniform or best is None else best.cost, timeout_ms)
        if found is not None and (best is None or found.cost < best.cost - _EPS):
            best = found
            if uniform:
                break
    if best is None:
        raise NoPlanFound(f"no safe plan reaches the goal within {limit} steps")
    assert_safe(workspace, best.trajectory, others, delta, goal)  # the trusted checker has the last word
    return best


class _Windows:
    """What the other drones hold in the skew window around each of my steps."""

    def __init__(self, workspace: Workspace, others: Mapping[str, Trajectory], delta: int) -> None:
        self.ws, self.others, self.delta = workspace, list(others.values()), delta

    def forbidden(self, t: int) -> set[int]:
        """Ids of the cells another drone may hold at a step ``p`` with ``|t - p| <= delta``."""
        window = range(t - self.delta, t + self.delta + 1)
        return {self.ws.cell_id(o.at(p)) for o in self.others for p in window}

    def swaps(self, t: int) -> set[tuple[int, int]]:
        """``(b, a)`` for every move ``a -> b`` another drone makes from a step in the window."""
        out: set[tuple[int, int]] = set()
        for o in self.others:
            for p in range(t - self.delta, t + self.delta + 1):
                a, b = o.at(p), o.at(p + 1)
                if a != b:
                    out.add((self.ws.cell_id(b), self.ws.cell_id(a)))
        return out


def _goal_free_from(goal: Cell, others: Mapping[str, Trajectory], n: int, delta: int) -> int | None:
    """The first step ``>= n`` from which no window ever holds ``goal``; None when never."""
    ready = n
    for other in others.values():
        if other.last == goal:
            return None
        # After other.end_step + delta the window holds only the other's last cell.
        for t in range(n, other.end_step + delta + 1):
            if any(other.at(p) == goal for p in range(t - delta, t + delta + 1)):
                ready = max(ready, t + 1)
    return ready


@dataclass(frozen=True)
class _Problem:
    workspace: Workspace
    model: MotionModel
    windows: _Windows
    start: Cell
    goal: Cell
    n: int  #: the start step
    from_start: Mapping[Cell, int]
    to_goal: Mapping[Cell, int]
    uniform: bool  #: every primitive costs the same


def _solve(problem: _Problem, k: int, below: float | None, timeout_ms: int | None) -> Plan | None:
    """The cheapest safe plan of exactly ``k`` primitives costing less than ``below``, or None."""
    workspace, model, n, uniform = problem.workspace, problem.model, problem.n, problem.uniform
    ctx = z3.Context()
    solver: Any = z3.Solver(ctx=ctx) if uniform else z3.Optimize(ctx=ctx)
    if timeout_ms is not None:
        solver.set("timeout", timeout_ms)
    xs, ids = _positions(workspace, solver, ctx, k)
    _endpoints(solver, xs, problem.start, problem.goal)
    _obstacles(workspace, solver, ctx, xs)
    choices = _continuity(model, solver, ctx, xs)
    _collisions(solver, problem.windows, ids, n)
    _corridor(problem, solver, ids, k)
    if not uniform:
        total = _total_cost(model, ctx, choices)
        if below is not None:  # only a cheaper plan is of use: proving there is none is quicker
            solver.add(total < z3.RealVal(below, ctx))
        solver.minimize(total)
    verdict = solver.check()
    if verdict == z3.unknown:
        raise SmtTimeout(f"Z3 could not decide plans of length {k}: {solver.reason_unknown()}")
    if verdict == z3.unsat:
        return None
    m = solver.model()
    cells = tuple((m.eval(x).as_long(), m.eval(y).as_long(), m.eval(z).as_long()) for x, y, z in xs)
    traj = Trajectory(n, cells)
    prims = traj.primitives()
    return Plan(traj, prims, model.plan_cost(prims), 0)


Pos = tuple[Any, Any, Any]


def _positions(workspace: Workspace, solver: Any, ctx: Any, k: int) -> tuple[list[Pos], list[Any]]:
    """Bounded coordinates ``l_0 .. l_k`` and the cell-id term of each."""
    nx, ny, nz = workspace.size
    xs: list[Pos] = []
    ids: list[Any] = []
    for q in range(k + 1):
        x, y, z = (z3.Int(f"{axis}_{q}", ctx) for axis in "xyz")
        solver.add(x >= 0, x < nx, y >= 0, y < ny, z >= 0, z < nz)
        xs.append((x, y, z))
        ids.append(x + nx * (y + ny * z))
    return xs, ids


def _endpoints(solver: Any, xs: Sequence[Pos], start: Cell, goal: Cell) -> None:
    """Eq. 2: the trajectory starts at ``start`` and ends at ``goal``."""
    for var, value in zip(xs[0] + xs[-1], start + goal, strict=True):
        solver.add(var == value)


def _obstacles(workspace: Workspace, solver: Any, ctx: Any, xs: Sequence[Pos]) -> None:
    """Eq. 4 with the obstacles as an uninterpreted predicate, as in the paper."""
    if not workspace.obstacles:
        return
    integer = z3.IntSort(ctx)
    obstacle = z3.Function("obstacle", integer, integer, integer, z3.BoolSort(ctx))
    for ox, oy, oz in workspace.obstacles:
        solver.add(obstacle(z3.IntVal(ox, ctx), z3.IntVal(oy, ctx), z3.IntVal(oz, ctx)))
    for x, y, z in xs:
        solver.add(z3.Not(obstacle(x, y, z)))


def _continuity(model: MotionModel, solver: Any, ctx: Any, xs: Sequence[Pos]) -> list[Any]:
    """Eq. 3: ``l_q = post(l_{q-1}, gamma_q)``; returns the primitive choices ``g_1 .. g_k``."""
    prims = model.primitives
    choices = []
    for q in range(1, len(xs)):
        g = z3.Int(f"g_{q}", ctx)
        solver.add(g >= 0, g < len(prims))
        for i, prim in enumerate(prims):
            moved = [after == before + d
                     for after, before, d in zip(xs[q], xs[q - 1], prim.vector, strict=True)]
            solver.add(z3.Implies(g == i, z3.And(*moved)))
        choices.append(g)
    return choices


def _collisions(solver: Any, windows: _Windows, ids: Sequence[Any], n: int) -> None:
    """Eq. 6 and the no-swap rule against every other drone, step by step."""
    for q, here in enumerate(ids):
        for cell in sorted(windows.forbidden(n + q)):
            solver.add(here != cell)
        if q + 1 < len(ids):
            for b, a in sorted(windows.swaps(n + q)):
                solver.add(z3.Not(z3.And(here == b, ids[q + 1] == a)))


def _corridor(problem: _Problem, solver: Any, ids: Sequence[Any], k: int) -> None:
    """``l_q`` is at most ``q`` moves from the start and ``k - q`` from the goal."""
    ws, far = problem.workspace, k + 1
    for q, here in enumerate(ids):
        inside = [ws.cell_id(c) for c, d in problem.from_start.items()
                  if d <= q and problem.to_goal.get(c, far) <= k - q]
        solver.add(z3.Or(*[here == cell for cell in inside]))


def _total_cost(model: MotionModel, ctx: Any, choices: Sequence[Any]) -> Any:
    """Eq. 1: the sum of the chosen primitives' costs, as an exact rational term."""
    prims = model.primitives
    terms = []
    for g in choices:
        term = z3.RealVal(model.cost(prims[-1]), ctx)
        for i in range(len(prims) - 2, -1, -1):
            term = z3.If(g == i, z3.RealVal(model.cost(prims[i]), ctx), term)
        terms.append(term)
    return z3.Sum(*terms) if terms else z3.RealVal(0, ctx)
