"""How a drone's agent judges its vehicle, at every step boundary and lambda after it: lost, back,
placed at its start, down by itself, later than lambda, lagging behind its plan.

A mixin of :class:`~fleet.agent.drone.DroneAgent`, which holds the state named below; what the
vehicle itself reports is read through :class:`~fleet.agent.watch.VehicleWatch`.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import TYPE_CHECKING, TextIO

from drona_gcs.audit import record_line, went_through
from drona_gcs.geo import GeoFrame
from drona_gcs.stack.drone import DroneAction, DroneStack
from drona_gcs.stack.protocol import State
from drona_gcs.workspace import Cell, Workspace
from fleet.agent.maildesk import MailDesk
from fleet.agent.vehicle import VehicleSupervisor
from fleet.agent.watch import Seen, VehicleWatch, Verdict, joined
from fleet.setpoint_loop import Sample, SetpointLoop, StepReport
from fleet.vehicle.limits import shortfalls
from fleet.vehicle.link import Autopilot, Readiness, VehicleLink

log = logging.getLogger("fleet.agent.drone")  # the agent's logger: its lines keep their name


class Tracking:
    """The vehicle's side of a drone's agent (see the module docstring)."""

    me: str
    stack: DroneStack
    link: VehicleLink
    frame: GeoFrame
    ws: Workspace
    delta: int
    record: TextIO | None
    vehicle: VehicleSupervisor
    watch: VehicleWatch
    setpoints: SetpointLoop | None
    mail: MailDesk
    out_of_service: str | None
    placed: bool
    actual: Cell | None
    recorded: Cell | None
    passing: tuple[Cell, ...]
    battery_pct: float
    late: str | None
    limits_short: str | None
    boundary_late_s: float
    on_time_at: int | None
    down: bool

    if TYPE_CHECKING:  # the agent's own
        def _carry_out(self, actions: Sequence[DroneAction]) -> None: ...
        def _alarm(self, kind: str, text: str | None) -> None: ...
        def _refusal(self) -> str | None: ...
        def publish_state_soon(self, delay_s: float = 0.0) -> None: ...

    def _watch_vehicle(self, step: int) -> None:
        """Lost, back, placed: what the vehicle did since the last boundary, and what the drone does about it."""
        protocol = self.stack.protocol
        verdict = self.watch.boundary(step, protocol.holds(), placeable=not protocol.coordinating)
        if verdict.seen is Seen.LOST:
            self._lost(step, verdict)
        elif verdict.seen is Seen.BACK:
            self._back(verdict)
        elif verdict.seen is Seen.BACK_ELSEWHERE:
            self.out_of_service = f"{verdict.reason}: land it by hand, then restart its agent"
            log.error("%s: %s", self.me, self.out_of_service)
            self._alarm("vehicle_lost", f"vehicle_lost: {self.out_of_service}")
        if not self.placed and not self.watch.lost and self.watch.readiness() is Readiness.READY:
            self._place()

    def _lost(self, step: int, verdict: Verdict) -> None:
        seen = self.watch.last_seen or self.stack.executor.cell
        log.warning("%s: vehicle lost (%s): holding every cell it may be in, taking no task", self.me, verdict.reason)
        self._alarm("vehicle_lost", f"vehicle_lost: {verdict.reason}")
        self.vehicle.pause(True)
        if self.setpoints is not None:
            self.setpoints.suspend(True)
        self._carry_out(self.stack.vehicle_lost(step, seen, f"drone {self.me}'s vehicle is lost"))

    def _back(self, verdict: Verdict) -> None:
        assert verdict.cell is not None
        where = "landed below" if verdict.landed else "in"
        log.warning("%s: vehicle back, %s %s: it rests there", self.me, where, list(verdict.cell))
        self._alarm("vehicle_lost", None)
        self._carry_out(self.stack.vehicle_back(verdict.cell, verdict.landed))
        self.vehicle.pause(False, airborne=not verdict.landed)
        if self.setpoints is not None:
            self.setpoints.suspend(False)

    def _place(self) -> None:
        """Checked once the vehicle is located (see VehicleWatch.misplaced): judged once, for good."""
        self.placed = True
        self.out_of_service = self.watch.misplaced(self.stack.executor.cell)
        if self.out_of_service is not None:
            log.error("%s: %s", self.me, self.out_of_service)
            self._alarm("placement", f"placement: {self.out_of_service}")

    def on_step(self, report: StepReport, actions: Sequence[object]) -> None:
        """After the boundary's setpoints went out: judge the vehicle, record it, publish the state."""
        self.boundary_late_s = report.late_s
        self.actual = self.watch.seen_cell()
        if self.actual is None:
            log.debug("%s: no cell at step %d: position %s", self.me, report.step, self.link.last_position())
        if not self.down and not self.watch.lost and self.vehicle.grounded_by_itself():
            self.down = True
            self.mail.refusal = "its vehicle came down by itself"
            below = self.watch.recorded_cell()
            where = f"in {list(below)}" if below is not None else "outside the grid"
            log.warning("%s: the vehicle came down by itself %s: its mail is handed back", self.me, where)
            cell = below if below is not None else self.stack.executor.cell
            self._carry_out(self.stack.vehicle_down(f"drone {self.me}'s vehicle came down by itself {where}", cell))
        if self._sent_too_late(report):
            self._late(f"its setpoint for {list(report.target)} went out {report.late_s:.3g} s after step "
                       f"{report.step} began, later than lambda ({self.ws.lateness_s:g} s)")
        self._judge_limits()
        self._alarm("lag", self._lag(report))
        self._alarm("down", "vehicle: came down while its plan flew (a failsafe or a pilot?); its mail was handed "
                    "back and it starts no task; restart its agent once it is back in service" if self.down else None)
        self._alarm("behind", f"catching up (a stall, or a vehicle too slow at a turn): {report.behind} "
                    "cells of its plan still to fly through" if report.behind else None)
        # A plan scheduled but not begun still needs the climb: the lead steps are for it.
        # Landing crosses only its own column when the cell is on the lowest layer; higher up it hovers.
        grounded = self.stack.landed and self.stack.executor.cell[2] == 0
        self.vehicle.want_airborne(not grounded or self.stack.protocol.state is State.EXECUTING)
        # Half a period later: at the boundary every drone of the fleet is busy, and answers come first.
        self.publish_state_soon(self.ws.tau_s / 2)

    def on_sample(self, sample: Sample) -> None:
        """Lambda after a boundary: record where the vehicle was, and judge how late it came."""
        seen = self.watch.seen_cell("sample")  # None: no fresh position, a gap in the record
        flown = sample.planned if sample.late_s is not None else self._when_due(sample, seen)
        if self.record is not None:
            self._record(sample, flown if seen is not None else None)
        if self.down or self.watch.lost:
            return
        if sample.late_s is not None:
            self.on_time_at = sample.step
        if (self.late is not None and self.limits_short is None and seen == self.stack.executor.cell
                and self.stack.executor.trajectory is None):
            self._on_time_again()  # in the air or landed below it: its vehicle is where its plan ended
        elif self.late is None and sample.late_s is None and self.vehicle.wanted:
            # In the air or not yet: a climb longer than the lead is late too.
            self._late(f"its vehicle was not in {list(sample.planned)} {self.ws.lateness_s:g} s (lambda) after "
                       f"step {sample.step} began")
        self.mail.refusal = self._refusal()
        self._alarm("late", None if self.late is None else f"late: {self.late}")

    @staticmethod
    def _when_due(sample: Sample, seen: Cell | None) -> Cell | None:
        """A late vehicle's cell when its sample was due: a host sampling late has seen it fly on since,
        and those cells are the next record's."""
        return sample.passed[-1] if sample.passed and seen is not None else seen

    def _record(self, sample: Sample, flown: Cell | None) -> None:
        """One line of the flight record, with the cells passed since the last line (None: a gap, whose
        cells go with the next line)."""
        assert self.record is not None
        self.passing = joined(self.passing, sample.passed)
        if flown is None:
            return
        via = went_through(self.passing, self.recorded, flown)
        self.record.write(record_line(sample.step, self.me, flown, sample.planned, self.delta, via))
        self.recorded, self.passing = flown, ()

    def _on_time_again(self) -> None:
        log.warning("%s: its vehicle is where its plan ended: it takes tasks again", self.me)
        self.late = None
        self._carry_out(self.stack.tracking_bound(False, ""))

    def _late(self, why: str) -> None:
        """Later than lambda, the margin peers planned with is gone: hold where the plan ends, until the
        vehicle is there."""
        self.late = why
        log.warning("%s: %s: it holds where its plan ends, and takes no task until it is on time", self.me, self.late)
        self._carry_out(self.stack.tracking_bound(True, f"drone {self.me}'s vehicle is later than lambda",
                                                  self.on_time_at))

    def _judge_limits(self) -> None:
        """A limit set lower in flight (the autopilot tells every ground station): lambda no longer holds,
        so the drone is late, and stays out of its bound until the limit is set back."""
        autopilot = self.link.telemetry().autopilot or Autopilot.OTHER
        short = shortfalls(autopilot, self.link.parameters_heard(), self.ws.vehicle, self.ws.tau_s, unanswered=False)
        was, self.limits_short = self.limits_short, "; ".join(short) or None
        if self.limits_short != was:
            log.warning("%s: its vehicle's limits %s", self.me, self.limits_short or "are back within the workspace's")
        if self.limits_short is not None and self.late is None and not self.down and not self.watch.lost:
            self._late(f"its autopilot was set out of the workspace's vehicle limits: {self.limits_short}")
        self._alarm("limits", None if self.limits_short is None else f"limits: {self.limits_short}")

    def _sent_too_late(self, report: StepReport) -> bool:
        """A vehicle sent to its next cell more than lambda into the step cannot be there within lambda:
        late at once, not a sample later (a host that far behind samples late too)."""
        moving = report.planned is not None and report.target != report.planned
        return (moving and report.late_s > self.ws.lateness_s and self.late is None and not self.down
                and not self.watch.lost and self.vehicle.wanted)

    def _lag(self, report: StepReport) -> str | None:
        """Trailing its timed trajectory, or on the ground while its plan flies: the separation argument
        assumes every drone is where its plan says."""
        if self.down or self.watch.lost:
            return None
        if self.stack.executor.flying and not self.vehicle.settled:
            return "lag: vehicle not in the air while its plan flies"
        return f"lag: vehicle {report.error_m:.1f} m from its cell" if report.lagging and self.vehicle.settled else None

    def _battery(self) -> float:
        pct = self.link.telemetry().battery_pct
        if pct is not None:
            self.battery_pct = float(pct)
        return self.battery_pct
