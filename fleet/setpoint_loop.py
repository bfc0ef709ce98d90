"""The setpoint loop: drives the core's plan executor from the local clock and sends setpoints.

Step ``k`` of a trajectory starts at ``epoch + k * tau`` on the local clock.
At each boundary the core's :class:`~drona_gcs.stack.executor.PlanExecutor`
takes the step and names the cell to be in; the loop sends the vehicle across
that cell, once (:meth:`SetpointLoop.aim_point`): the link streams the sweep at its own
rate (PX4 leaves offboard mode at 2 Hz or less), as MAVSDK's offboard plugin does, so a
second stream here would only double the traffic. At each boundary it also reports where
the vehicle actually is (its cell and the distance to the cell it should be
in) and flags a drone that lags its timed trajectory by more than
``lag_tolerance_m``: the safety argument assumes every drone follows its
timed trajectory, so a lagging drone is an alarm, not a detail. A process
that stalls past a boundary takes the missed ones back to back, and a slow
vehicle is still short of its cell when the next one comes; either way the
vehicle flies the plan's cells in order (:meth:`SetpointLoop.take`), never
straight across a turn to the newest one, and never more than one cell ahead of where it is.
Lambda after each boundary, when a vehicle within its bound must be in the step's cell, the loop
samples where it is (:class:`Sample`): that is what a flight record holds, with how late the vehicle
entered the cell, measured from telemetry. A vehicle whose link is down is one
drone's problem: its loop sends nothing (:attr:`SetpointLoop.suspended`, set by
its agent, which decides what it flies once the vehicle is back), and a send that
fails is dropped, never the end of the process's other loops.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from drona_gcs.errors import VehicleError
from drona_gcs.geo import GeoFrame, Ned
from drona_gcs.stack.executor import PlanExecutor, Setpoint
from drona_gcs.workspace import Cell
from fleet.clock import step_at
from fleet.vehicle.link import STILL, SetpointSink, Sweep


@dataclass(frozen=True)
class StepReport:
    step: int
    target: Cell
    actual: Cell | None  #: where telemetry puts the vehicle (None: no position yet or outside the grid)
    error_m: float  #: distance from the vehicle to the centre of the cell it should be in
    lagging: bool
    late_s: float  #: how late the boundary was taken on the local clock (jitter)
    behind: int = 0  #: cells of the plan the vehicle must still fly through before its target (see SetpointLoop.take)
    planned: Cell | None = None  #: the cell the plan put the drone in for the step that just ended


@dataclass(frozen=True)
class Sample:
    """Lambda after boundary ``step``: whether telemetry saw the vehicle in the step's cell by then
    (as the flight record places it: under the grid, in the cell over it).

    Within its bound, a vehicle enters each cell by lambda after its step begins and leaves it no
    sooner than the next step (it is never sent further): that is what the separation window
    assumes, and what a flight record keeps, step by step, as a sighting of the step's cell. A
    vehicle that was not seen there is recorded where it is when its time ran out.
    """

    step: int
    planned: Cell  #: the cell of the step
    actual: Cell | None  #: ``planned`` if seen there in time, else where it is (None: no cell)
    late_s: float | None  #: how long after the boundary it was first seen in ``planned`` (None: not by lambda)
    #: every cell telemetry put it in since the previous sample's sighting, in order, each once per visit
    passed: tuple[Cell, ...] = ()


@dataclass
class _Arrival:
    """A step awaiting its sample: its cell, its boundary, and when the vehicle was first seen there."""

    step: int
    cell: Cell
    boundary: float
    seen_at: float | None = None


ROUTE_LIMIT = 64  #: cells kept for a vehicle that does not follow at all (it is flagged lagging anyway)
#: of a step: how far short of the face to its next cell a sweep stops (a stalled process's vehicle waits there)
SWEEP_SHORT = 0.1


class SetpointLoop:
    """``check_hz``: how often, while the vehicle has a route (cells to fly through before its
    target), its position is checked to send it on to the next (no faster than telemetry comes is useful)."""

    def __init__(self, sink: SetpointSink, frame: GeoFrame, executor: PlanExecutor, epoch: float, tau: float,
                 clock: Callable[[], float], check_hz: float = 10.0, lag_tolerance_m: float | None = None,
                 tick: Callable[[int], Sequence[object]] | None = None, lateness_s: float = 0.0,
                 link_clock: Callable[[], float] | None = None) -> None:
        if tau <= 0 or check_hz <= 0 or lateness_s < 0:
            raise ValueError("tau and check_hz must be > 0, lateness_s >= 0")
        self.lateness = lateness_s
        #: the clock positions are stamped with (None: ``clock``): an arrival counts when it was reported
        self.link_clock = link_clock or clock
        #: steps taken whose sample is not yet due, oldest first
        self.arrivals: collections.deque[_Arrival] = collections.deque()
        self.sink, self.frame, self.executor = sink, frame, executor
        self.epoch, self.tau, self.clock = epoch, tau, clock
        self.check_period = 1.0 / check_hz
        # By default a drone may trail by a cell: it is between two cells for most of a step.
        self.tolerance = lag_tolerance_m if lag_tolerance_m is not None else frame.ws.cell_size_m
        self.target = executor.cell
        self.came_from = executor.cell  #: the target before this one: the cell of the step before
        #: Cells the vehicle must still fly through, in order, before ``target`` (see :meth:`take`).
        self.route: collections.deque[Cell] = collections.deque()
        self.changed_at = -math.inf  #: when the target last moved
        #: takes a boundary: the executor's own tick, or the whole drone stack's step (which ticks it)
        self.tick: Callable[[int], Sequence[object]] = tick or executor.tick
        self.suspended = False  #: the vehicle is lost: nothing is sent until its agent says where it is
        self.sampled_at = -math.inf  #: the link time the last sample's cells end at: positions after it are news

    def step_at(self, t: float) -> int:
        """The step under way at local time ``t``."""
        return step_at(t, self.epoch, self.tau)

    async def run(self, on_step: Callable[[StepReport, Sequence[object]], None], stop: asyncio.Event,
                  on_sample: Callable[[Sample], None] | None = None) -> None:
        """Until ``stop`` is set: take every boundary (and fly a route after a stall)."""
        sampled = (lambda _, sample: on_sample(sample)) if on_sample is not None else None
        await SetpointFleet([self]).run(lambda _, report, actions: on_step(report, actions), stop, sampled)

    # ------------------------------------------------- used by SetpointFleet
    @property
    def aim(self) -> Cell:
        """The cell the vehicle is sent to: the next one of its route, or the target."""
        return self.route[0] if self.route else self.target

    def aim_point(self) -> tuple[Ned, Sweep | None]:
        """Where the vehicle is sent: swept across the aimed cell as the schedule runs.

        An autopilot slows down as it closes in on a point: aimed at each centre in turn, an
        ArduCopter falls ever further behind a cell per tau. So the vehicle is swept across its cell,
        the velocity fed forward: from the middle of the face it enters by towards the middle of the
        face it leaves by, over the step (:func:`profile`). Straight on, that is through the centre;
        at a turn it cuts the cell's corner (a staircase is flown as a diagonal line), never leaving
        the cell. It slows down to stop at the centre before a wait, the plan's end, or a way back;
        it speeds up from the centre after one. A sweep on to the next cell stops short of its face
        (:data:`SWEEP_SHORT`): the vehicle is never sent into its next cell before that cell's step.
        On time, the sweep starts where the step has got to; behind (a route), each cell of the
        route is swept from its entry as soon as the vehicle is in the cell before, never further.
        """
        way = [*self.route, self.target]
        aim, plan, step = way[0], self.executor.trajectory, self.executor.step
        if self.route:  # from where the vehicle is, as soon as it is in the cell before
            here = self._here()
            before, after, into = here if here is not None else aim, way[1], 0.0
        else:
            before, into = self.came_from, (self.clock() - self._boundary()) / self.tau
            after = plan.at(step + 1) if plan is not None and plan.at(step) == aim else aim
        centre = self.frame.cell_to_ned(aim)
        entry, leave = self._face(aim, before), self._face(aim, after)
        if leave == entry:  # a way back: stop at the centre first
            leave = centre
        if entry == centre == leave:
            return centre, None
        return profile(entry, leave, from_rest=entry == centre, stop=leave == centre, into=into, tau=self.tau)

    def _face(self, cell: Cell, neighbour: Cell) -> Ned:
        """The middle of ``cell``'s face to ``neighbour`` (its centre if that is ``cell``, or not next to it)."""
        here = self.frame.cell_to_ned(cell)
        if sum(abs(a - b) for a, b in zip(cell, neighbour, strict=True)) != 1:
            return here
        there = self.frame.cell_to_ned(neighbour)
        return _along(here, Ned(there.north - here.north, there.east - here.east, there.down - here.down), 0.5)

    def _boundary(self) -> float:
        """When the executor's step began, on the local clock."""
        return self.epoch + self.executor.step * self.tau

    async def send(self) -> None:
        if self.suspended:
            return
        try:
            await self.sink.send_position_target(*self.aim_point())
        except VehicleError:
            return  # the link just went down: its agent sees it at the next boundary

    def suspend(self, suspended: bool) -> None:
        """Send nothing while ``suspended``; either way, forget the route (the plan was left or replaced)."""
        self.suspended = suspended
        self.route.clear()

    def take(self, step: int, boundary: float) -> tuple[StepReport, Sequence[object]]:
        """Take boundary ``step`` (no I/O): the executor moves the target to its next cell.

        A vehicle sent to the new target before it reached the last one flies straight at it, and
        across a turn that cuts the corner, through a cell that was never reserved for it. This
        happens when boundaries are taken back to back (the process stalled past one: the vehicle
        had no time) and when the vehicle is too slow (wind, a low speed limit). So the last target
        stays on the route when the vehicle is in neither it nor the new target; so does every
        target that comes while a route is pending. The vehicle flies the plan's cells in order,
        each as soon as it is in the last, late (and flagged lagging) rather than off the path, and
        on a straight line too: sent further, it would reach its cells earlier than a peer behind
        it was told. Under the grid, still climbing, it is in the cell over it (as its flight record
        has it). Where telemetry puts the vehicle in no cell (no position yet, or outside the grid)
        only a stall counts: it is flagged lagging, and a route it could never be seen to fly would
        only grow.
        """
        now = self.clock()
        previous = self.came_from = self.target
        actions = self.tick(step)
        self.target = next(a.cell for a in actions if isinstance(a, Setpoint))
        if self.target != previous and not self.suspended:
            # A target never aimed at (a route was pending) must be flown through too.
            if self.route or self._short_of(previous, now):
                self.route.append(previous)
                if len(self.route) > ROUTE_LIMIT:  # it is not following at all: keep the newest cells
                    del self.route[1]
            self.changed_at = now
        self.arrivals.append(_Arrival(step, self.target, boundary))
        if self.sampled_at == -math.inf:  # what came before the first step is no step's
            self.sampled_at = self.link_clock()
        self.look()
        return self._report(step, previous, self.target, now - boundary), actions

    def look(self) -> None:
        """Note the steps whose cell the vehicle is in now, for the first time. Both clocks are read
        here: a time read before a tick or another drone's turn would date the report too early."""
        position = self.sink.last_position() if self.arrivals and not self.suspended else None
        if position is None:
            return
        here = self.frame.recorded_cell(position.ned)  # below the grid: over its take-off or landing
        seen = self.clock() - max(0.0, self.link_clock() - position.at)  # a look the process was late to make
        for arrival in self.arrivals:
            if arrival.seen_at is None and here == arrival.cell:
                arrival.seen_at = max(seen, arrival.boundary)

    @property
    def arriving(self) -> bool:
        """Whether a step awaiting its sample has not yet seen the vehicle in its cell."""
        return any(a.seen_at is None for a in self.arrivals)

    def sample(self, step: int) -> Sample | None:
        """Boundary ``step``'s sample, due lambda after it (None: the loop never took that step)."""
        while self.arrivals and self.arrivals[0].step < step:
            self.arrivals.popleft()
        if not self.arrivals or self.arrivals[0].step != step:
            return None
        arrival = self.arrivals.popleft()
        if arrival.seen_at is None:
            due = self.epoch + step * self.tau + self.lateness
            return Sample(step, arrival.cell, self._here(), None, self._passed(due))
        return Sample(step, arrival.cell, arrival.cell, max(0.0, arrival.seen_at - arrival.boundary),
                      self._passed(arrival.seen_at))

    def _passed(self, until: float) -> tuple[Cell, ...]:
        """The cells (as the flight record places them) of the positions reported since the last sample's
        sighting, up to this one's (local time ``until``): when the vehicle was seen in the step's cell, or
        when the sample was due. Not up to now: lambda may span steps, and a process may sample late."""
        reported_until = self.link_clock() - max(0.0, self.clock() - until)
        positions = [p for p in self.sink.positions_since(self.sampled_at) if p.at <= reported_until]
        self.sampled_at = max(self.sampled_at, reported_until)
        cells = (self.frame.recorded_cell(p.ned) for p in positions)
        return tuple(cell for cell, _ in itertools.groupby(c for c in cells if c is not None))

    def _short_of(self, previous: Cell, now: float) -> bool:
        """Whether the vehicle, not yet in ``previous``, must fly through it before the new target: it
        is never sent more than one cell ahead of where it is. Where no cell is known only a stall counts."""
        here = self._here()
        if here is None:
            return now - self.changed_at < self.tau / 2
        return here not in (previous, self.target)

    def advance(self) -> bool:
        """Drop the route's cells up to the one the vehicle is in (it got that far); whether the aim
        moved (send it now). Only the next two count: a plan may come back to a cell, and a vehicle
        may cross a whole cell between two looks."""
        here = self._here() if self.route and not self.suspended else None
        ahead = [*itertools.islice(self.route, 2), self.target][:2]
        if here is None or here not in ahead:
            return False
        for _ in range(min(ahead.index(here) + 1, len(self.route))):
            self.route.popleft()
        return True

    def _here(self) -> Cell | None:
        """The cell telemetry puts the vehicle in, as the flight record does: under the grid (climbing
        late, landing), the cell over it. None: no position yet, or outside the grid."""
        position = self.sink.last_position()
        return None if position is None else self.frame.recorded_cell(position.ned)

    def _report(self, step: int, previous: Cell, target: Cell, late: float) -> StepReport:
        """At boundary ``step`` the vehicle should have reached ``previous`` (last step's cell)."""
        position = self.sink.last_position()
        if position is None:
            return StepReport(step, target, None, math.inf, True, late, len(self.route), previous)
        fix = self.frame.locate(position.ned)
        should = self.frame.cell_to_ned(previous)
        error = math.dist((position.ned.north, position.ned.east, position.ned.down),
                          (should.north, should.east, should.down))
        return StepReport(step, target, fix.cell, error, error > self.tolerance, late, len(self.route), previous)


class SetpointFleet:
    """The setpoint loops of every drone a process hosts, on one timer.

    At a boundary each executor takes its step and its new target is sent, one
    drone after the other: loops that each woke on their own timer would take
    their boundaries further apart. Between two drones the event loop takes a
    turn (a step costs a few hundred microseconds with its stack's).
    """

    def __init__(self, loops: Sequence[SetpointLoop]) -> None:
        if not loops:
            raise ValueError("no setpoint loops")
        first = loops[0]
        if any(loop.epoch != first.epoch or loop.tau != first.tau for loop in loops):
            raise ValueError("the loops of one process share the fleet epoch and tau")
        self.loops, self.clock, self.epoch, self.tau = list(loops), first.clock, first.epoch, first.tau

    async def run(self, on_step: Callable[[int, StepReport, Sequence[object]], None], stop: asyncio.Event,
                  on_sample: Callable[[int, Sample], None] | None = None) -> None:
        """Until ``stop`` is set; ``on_step(i, report, actions)`` for loop ``i`` at each boundary, and
        ``on_sample(i, sample)`` lambda after it."""
        step = max(self.loops[0].step_at(self.clock()), *(loop.executor.step + 1 for loop in self.loops))
        sampled = step  #: the next step to sample
        lateness = max(loop.lateness for loop in self.loops)
        for loop in self.loops:  # the link streams from the first setpoint on
            await loop.send()
        while not stop.is_set():
            boundary = self.epoch + step * self.tau
            while self.clock() < boundary and not stop.is_set():
                await self._between(stop, min(boundary, self._sample_at(sampled, lateness)))
                while sampled < step and self.clock() >= self._sample_at(sampled, lateness):
                    await self._sample(sampled, on_sample)
                    sampled += 1
            if stop.is_set():
                return
            taken = []
            for loop in self.loops:
                taken.append(loop.take(step, boundary))
                await loop.send()
                await _let_messages_in()
            for i, (report, actions) in enumerate(taken):
                on_step(i, report, actions)
            step += 1

    def _sample_at(self, step: int, lateness: float) -> float:
        return self.epoch + step * self.tau + lateness

    async def _sample(self, step: int, on_sample: Callable[[int, Sample], None] | None) -> None:
        for i, loop in enumerate(self.loops):
            sample = loop.sample(step)
            if sample is not None and on_sample is not None:
                on_sample(i, sample)
            await _let_messages_in()

    async def _between(self, stop: asyncio.Event, until: float) -> None:
        """Until ``until``: fly routes (catching up on a stall or a turn), and watch for arrivals."""
        now = self.clock()
        for loop in self.loops:
            loop.look()
            if loop.advance():
                await loop.send()
        watched = [loop.check_period for loop in self.loops if loop.route or loop.arriving]
        wake = now + min(watched) if watched else until
        await _sleep_or_stop(stop, min(wake, until) - self.clock())


async def _let_messages_in() -> None:
    """One turn of the loop: a peer's message that came meanwhile is taken before the next drone's step
    (Zenoh's inbox hands the loop one per turn). A round started at a boundary waits on every process's
    drones, all busy with the same boundary."""
    await asyncio.sleep(0)


def profile(entry: Ned, leave: Ned, *, from_rest: bool, stop: bool, into: float, tau: float) -> tuple[Ned, Sweep]:
    """A step's sweep from ``entry`` towards ``leave``, ``into`` (a share of tau) after the step began:
    at an even pace; slowing down evenly to stop at ``leave`` by the step's end (``stop``), from the
    pace it came at; or speeding up evenly from rest to that pace (``from_rest``). One that does not
    stop ends short of ``leave`` (:data:`SWEEP_SHORT`). Its acceleration is at most a cell's length over
    tau squared."""
    end = 1.0 if stop else 1.0 - SWEEP_SHORT
    u = min(max(into, 0.0), end)
    if stop:  # the share of the way covered by u: 2u - u², its pace 2 - 2u and its change -2
        covered, pace, change = 2 * u - u * u, 2 - 2 * u, -2.0
    elif from_rest:
        covered, pace, change = u * u, 2 * u, 2.0
    else:
        covered, pace, change = u, 1.0, 0.0
    way = _between(entry, leave)
    return _along(entry, way, covered), Sweep(_along(STILL, way, pace / tau), (end - u) * tau,
                                              _along(STILL, way, change / (tau * tau)))


def _between(a: Ned, b: Ned) -> Ned:
    return Ned(b.north - a.north, b.east - a.east, b.down - a.down)


def _along(start: Ned, way: Ned, share: float) -> Ned:
    """``start`` moved ``share`` of ``way``."""
    return Ned(start.north + share * way.north, start.east + share * way.east, start.down + share * way.down)


async def _sleep_or_stop(stop: asyncio.Event, seconds: float) -> None:
    with contextlib.suppress(TimeoutError):
        await asyncio.wait_for(stop.wait(), timeout=max(seconds, 0))
