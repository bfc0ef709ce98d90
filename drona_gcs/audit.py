"""Audit a flown run: the cells drones actually occupied, step by step, against the rules and the plan.

Input is what ``drona agent --record`` (and ``drona demo --record``) write:
records ``{"step": k, "drone": id, "cell": [x, y, z], "planned": [x, y, z] | null,
"delta": D}``, D = ceil((beta + lambda) / tau). A record is taken lambda after its step
begins: the step's cell if telemetry saw the vehicle there by then (all the separation
window assumes of a vehicle), else where telemetry puts it. Three things are judged, each
on its own:

* **Separation**: each drone's cells become a timed trajectory; a step with no
  record (telemetry gave no fix) counts as the cell of the step before it, and is
  reported as a gap, because an auditor must know what was not seen. The
  trajectories are checked pairwise under Delta by
  :func:`drona_gcs.safety.check_fleet`, the same checker the planner's tests trust.
* **Conformance**: of the steps that had a planned cell, the share flown in that
  very cell, and the worst distance (in cell moves) between flown and planned.
* **Continuity**: a drone moves one cell per step at most, so two records ``s``
  steps apart more than ``s`` cell moves apart are a jump: the record missed
  where the vehicle went in between.
"""

from __future__ import annotations

import itertools
from collections import defaultdict
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from drona_gcs.errors import ProblemError
from drona_gcs.motion import Trajectory
from drona_gcs.safety import Violation, ViolationKind, check_fleet
from drona_gcs.workspace import Cell, Workspace


@dataclass(frozen=True)
class Deviation:
    """A step flown away from its planned cell."""

    drone: str
    step: int
    flown: Cell
    planned: Cell

    @property
    def cells(self) -> int:
        return moves(self.flown, self.planned)

    def __str__(self) -> str:
        return (f"{self.drone} at step {self.step} flew {list(self.flown)}, planned {list(self.planned)} "
                f"({self.cells} cells away)")


@dataclass(frozen=True)
class Jump:
    """Two records of one drone further apart in cells than in steps."""

    drone: str
    step: int  #: the later of the two records
    steps: int  #: steps between the two records
    before: Cell
    after: Cell

    def __str__(self) -> str:
        return (f"{self.drone} moved {moves(self.before, self.after)} cells in {self.steps} step(s), "
                f"{list(self.before)} -> {list(self.after)} at step {self.step}")


@dataclass(frozen=True)
class Conformance:
    planned_steps: int  #: records that had a planned cell
    deviations: tuple[Deviation, ...]  #: those flown elsewhere

    @property
    def fraction(self) -> float:
        """Share of planned steps flown in the planned cell (1.0 when nothing was planned)."""
        if not self.planned_steps:
            return 1.0
        return 1.0 - len(self.deviations) / self.planned_steps

    @property
    def worst(self) -> Deviation | None:
        return max(self.deviations, key=lambda d: d.cells, default=None)


@dataclass(frozen=True)
class Audit:
    trajectories: Mapping[str, Trajectory]
    delta: int
    gaps: Mapping[str, int]  #: steps without a record, per drone
    violations: list[Violation]  #: separation, obstacles and bounds
    conformance: Conformance
    jumps: tuple[Jump, ...]

    @property
    def safe(self) -> bool:
        return not self.violations


@dataclass(frozen=True)
class _Record:
    step: int
    drone: str
    cell: Cell
    planned: Cell | None
    delta: int


def moves(a: Cell, b: Cell) -> int:
    """Cell moves between two cells (a drone moves along one axis per step)."""
    return sum(abs(p - q) for p, q in zip(a, b, strict=True))


def audit(workspace: Workspace, records: Iterable[Mapping[str, object]]) -> Audit:
    parsed = _parse(records)
    trajectories, delta, gaps = _trajectories(parsed)
    # Jumps are judged below from the records themselves, not from the gap-filled trajectories.
    separation = [v for v in check_fleet(workspace, trajectories, delta) if v.kind is not ViolationKind.JUMP]
    return Audit(trajectories, delta, gaps, separation, _conformance(parsed), _jumps(parsed))


def _parse(records: Iterable[Mapping[str, object]]) -> list[_Record]:
    return [_fields(record, number) for number, record in enumerate(records, 1)]


def _trajectories(records: list[_Record]) -> tuple[dict[str, Trajectory], int, dict[str, int]]:
    cells: dict[str, dict[int, Cell]] = defaultdict(dict)
    deltas = {r.delta for r in records}
    if len(deltas) > 1:
        raise ProblemError(f"the records disagree on delta: {sorted(deltas)}")
    for r in records:
        cells[r.drone][r.step] = r.cell
    trajectories: dict[str, Trajectory] = {}
    gaps: dict[str, int] = {}
    for drone, by_step in cells.items():
        first, last = min(by_step), max(by_step)
        path: list[Cell] = []
        for step in range(first, last + 1):
            path.append(by_step.get(step, path[-1] if path else by_step[first]))
        trajectories[drone] = Trajectory(first, tuple(path))
        gaps[drone] = (last - first + 1) - len(by_step)
    return trajectories, deltas.pop() if deltas else 0, gaps


def _conformance(records: list[_Record]) -> Conformance:
    planned = [r for r in records if r.planned is not None]
    deviations = tuple(Deviation(r.drone, r.step, r.cell, r.planned) for r in planned
                       if r.planned is not None and r.cell != r.planned)
    return Conformance(len(planned), deviations)


def _jumps(records: list[_Record]) -> tuple[Jump, ...]:
    by_drone: dict[str, dict[int, Cell]] = defaultdict(dict)
    for r in records:
        by_drone[r.drone][r.step] = r.cell
    found: list[Jump] = []
    for drone, by_step in sorted(by_drone.items()):
        steps = sorted(by_step)
        for before, after in itertools.pairwise(steps):
            if moves(by_step[before], by_step[after]) > after - before:
                found.append(Jump(drone, after, after - before, by_step[before], by_step[after]))
    return tuple(found)


def _fields(record: Mapping[str, object], number: int) -> _Record:
    step, drone, delta = (record.get(k) for k in ("step", "drone", "delta"))
    if not isinstance(step, int) or not isinstance(drone, str) or not isinstance(delta, int):
        raise ProblemError(f"record {number}: needs an integer step, a drone id and an integer delta")
    cell = _cell(record.get("cell"), number, "cell")
    if cell is None:
        raise ProblemError(f"record {number}: cell must be [x, y, z] integers, got null")
    return _Record(step, drone, cell, _cell(record.get("planned"), number, "planned"), delta)


def _cell(value: object, number: int, name: str) -> Cell | None:
    if value is None:
        return None
    if not (isinstance(value, list) and len(value) == 3 and all(type(v) is int for v in value)):
        raise ProblemError(f"record {number}: {name} must be [x, y, z] integers or null, got {value!r}")
    return (value[0], value[1], value[2])
