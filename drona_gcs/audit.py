"""Audit a flown run: the cells drones actually occupied, step by step, judged by the safety checker.

Input is what ``drona agent --record`` (and ``drona demo --record``) write:
records ``{"step": k, "drone": id, "cell": [x, y, z], "delta": D}``. Each
drone's cells become a timed trajectory; a step with no record (telemetry
gave no fix) counts as the cell of the step before it, and is reported as a
gap, because an auditor must know what was not seen. The trajectories are
then checked pairwise under Delta by :func:`drona_gcs.safety.check_fleet`,
the same checker the planner's tests trust.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from drona_gcs.errors import ProblemError
from drona_gcs.motion import Trajectory
from drona_gcs.safety import Violation, check_fleet
from drona_gcs.workspace import Cell, Workspace


@dataclass(frozen=True)
class Audit:
    trajectories: Mapping[str, Trajectory]
    delta: int
    gaps: Mapping[str, int]  #: steps without a record, per drone
    violations: list[Violation]

    @property
    def safe(self) -> bool:
        return not self.violations


def flown_trajectories(records: Iterable[Mapping[str, object]]) -> tuple[dict[str, Trajectory], int, dict[str, int]]:
    """Per drone, its recorded cells as a trajectory; the run's Delta; and the gaps filled."""
    cells: dict[str, dict[int, Cell]] = defaultdict(dict)
    deltas: set[int] = set()
    for number, record in enumerate(records, 1):
        step, drone, cell, delta = _fields(record, number)
        cells[drone][step] = cell
        deltas.add(delta)
    if len(deltas) > 1:
        raise ProblemError(f"the records disagree on delta: {sorted(deltas)}")
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


def audit(workspace: Workspace, records: Iterable[Mapping[str, object]]) -> Audit:
    trajectories, delta, gaps = flown_trajectories(records)
    return Audit(trajectories, delta, gaps, check_fleet(workspace, trajectories, delta))


def _fields(record: Mapping[str, object], number: int) -> tuple[int, str, Cell, int]:
    step, drone, cell, delta = (record.get(k) for k in ("step", "drone", "cell", "delta"))
    if not isinstance(step, int) or not isinstance(drone, str) or not isinstance(delta, int):
        raise ProblemError(f"record {number}: needs an integer step, a drone id and an integer delta")
    if not (isinstance(cell, list) and len(cell) == 3 and all(isinstance(v, int) for v in cell)):
        raise ProblemError(f"record {number}: cell must be [x, y, z] integers, got {cell!r}")
    return step, drone, (cell[0], cell[1], cell[2]), delta
