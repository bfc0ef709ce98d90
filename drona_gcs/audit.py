"""Audit a flown run: the cells drones actually occupied, step by step, against the rules and the plan.

Input is what ``drona agent --record`` (and ``drona demo --record``) write:
records ``{"step": k, "drone": id, "cell": [x, y, z], "planned": [x, y, z] | null,
"delta": D, "via": [[x, y, z], ...]}``, D = ceil((beta + lambda) / tau); ``via`` (optional)
is every other grid cell telemetry saw the vehicle in since the drone's record before, in order.
A record is taken lambda after its step begins: the step's cell if telemetry saw the vehicle
there by then (all the separation window assumes of a vehicle), else where telemetry puts it.
Three things are judged, each on its own:

* **Separation**: each drone's cells become a timed trajectory; a step with no
  record (telemetry gave no fix) counts as the cell of the step before it, and is
  reported as a gap, because an auditor must know what was not seen. The
  trajectories are checked pairwise under Delta by
  :func:`drona_gcs.safety.check_fleet`, the same checker the planner's tests trust.
  A cell passed ``via`` was held at some time between its two records: it must be
  clear of every other drone (its records, and the cells it passed) from Delta steps
  before the first to Delta after the second.
* **Conformance**: of the steps that had a planned cell, the share flown in that
  very cell, and the worst distance (in cell moves) between flown and planned.
* **Continuity**: a drone moves one cell per step at most, so two records ``s``
  steps apart more than ``s`` cell moves apart are a jump: the record missed
  where the vehicle went in between. A vehicle catching up on its plan may cross
  several cells in a step; with the cells it passed ``via``, each move counts.
"""

from __future__ import annotations

import itertools
import json
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


MIN_CONFORMANCE = 0.95  #: the least share of planned steps flown in the planned cell, by default


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

    def broken(self, min_conformance: float = MIN_CONFORMANCE, max_jumps: int = 0) -> list[str]:
        """What the run breaks: separation, conformance below ``min_conformance``, more than ``max_jumps``
        jumps (none: it audits clean)."""
        broken = []
        if not self.safe:
            broken.append(f"{len(self.violations)} separation violations")
        if self.conformance.fraction < min_conformance:
            broken.append(f"conformance {self.conformance.fraction:.1%} < {min_conformance:.1%}")
        if len(self.jumps) > max_jumps:
            broken.append(f"{len(self.jumps)} jumps > {max_jumps}")
        return broken


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


@dataclass(frozen=True)
class _Span:
    """From a drone's record before (a step earlier for its first) to a record: the cells seen in order."""

    drone: str
    first: int  #: the step of the record before
    record: _Record
    before: Cell | None  #: the cell of the record before (None: the first record)

    @property
    def chain(self) -> tuple[Cell, ...]:
        return (*(() if self.before is None else (self.before,)), *self.record.via, self.record.cell)

    def overlaps(self, other: _Span, delta: int) -> bool:
        """Whether some time of this span is within Delta steps of some time of ``other``."""
        return self.first - delta <= other.record.step and other.first <= self.record.step + delta


def _spans(records: list[_Record]) -> list[_Span]:
    return [_Span(drone, mine[k - 1].step if k else r.step - 1, r, mine[k - 1].cell if k else None)
            for drone, mine in _by_drone(records).items() for k, r in enumerate(mine)]


def _jumps(records: list[_Record]) -> tuple[Jump, ...]:
    found: list[Jump] = []
    for span in _spans(records):
        steps = span.record.step - span.first
        found += [Jump(span.drone, span.record.step, steps, a, b)
                  for a, b in itertools.pairwise(span.chain) if moves(a, b) > steps]
    return tuple(found)


def _passing(workspace: Workspace, records: list[_Record], trajectories: Mapping[str, Trajectory],
             delta: int) -> list[Violation]:
    """Cells passed between two records: in the grid, off obstacles, and clear of every other drone
    (its records, and the cells it passed) at any step within Delta of the time between the two records."""
    passing = [span for span in _spans(records) if span.record.via]
    found: list[Violation] = []
    for span in passing:
        step = span.record.step
        window = range(span.first - delta, step + delta + 1)
        for cell in span.record.via:
            if not workspace.in_bounds(cell):
                found.append(Violation(ViolationKind.OUT_OF_BOUNDS, step, cell))
            elif cell in workspace.obstacles:
                found.append(Violation(ViolationKind.OBSTACLE, step, cell))
            found += [Violation(ViolationKind.COLLISION, step, cell, f"{span.drone}~{other}", when)
                      for other, trajectory in sorted(trajectories.items()) if other != span.drone
                      if (when := next((p for p in window if trajectory.at(p) == cell), None)) is not None]
            found += [Violation(ViolationKind.COLLISION, step, cell, f"{span.drone}~{them.drone}", them.record.step)
                      for them in passing if them.drone > span.drone and cell in them.record.via
                      and span.overlaps(them, delta)]
    return found


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
        raise ProblemError(f"record {number}: via must be a list of [x, y, z] cells, got {_json(value)}")
    return tuple(_strict_cell(v, number, "each cell of via", "") for v in value)


def _cell(value: object, number: int, name: str) -> Cell | None:
    return None if value is None else _strict_cell(value, number, name, " or null")


def _strict_cell(value: object, number: int, name: str, or_else: str) -> Cell:
    if not (isinstance(value, list) and len(value) == 3 and all(type(v) is int for v in value)):
        raise ProblemError(f"record {number}: {name} must be [x, y, z] integers{or_else}, got {_json(value)}")
    return (value[0], value[1], value[2])


def _json(value: object) -> str:
    return json.dumps(value, default=repr)


def record_line(step: int, drone: str, cell: Cell, planned: Cell | None, delta: int,
                via: tuple[Cell, ...] = ()) -> str:
    """One line of the flight record (``--record``): where the vehicle was at ``step``, the
    cell its plan put it in, and the cells it went through since the last record (see drona_gcs.audit)."""
    plan = "null" if planned is None else _cell_json(planned)
    through = f', "via": [{", ".join(map(_cell_json, via))}]' if via else ""
    return (f'{{"step": {step}, "drone": "{drone}", "cell": {_cell_json(cell)}, "planned": {plan}, "delta": {delta}'
            f'{through}}}\n')


def went_through(passed: tuple[Cell, ...], before: Cell | None, after: Cell) -> tuple[Cell, ...]:
    """The cells seen between two records, in order, without the records' own at either end."""
    start = 1 if passed and passed[0] == before else 0
    end = len(passed) - 1 if len(passed) > start and passed[-1] == after else len(passed)
    return passed[start:end]


def _cell_json(cell: Cell) -> str:
    return "[{}, {}, {}]".format(*cell)
