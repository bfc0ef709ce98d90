"""Audit a flown run: the cells drones actually occupied, step by step, against the rules and the plan.

Input is what ``drona agent --record`` (and ``drona demo --record``) write:
records ``{"step": k, "drone": id, "cell": [x, y, z], "planned": [x, y, z] | null,
"delta": D, "via": [[x, y, z], ...]}``, D = ceil((beta + lambda) / tau); ``via`` (optional)
is every other cell telemetry saw the vehicle in since the drone's record before, in order.
A record is taken lambda after its step begins: the step's cell if telemetry saw the vehicle
there by then (all the separation window assumes of a vehicle), else where telemetry puts it.
Three things are judged, each on its own:

* **Separation**: each drone's cells become a timed trajectory; a step with no
  record (telemetry gave no fix) counts as the cell of the step before it, and is
  reported as a gap, because an auditor must know what was not seen. The
  trajectories are checked pairwise under Delta by
  :func:`drona_gcs.safety.check_fleet`, the same checker the planner's tests trust.
  A cell passed ``via`` was held at some time between its two records: it must be
  clear of every other drone from Delta steps before the first to Delta after the second.
* **Conformance**: of the steps that had a planned cell, the share flown in that
  very cell, and the worst distance (in cell moves) between flown and planned.
* **Continuity**: a drone moves one cell per step at most, so two records ``s``
  steps apart more than ``s`` cell moves apart are a jump: the record missed
  where the vehicle went in between. A vehicle catching up on its plan may cross
  several cells in a step; with the cells it passed ``via``, each move counts.
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
    via: tuple[Cell, ...] = ()


def moves(a: Cell, b: Cell) -> int:
    """Cell moves between two cells (a drone moves along one axis per step)."""
    return sum(abs(p - q) for p, q in zip(a, b, strict=True))


def audit(workspace: Workspace, records: Iterable[Mapping[str, object]]) -> Audit:
    parsed = _parse(records)
    trajectories, delta, gaps = _trajectories(parsed)
    # Jumps are judged below from the records themselves, not from the gap-filled trajectories.
    separation = [v for v in check_fleet(workspace, trajectories, delta) if v.kind is not ViolationKind.JUMP]
    separation += _passing(workspace, parsed, trajectories, delta)
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


def _by_drone(records: list[_Record]) -> dict[str, list[_Record]]:
    """Each drone's records in step order, one per step (the last written)."""
    by_step: dict[str, dict[int, _Record]] = defaultdict(dict)
    for r in records:
        by_step[r.drone][r.step] = r
    return {drone: [steps[k] for k in sorted(steps)] for drone, steps in sorted(by_step.items())}


def _jumps(records: list[_Record]) -> tuple[Jump, ...]:
    found: list[Jump] = []
    for drone, mine in _by_drone(records).items():
        for before, after in itertools.pairwise(mine):
            steps = after.step - before.step
            for a, b in itertools.pairwise((before.cell, *after.via, after.cell)):
                if moves(a, b) > steps:
                    found.append(Jump(drone, after.step, steps, a, b))
    return tuple(found)


def _passing(workspace: Workspace, records: list[_Record], trajectories: Mapping[str, Trajectory],
             delta: int) -> list[Violation]:
    """Cells passed between two records: in the grid, off obstacles, and clear of every other drone
    at any step within Delta of the time between the two records."""
    found: list[Violation] = []
    for drone, mine in _by_drone(records).items():
        for k, after in enumerate(mine):
            first = mine[k - 1].step if k else after.step - 1
            for cell in after.via:
                found += _passed_cell(workspace, drone, cell, range(first - delta, after.step + delta + 1),
                                      after.step, trajectories)
    return found


def _passed_cell(workspace: Workspace, drone: str, cell: Cell, window: range, step: int,
                 trajectories: Mapping[str, Trajectory]) -> list[Violation]:
    if not workspace.in_bounds(cell):
        return [Violation(ViolationKind.OUT_OF_BOUNDS, step, cell)]
    if cell in workspace.obstacles:
        return [Violation(ViolationKind.OBSTACLE, step, cell)]
    return [Violation(ViolationKind.COLLISION, step, cell, f"{drone}~{other}", p)
            for other, trajectory in sorted(trajectories.items()) if other != drone
            for p in window if trajectory.at(p) == cell]


def _fields(record: Mapping[str, object], number: int) -> _Record:
    step, drone, delta = (record.get(k) for k in ("step", "drone", "delta"))
    if not isinstance(step, int) or not isinstance(drone, str) or not isinstance(delta, int):
        raise ProblemError(f"record {number}: needs an integer step, a drone id and an integer delta")
    cell = _cell(record.get("cell"), number, "cell")
    if cell is None:
        raise ProblemError(f"record {number}: cell must be [x, y, z] integers, got null")
    return _Record(step, drone, cell, _cell(record.get("planned"), number, "planned"), delta,
                   _via(record.get("via", []), number))


def _via(value: object, number: int) -> tuple[Cell, ...]:
    if not isinstance(value, list):
        raise ProblemError(f"record {number}: via must be a list of [x, y, z] cells, got {value!r}")
    cells = tuple(_cell(v, number, "each cell of via") for v in value)
    if any(c is None for c in cells):
        raise ProblemError(f"record {number}: each cell of via must be [x, y, z] integers, got null")
    return tuple(c for c in cells if c is not None)


def _cell(value: object, number: int, name: str) -> Cell | None:
    if value is None:
        return None
    if not (isinstance(value, list) and len(value) == 3 and all(type(v) is int for v in value)):
        raise ProblemError(f"record {number}: {name} must be [x, y, z] integers or null, got {value!r}")
    return (value[0], value[1], value[2])
