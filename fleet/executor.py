"""The setpoint loop: drives the core's plan executor from the local clock and streams setpoints.

Step ``k`` of a trajectory starts at ``epoch + k * tau`` on the local clock.
At each boundary the core's :class:`~drona_gcs.stack.executor.PlanExecutor`
takes the step and names the cell to be in; the loop moves the target to
that cell's centre and keeps streaming it between boundaries at ``rate_hz``
(PX4 leaves offboard mode below 2 Hz). At each boundary it also reports where
the vehicle actually is (its cell and the distance to the cell it should be
in) and flags a drone that lags its timed trajectory by more than
``lag_tolerance_m``: the safety argument assumes every drone follows its
timed trajectory, so a lagging drone is an alarm, not a detail.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from drona_gcs.geo import GeoFrame
from drona_gcs.stack.executor import ExecutorAction, PlanExecutor, Setpoint
from drona_gcs.workspace import Cell
from fleet.vehicle.link import SetpointSink


@dataclass(frozen=True)
class StepReport:
    step: int
    target: Cell
    actual: Cell | None  #: where telemetry puts the vehicle (None: no position yet or outside the grid)
    error_m: float  #: distance from the vehicle to the centre of the cell it should be in
    lagging: bool
    late_s: float  #: how late the boundary was taken on the local clock (jitter)


class SetpointLoop:
    def __init__(self, sink: SetpointSink, frame: GeoFrame, executor: PlanExecutor, epoch: float, tau: float,
                 clock: Callable[[], float], rate_hz: float = 10.0, lag_tolerance_m: float | None = None) -> None:
        if tau <= 0 or rate_hz <= 0:
            raise ValueError("tau and rate_hz must be > 0")
        self.sink, self.frame, self.executor = sink, frame, executor
        self.epoch, self.tau, self.clock = epoch, tau, clock
        self.period = 1.0 / rate_hz
        # By default a drone may trail by a cell: it is between two cells for most of a step.
        self.tolerance = lag_tolerance_m if lag_tolerance_m is not None else frame.ws.cell_size_m

    def step_at(self, t: float) -> int:
        """The step under way at local time ``t``."""
        return math.floor((t - self.epoch) / self.tau)

    async def run(self, on_step: Callable[[StepReport, Sequence[ExecutorAction]], None],
                  stop: asyncio.Event) -> None:
        """Until ``stop`` is set: take every boundary, stream the target between them."""
        step = max(self.step_at(self.clock()), self.executor.step + 1)
        target = self.executor.cell
        while not stop.is_set():
            boundary = self.epoch + step * self.tau
            while (now := self.clock()) < boundary and not stop.is_set():
                await self.sink.send_position_target(self.frame.cell_to_ned(target))
                await _sleep_or_stop(stop, min(self.period, boundary - now))
            if stop.is_set():
                return
            late = self.clock() - boundary
            previous = target
            actions = self.executor.tick(step)
            target = next(a.cell for a in actions if isinstance(a, Setpoint))
            await self.sink.send_position_target(self.frame.cell_to_ned(target))
            on_step(self._report(step, previous, target, late), actions)
            step += 1

    def _report(self, step: int, previous: Cell, target: Cell, late: float) -> StepReport:
        """At boundary ``step`` the vehicle should have reached ``previous`` (last step's cell)."""
        position = self.sink.last_position()
        if position is None:
            return StepReport(step, target, None, math.inf, True, late)
        fix = self.frame.locate(position.ned)
        should = self.frame.cell_to_ned(previous)
        error = math.dist((position.ned.north, position.ned.east, position.ned.down),
                          (should.north, should.east, should.down))
        return StepReport(step, target, fix.cell, error, error > self.tolerance, late)


async def _sleep_or_stop(stop: asyncio.Event, seconds: float) -> None:
    with contextlib.suppress(TimeoutError):
        await asyncio.wait_for(stop.wait(), timeout=max(seconds, 0))
