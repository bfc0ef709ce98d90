"""The simulator's own flight record: where each fake vehicle really was at each step.

An agent's record (``drona agent --record``) is what its telemetry showed it: a host that falls
behind reads positions late, and its record goes wrong with it. This one comes from the physics,
on the wall clock the fleet's steps are counted on, and shares nothing with the agents: an audit
of it (``drona audit``) judges what was flown, whoever planned it.

Each line is one vehicle at one step, in the agents' format (see :mod:`drona_gcs.audit`): the cell
it was in when the step began, the cells it passed since the line before (``via``), no plan, and
``delta`` 0: two vehicles in one cell within a step of each other were there together.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TextIO

from drona_gcs.audit import record_line, went_through
from drona_gcs.geo import GeoFrame, Ned
from drona_gcs.workspace import Cell
from fleet.clock import step_at

TRUTH_DELTA = 0  #: one clock, no plan: the same cell within the same step


class TruthRecord:
    """Writes a line per vehicle each time a step begins; ``observe`` at every physics tick."""

    def __init__(self, frame: GeoFrame, drones: Sequence[str], epoch: float, out: TextIO) -> None:
        self.frame, self.drones, self.epoch, self.out = frame, list(drones), epoch, out
        self.tau = frame.ws.tau_s
        self._step: int | None = None
        self._last: list[Cell | None] = [None] * len(self.drones)  #: each vehicle's last recorded cell
        self._passed: list[list[Cell]] = [[] for _ in self.drones]  #: cells seen since, in order

    def observe(self, wall: float, positions: Sequence[Ned]) -> None:
        """The vehicles' positions (workspace NED, in ``drones`` order) at Unix time ``wall``."""
        step = step_at(wall, self.epoch, self.tau)
        begins = step != self._step
        self._step = step
        for i, ned in enumerate(positions):
            cell = self.frame.recorded_cell(ned)
            if begins:
                self._write(i, step, cell)
            elif cell is not None and (not self._passed[i] or self._passed[i][-1] != cell):
                self._passed[i].append(cell)
        if begins:  # a simulator killed keeps its record up to its last step
            self.out.flush()

    def _write(self, i: int, step: int, cell: Cell | None) -> None:
        if cell is None:  # outside the grid: its cells so far go with the next line
            return
        via = went_through(tuple(self._passed[i]), self._last[i], cell)
        self.out.write(record_line(step, self.drones[i], cell, None, TRUTH_DELTA, via))
        self._last[i], self._passed[i] = cell, []
