"""``drona plan``: safe plans for a stream of JSON Lines problems, one result line each, in order.

``ms`` is the planner's compute time for that line (reservations, heuristic
and search), not JSON parsing. A bad line gets ``{"status": "error", ...}``
naming the line and the problem, and the batch goes on. Blank lines are skipped.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from functools import lru_cache
from typing import Any, TextIO

from drona_gcs.errors import DronaError, NoPlanFound, WorkspaceError
from drona_gcs.planner import Plan, SafePlanner
from drona_gcs.planner.problem import PlanProblem, parse_problem
from drona_gcs.safety import check_trajectory
from drona_gcs.workspace import Workspace
from drona_gcs.workspace_files import load_workspace


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("input", nargs="?", default="-", help="JSON Lines file of problems (default: stdin)")
    parser.add_argument("--workspace", help="workspace (YAML, DRONA XML, JSON) for lines that have none")
    parser.add_argument("--output", "-o", default="-", help="where to write results (default: stdout)")
    parser.add_argument("--check", action="store_true",
                        help="judge every plan with the independent safety checker (adds 'safe')")


def run(args: argparse.Namespace) -> int:
    loader = _WorkspaceLoader()
    default = None
    if args.workspace:
        try:
            default = loader.load(args.workspace)
        except WorkspaceError as exc:
            print(f"drona plan: --workspace: {exc}", file=sys.stderr)
            return 2
    try:
        source = sys.stdin if args.input == "-" else open(args.input, encoding="utf-8")  # noqa: SIM115
    except OSError as exc:
        print(f"drona plan: cannot read {args.input}: {exc.strerror}", file=sys.stderr)
        return 2
    sink = sys.stdout if args.output == "-" else open(args.output, "w", encoding="utf-8")  # noqa: SIM115
    with source, sink:
        for result in solve_lines(source, loader, default, check=args.check):
            _write(sink, result)
    return 0


def solve_lines(lines: Iterable[str], loader: _WorkspaceLoader, default: Workspace | None,
                check: bool = False) -> Iterator[dict[str, Any]]:
    planners = _PlannerCache()
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            data = json.loads(line)
        except json.JSONDecodeError as exc:
            yield {"status": "error", "error": f"line {number}: not valid JSON: {exc.msg} at column {exc.colno}"}
            continue
        try:
            problem = parse_problem(data, loader.load, default)
        except DronaError as exc:
            yield _with_id(data, {"status": "error", "error": f"line {number}: {exc}"})
            continue
        try:
            result = solve(problem, planners, check)
        except DronaError as exc:  # for example the Z3 planner without its extra
            result = {"status": "error", "error": f"line {number}: {exc}"}
        yield _with_id(data, result)


def solve(problem: PlanProblem, planners: _PlannerCache, check: bool = False) -> dict[str, Any]:
    plan_one = _planner_for(problem, planners)  # set-up per workspace is not the plan's time
    started = time.process_time()
    try:
        plan = plan_one()
    except NoPlanFound:
        return {"status": "no_plan", "ms": _ms_since(started)}
    ms = _ms_since(started)
    traj = plan.trajectory
    result: dict[str, Any] = {
        "status": "ok", "cells": [list(c) for c in traj.cells],
        "primitives": [p.value for p in plan.primitives], "cost": _number(plan.cost), "ms": ms}
    if check:
        violations = check_trajectory(problem.workspace, traj, problem.others, problem.delta, problem.goal)
        result["safe"] = not violations
        if violations:
            result["violations"] = [str(v) for v in violations[:10]]
    return result


def _planner_for(problem: PlanProblem, planners: _PlannerCache) -> Callable[[], Plan]:
    p = problem
    if p.planner == "smt":
        try:
            from drona_gcs.planner.smt import plan_smt
        except ImportError as exc:
            raise DronaError(f"the Z3 planner is not available: {exc}") from exc
        return lambda: plan_smt(p.workspace, p.start, p.goal, p.start_step, p.others, p.delta,
                                p.max_length, p.costs)
    planner = planners.get(p)
    return lambda: planner.plan(p.start, p.goal, p.start_step, p.others, p.max_length)


class _PlannerCache:
    """One planner per (workspace, delta, costs), so its tables carry over between lines."""

    def __init__(self) -> None:
        self._planners: dict[tuple[int, int, tuple[tuple[str, float], ...]], SafePlanner] = {}
        self._keep: list[Workspace] = []  # keeps id() keys valid

    def get(self, problem: PlanProblem) -> SafePlanner:
        costs = tuple(sorted((p.value, c) for p, c in problem.costs.items()))
        key = (id(problem.workspace), problem.delta, costs)
        planner = self._planners.get(key)
        if planner is None:
            if len(self._planners) >= 16:  # inline workspaces differ per line: do not grow forever
                self._planners.clear()
                self._keep.clear()
            planner = SafePlanner(problem.workspace, problem.delta, problem.costs)
            self._planners[key] = planner
            self._keep.append(problem.workspace)
        return planner


class _WorkspaceLoader:
    """Loads each workspace file once."""

    def __init__(self) -> None:
        self.load = lru_cache(maxsize=64)(load_workspace)


def _ms_since(started: float) -> float:
    return round((time.process_time() - started) * 1000, 3)


def _number(value: float) -> float | int:
    return int(value) if float(value).is_integer() else value


def _with_id(data: object, result: dict[str, Any]) -> dict[str, Any]:
    if isinstance(data, dict) and "id" in data:
        return {"id": data["id"], **result}
    return result


def _write(sink: TextIO, result: dict[str, Any]) -> None:
    sink.write(json.dumps(result, separators=(",", ":")) + "\n")
    sink.flush()
