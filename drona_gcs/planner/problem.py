"""Planning problems as JSON objects (the ``drona plan`` line format), parsed and validated.

A problem::

    {"workspace": {"size": [nx,ny,nz], "obstacles": [[x,y,z], ...]} or "path/to/file",
     "start": [x,y,z], "goal": [x,y,z], "start_step": n, "delta": d, "max_length": L,
     "others": {"<id>": {"start_step": m, "cells": [[x,y,z], ...]}},
     "planner": "astar" | "smt", "costs": {"hold": 1, "+x": 1, ...}, "id": any}

Only ``start`` and ``goal`` are required when a default workspace is given;
``delta`` and ``max_length`` default to the workspace's. ``costs`` and ``id``
(echoed back in the result) are our extensions. Every problem found is
reported as :class:`ProblemError` naming the field.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from drona_gcs.errors import ProblemError, WorkspaceError
from drona_gcs.motion import Primitive, Trajectory, parse_costs
from drona_gcs.workspace import Cell, Workspace
from drona_gcs.workspace_files import workspace_from_mapping

PLANNERS = ("astar", "smt")
_FIELDS = {"workspace", "start", "goal", "start_step", "delta", "max_length", "others", "planner",
           "costs", "id"}


@dataclass(frozen=True)
class PlanProblem:
    workspace: Workspace
    start: Cell
    goal: Cell
    start_step: int
    delta: int
    max_length: int
    others: Mapping[str, Trajectory]
    planner: str = "astar"
    costs: Mapping[Primitive, float] = field(default_factory=dict)
    request_id: Any = None


def parse_problem(data: object, load: Callable[[str], Workspace],
                  default: Workspace | None = None) -> PlanProblem:
    """Validate one problem object. ``load`` turns a workspace path into a Workspace."""
    if not isinstance(data, Mapping):
        raise ProblemError(f"a problem must be a JSON object, got {type(data).__name__}")
    unknown = sorted(set(data) - _FIELDS)
    if unknown:
        raise ProblemError(f"unknown field(s) {unknown}; known: {sorted(_FIELDS)}")
    ws = _workspace(data.get("workspace"), load, default)
    start = _free_cell(ws, data.get("start"), "start")
    goal = _free_cell(ws, data.get("goal"), "goal")
    planner = data.get("planner", "astar")
    if planner not in PLANNERS:
        raise ProblemError(f"planner: must be one of {list(PLANNERS)}, got {planner!r}")
    costs_raw = data.get("costs", {})
    if not isinstance(costs_raw, Mapping) or not all(_is_number(v) for v in costs_raw.values()):
        raise ProblemError(f"costs: must map primitive names to numbers, got {costs_raw!r}")
    return PlanProblem(
        workspace=ws, start=start, goal=goal,
        start_step=_int(data, "start_step", 0),
        delta=_int(data, "delta", ws.delta, minimum=0),
        max_length=_int(data, "max_length", ws.plan_length_limit, minimum=0),
        others=_others(ws, data.get("others", {})),
        planner=planner, costs=parse_costs(costs_raw), request_id=data.get("id"))


def _workspace(value: object, load: Callable[[str], Workspace], default: Workspace | None) -> Workspace:
    if value is None:
        if default is None:
            raise ProblemError("workspace: missing, and no --workspace was given")
        return default
    try:
        if isinstance(value, str):
            return load(value)
        return workspace_from_mapping(value, source="workspace")
    except WorkspaceError as exc:
        raise ProblemError(f"workspace: {exc}") from exc


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _int(data: Mapping[str, Any], key: str, default: int, minimum: int | None = None) -> int:
    value = data.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int):
        raise ProblemError(f"{key}: must be an integer, got {value!r}")
    if minimum is not None and value < minimum:
        raise ProblemError(f"{key}: must be >= {minimum}, got {value}")
    return value


def _cell(ws: Workspace, value: object, where: str) -> Cell:
    if (not isinstance(value, list) or len(value) not in (2, 3)
            or any(isinstance(v, bool) or not isinstance(v, int) for v in value)):
        raise ProblemError(f"{where}: must be a cell [x, y, z] of integers, got {value!r}")
    cell = (value[0], value[1], value[2] if len(value) == 3 else 0)
    if not ws.in_bounds(cell):
        raise ProblemError(f"{where}: cell {list(cell)} is outside the grid {list(ws.size)}")
    return cell


def _free_cell(ws: Workspace, value: object, where: str) -> Cell:
    if value is None:
        raise ProblemError(f"{where}: missing")
    cell = _cell(ws, value, where)
    if cell in ws.obstacles:
        raise ProblemError(f"{where}: cell {list(cell)} is on an obstacle")
    return cell


def _others(ws: Workspace, value: object) -> dict[str, Trajectory]:
    if not isinstance(value, Mapping):
        raise ProblemError(f"others: must map drone ids to trajectories, got {value!r}")
    out: dict[str, Trajectory] = {}
    for drone, raw in value.items():
        where = f"others.{drone}"
        if not isinstance(raw, Mapping) or "cells" not in raw:
            raise ProblemError(f"{where}: must be {{\"start_step\": m, \"cells\": [[x,y,z], ...]}}")
        extra = sorted(set(raw) - {"start_step", "cells"})
        if extra:
            raise ProblemError(f"{where}: unknown field(s) {extra}")
        cells_raw = raw["cells"]
        if not isinstance(cells_raw, list) or not cells_raw:
            raise ProblemError(f"{where}.cells: must be a non-empty list of cells")
        cells = [_free_cell(ws, c, f"{where}.cells[{i}]") for i, c in enumerate(cells_raw)]
        for i in range(1, len(cells)):
            if sum(abs(a - b) for a, b in zip(cells[i], cells[i - 1], strict=True)) > 1:
                raise ProblemError(f"{where}.cells[{i}]: {list(cells[i])} is not one move from "
                                   f"{list(cells[i - 1])}")
        out[str(drone)] = Trajectory(_int(raw, "start_step", 0), tuple(cells))
    return out
