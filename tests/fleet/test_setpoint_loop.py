"""The setpoint loop: boundaries on the clock, one setpoint each (the link streams it), lag detection."""

from __future__ import annotations

import asyncio
import itertools
import json
import math
import time
from collections.abc import Callable, Sequence

import pytest

from drona_gcs.audit import audit, moves, record_line, went_through
from drona_gcs.geo import GeoFrame, Ned
from drona_gcs.motion import Trajectory
from drona_gcs.stack.executor import Completed, ExecutorAction, PlanExecutor, Setpoint
from drona_gcs.workspace import Cell, VehicleLimits, Workspace
from fleet.setpoint_loop import SWEEP_SHORT, Sample, SetpointLoop, StepReport
from fleet.sim.config import VehicleConfig
from fleet.sim.params import limit_params, starting_limits
from fleet.sim.personality import ARDUPILOT
from fleet.sim.physics import Body, Limits, Target
from fleet.vehicle.link import Aim, Position, Sweep, Trail
from tests.fakes.vehicle import FakeVehicle

WS = Workspace.build(size=(6, 4, 1), cell_size_m=4.0, tau_s=0.1)
FRAME = GeoFrame(WS)
TRAJ = Trajectory(2, ((0, 0, 0), (1, 0, 0), (2, 0, 0), (2, 1, 0)))


def executor_actions(done: Sequence[object]) -> list[ExecutorAction]:
    """A step's actions, as the loop reports them: its executor's."""
    actions = [a for a in done if isinstance(a, Setpoint | Completed)]
    assert len(actions) == len(done), done
    return actions


def cell_of(ned: Ned) -> Cell:
    """The cell a position is in (it is in the workspace)."""
    cell = FRAME.locate(ned).cell
    assert cell is not None, ned
    return cell


async def fly(follow: bool, steps: int = 7) -> tuple[list[StepReport], list[ExecutorAction], FakeVehicle, float]:
    loop = asyncio.get_running_loop()
    sink = FakeVehicle(FRAME, (0, 0, 0), at=0.0, clock=loop.time, follow=follow)
    executor = PlanExecutor((0, 0, 0))
    executor.start(TRAJ)
    epoch = loop.time() + 0.05
    reports: list[StepReport] = []
    actions: list[ExecutorAction] = []
    stop = asyncio.Event()

    def on_step(report: StepReport, done: Sequence[object]) -> None:
        reports.append(report)
        actions.extend(executor_actions(done))
        if len(reports) == steps:
            stop.set()

    runner = SetpointLoop(sink, FRAME, executor, epoch, 0.1, loop.time, check_hz=40.0)
    await asyncio.wait_for(runner.run(on_step, stop), timeout=10)
    return reports, actions, sink, epoch


def face(cell: Cell, neighbour: Cell) -> Ned:
    """The middle of ``cell``'s face to ``neighbour`` (its centre when that is ``cell``)."""
    a, b = FRAME.cell_to_ned(cell), FRAME.cell_to_ned(neighbour)
    return Ned((a.north + b.north) / 2, (a.east + b.east) / 2, (a.down + b.down) / 2)


#: TRAJ's steps swept: from the face (or centre) the vehicle enters by, to the face (or centre) it leaves
#: by; the share of that way covered u of the way into the step, and where the sweep ends.
SWEPT: dict[int, tuple[Cell, Cell, Callable[[float], float], float]] = {
    2: ((0, 0, 0), (1, 0, 0), lambda u: u * u, 0.81),  # from rest at the start cell's centre, speeding up
    3: ((0, 0, 0), (2, 0, 0), lambda u: u, 0.9),  # straight on, short of the face
    4: ((1, 0, 0), (2, 1, 0), lambda u: u, 0.9),  # the turn: across the corner
    5: ((2, 0, 0), (2, 1, 0), lambda u: 2 * u - u * u, 1.0),  # the end: slowing down to stop at the centre
}


def close(a: Ned, b: Ned, within: float = 1e-6) -> bool:
    return math.dist((a.north, a.east, a.down), (b.north, b.east, b.down)) <= within


def test_boundaries_follow_the_timed_trajectory() -> None:
    reports, actions, sink, epoch = asyncio.run(fly(follow=True))
    assert [r.step for r in reports] == list(range(7))
    assert [r.target for r in reports] == [TRAJ.at(k) for k in range(7)]
    assert [a for a in actions if isinstance(a, Completed)] == [Completed(TRAJ)]
    assert max(r.late_s for r in reports) < 0.05  # generous for a loaded CI machine
    assert not any(r.lagging for r in reports[1:])
    # Every boundary's target is sent once, at the boundary: the link streams it (a second stream
    # here would double the traffic to the vehicle).
    for k in range(1, 7):
        start, end = epoch + k * 0.1, epoch + (k + 1) * 0.1
        between = [sent for sent in sink.sent if start <= sent[0] < end]
        at, target, sweep = between[0]
        assert at - start < 0.05
        if k not in SWEPT:  # before the plan, and after it: held at the centre
            assert (target, sweep) == (FRAME.cell_to_ned(TRAJ.at(k)), None) and len(between) <= 1, f"step {k}"
            continue
        assert len(between) == 1, f"step {k}: {between}"
        came, goes, covered, ends = SWEPT[k]
        cell = TRAJ.at(k)
        entry, leave = face(cell, came), face(cell, goes)
        way = Ned(leave.north - entry.north, leave.east - entry.east, leave.down - entry.down)
        u = (at - start) / 0.1
        assert sweep is not None, f"step {k}"
        share = covered(u)
        assert close(target, Ned(entry.north + share * way.north, entry.east + share * way.east, entry.down), 0.1)
        pace = (covered(u + 1e-4) - share) / 1e-4 / 0.1  # how fast the share grows, per second
        assert close(sweep.velocity, Ned(pace * way.north, pace * way.east, 0.0), 0.05 * math.hypot(way.north, way.east)
                     / 0.1), f"step {k}: {sweep}"
        stop = Ned(entry.north + ends * way.north, entry.east + ends * way.east, entry.down)
        assert close(sweep.at(target, sweep.duration_s).where, stop, 1e-3), f"step {k}"


def test_a_drone_that_does_not_follow_is_flagged_lagging() -> None:
    reports, _, _, _ = asyncio.run(fly(follow=False))
    # It stays at (0,0,0): from the step after it should have reached (2,0,0), it lags 8 m > 4 m.
    lagging = [r.step for r in reports if r.lagging]
    assert lagging and lagging[0] == 5
    assert reports[5].actual == (0, 0, 0) and reports[5].error_m == 8.0


class CruisingSink(FakeVehicle):
    """The shared fake vehicle, flying at ``speed`` m/s straight at the last setpoint (where a sweep has
    got to) and stopping on it; it records the straight legs it was sent along (where it was when a
    new setpoint came, and where that setpoint ends: its point, or the end of its sweep)."""

    def __init__(self, loop: asyncio.AbstractEventLoop, start: Ned, speed: float) -> None:
        super().__init__(FRAME, at=loop.time(), clock=loop.time)
        self.speed, self.here = speed, start
        self.aim = Aim(start, None, loop.time())
        self.legs: list[tuple[Ned, Ned]] = []

    def _move(self) -> None:
        now = self.clock()
        aim = self.aim.at(now).where
        gap = math.dist((self.here.north, self.here.east), (aim.north, aim.east))
        step = min(gap, self.speed * (now - self.at))
        if gap > 0:
            f = step / gap
            self.here = Ned(self.here.north + f * (aim.north - self.here.north),
                            self.here.east + f * (aim.east - self.here.east), aim.down)
        self.where, self.at = self.here, now

    async def send_position_target(self, target: Ned, sweep: Sweep | None = None) -> None:
        self._move()
        if (target, sweep) != (self.aim.start, self.aim.sweep):
            end = target if sweep is None else sweep.at(target, sweep.duration_s).where
            self.legs.append((self.here, end))
        self.aim = Aim(target, sweep, self.clock())
        await super().send_position_target(target, sweep)

    def last_position(self) -> Position | None:
        self._move()
        return super().last_position()


def cruise(plan: Trajectory, cells_a_step: float, tau: float,
           until: Callable[[StepReport, CruisingSink], bool], check_hz: float = 40.0,
           stall: tuple[int, float] | None = None, lateness_s: float = 0.0,
           samples: list[Sample] | None = None) -> tuple[CruisingSink, list[StepReport]]:
    """Fly ``plan`` with a :class:`CruisingSink` at ``cells_a_step`` until ``until(report, sink)``;
    ``stall``: at that step the whole process blocks for that many seconds (a blocking call, a
    paused VM)."""
    async def scenario() -> tuple[CruisingSink, list[StepReport]]:
        loop = asyncio.get_running_loop()
        sink = CruisingSink(loop, FRAME.cell_to_ned(plan.cells[0]), speed=cells_a_step * 4.0 / tau)
        executor = PlanExecutor(plan.cells[0])
        executor.start(plan)
        reports: list[StepReport] = []
        stop = asyncio.Event()

        def on_step(report: StepReport, done: Sequence[object]) -> None:
            reports.append(report)
            if stall is not None and report.step == stall[0]:
                time.sleep(stall[1])
            if until(report, sink):
                stop.set()

        runner = SetpointLoop(sink, FRAME, executor, loop.time() + 0.05, tau, loop.time, check_hz=check_hz,
                              lateness_s=lateness_s)
        sampled = None if samples is None else samples.append
        await asyncio.wait_for(runner.run(on_step, stop, on_sample=sampled), timeout=10)
        return sink, reports

    return asyncio.run(scenario())


def legs_off_the_plan(sink: CruisingSink, plan: Trajectory) -> list[str]:
    """The straight legs the vehicle flew that cross a cell the plan never had."""
    allowed, off = set(plan.cells), []
    for start, end in sink.legs:
        for i in range(101):
            f = i / 100
            point = Ned(start.north + f * (end.north - start.north), start.east + f * (end.east - start.east),
                        end.down)
            if FRAME.locate(point).cell not in allowed:
                off.append(f"{start} -> {end} crosses {FRAME.locate(point).cell}")
                break
    return off


def cells_sent_to(sink: CruisingSink, plan: Trajectory) -> list[Cell | None]:
    """The cells the vehicle was sent into after its start cell, in order, each once a visit (a cell is
    swept across and a sweep sent again after a stall)."""
    cells = [FRAME.locate(end).cell for _, end in sink.legs]
    visits = [c for i, c in enumerate(cells) if i == 0 or c != cells[i - 1]]
    return visits[1:] if visits and visits[0] == plan.cells[0] else visits


LONG = Trajectory(2, ((0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0), (3, 1, 0), (3, 2, 0)))


@pytest.mark.parametrize("plan, cells_a_step, stalled_steps", [(TRAJ, 2.0, 3.5), (LONG, 1.2, 3.2)],
                         ids=["fast-corner-in-the-stall", "slow-corner-after-the-stall"])
def test_a_stalled_process_catches_up_through_every_cell_and_cuts_no_corner(
        plan: Trajectory, cells_a_step: float, stalled_steps: float) -> None:
    """The process stalls over boundaries before a corner. Sent straight to the newest cell, the
    vehicle would fly across a cell the plan never reserved (with TRAJ, from (0,0,0) across (1,1,0));
    it must fly the plan's cells in order instead, the corner too, even when it is still catching
    up as the plan turns."""
    tau = 0.2
    sink, reports = cruise(plan, cells_a_step, tau, lambda report, _: report.step == 12,
                           stall=(2, stalled_steps * tau))
    assert legs_off_the_plan(sink, plan) == []
    assert cells_sent_to(sink, plan) == list(plan.cells[1:])
    assert max(r.behind for r in reports) >= 1  # a cell it had no time to reach was kept
    assert reports[-1].behind == 0 and FRAME.locate(sink.here).cell == plan.cells[-1]


ZIGZAG = Trajectory(2, ((0, 0, 0), (1, 0, 0), (2, 0, 0), (2, 1, 0), (2, 2, 0), (3, 2, 0), (4, 2, 0), (4, 3, 0)))


def test_a_stalled_process_records_every_cell_its_vehicle_went_through_on_the_way_back() -> None:
    """Back from a stall, the vehicle flies the cells it missed at 2 cells a step: two samples a step
    apart find it more than a cell apart. The cells telemetry saw in between go with the record
    (``via``), so the audit sees where it went, and finds no jump."""
    samples: list[Sample] = []
    cruise(LONG, 2.0, 0.2, lambda report, _: report.step == 12, stall=(2, 3.5 * 0.2), lateness_s=0.05,
           samples=samples)
    records, before = [], None
    for s in samples:
        assert s.actual is not None
        via = went_through(s.passed, before, s.actual)
        records.append(json.loads(record_line(s.step, "d0", s.actual, s.planned, 1, via)))
        before = s.actual
    assert any("via" in r for r in records), records  # the catch-up crossed cells between two samples
    result = audit(WS, records)
    assert not result.jumps and result.safe, (result.jumps, records)


@pytest.mark.parametrize("cells_a_step", [0.4, 0.5])
def test_a_slow_vehicle_turns_in_the_plans_cells(cells_a_step: float) -> None:
    """No stall, but a vehicle slower than a cell a step: at each turn it is still short of the
    corner when the next cell comes. Sent straight there it would cut the corner; it must fly
    through the corner first (late, rather than off the path)."""
    def done(report: StepReport, sink: CruisingSink) -> bool:
        return report.step >= 12 and not report.behind and FRAME.locate(sink.here).cell == ZIGZAG.cells[-1]

    sink, reports = cruise(ZIGZAG, cells_a_step, 0.1, done, check_hz=100.0)
    assert legs_off_the_plan(sink, ZIGZAG) == []
    # The cells it was sent to, in order (a check late under load may aim it at a second point of a cell).
    assert cells_sent_to(sink, ZIGZAG) == list(ZIGZAG.cells[1:])
    assert max(r.behind for r in reports) >= 1  # the corner was kept on its route


STRAIGHT = Trajectory(2, tuple((x, 0, 0) for x in range(6)))


def test_a_vehicle_behind_on_a_straight_line_is_sent_one_cell_ahead_at_most() -> None:
    """Short of its cell on a straight line (one cell behind, then two), a vehicle is sent on to the
    cell after the one it is in, never further: sent at its target it would speed through cells that
    a peer behind it was told it had left long ago, and jump cells between two samples."""
    tau = 0.3
    seen: list[tuple[StepReport, Cell | None]] = []

    def record(report: StepReport, sink: CruisingSink) -> bool:
        seen.append((report, FRAME.locate(sink.here).cell))
        return report.step == 14

    sink, _ = cruise(STRAIGHT, 0.6, tau, record, check_hz=100.0)
    assert max(r.target[0] - here[0] for r, here in seen if here is not None) >= 2  # it fell behind
    for start, end in sink.legs:  # every setpoint, from where the vehicle was when it went out
        assert moves(cell_of(start), cell_of(end)) <= 1, (start, end)
    assert cells_sent_to(sink, STRAIGHT) == list(STRAIGHT.cells[1:])


@pytest.mark.parametrize("cells_a_step", [2.0, 1.0])
def test_each_step_is_sampled_lambda_after_its_boundary_with_how_late_the_vehicle_came(cells_a_step: float) -> None:
    """A vehicle swept across each cell of a straight line waits short of the face to the next
    (SWEEP_SHORT of a step, at a cell a step) until the next sweep begins at the boundary, then
    crosses it: every sample, lambda after the boundary, saw it in the step's cell, and says how late
    it came, the gap over its speed."""
    tau = 0.3
    samples: list[Sample] = []
    cruise(STRAIGHT, cells_a_step, tau, lambda report, _: report.step == 10, check_hz=200.0,
           lateness_s=0.15, samples=samples)
    moving = [s for s in samples if 4 <= s.step <= 7]  # under way: the first move starts at a centre
    assert [s.step for s in samples] == list(range(samples[0].step, samples[0].step + len(samples)))
    assert [(s.planned, s.actual) for s in moving] == [(STRAIGHT.at(s.step), STRAIGHT.at(s.step)) for s in moving]
    late = SWEEP_SHORT * tau / cells_a_step
    for s in moving:
        assert s.late_s is not None and late - 0.01 <= s.late_s <= late + 0.04, s


def test_a_vehicle_not_in_its_cell_lambda_after_the_boundary_is_sampled_late() -> None:
    """At 0.4 cells a step the vehicle falls behind: lambda after a boundary it is still short of
    the step's cell, and the sample says so (no lateness) with where it is."""
    samples: list[Sample] = []
    cruise(STRAIGHT, 0.4, 0.2, lambda report, _: report.step == 9, check_hz=100.0, lateness_s=0.1,
           samples=samples)
    behind = [s for s in samples if s.step >= 4]
    assert behind and all(s.late_s is None and s.actual != s.planned for s in behind)


def test_an_arrival_counts_when_telemetry_reported_it_not_when_a_stalled_loop_looked() -> None:
    """A loaded process looks 0.4 s after the boundary; the vehicle's position, reported 0.05 s after
    it, already puts it in the step's cell: it was 0.05 s late, not 0.4 s (a suite under load raised
    late alarms for vehicles on time)."""
    executor = PlanExecutor((0, 0, 0))
    executor.start(Trajectory(1, ((0, 0, 0), (1, 0, 0))))
    reported = FakeVehicle(FRAME, (1, 0, 0), at=100.05)  # on the link's clock
    loop = SetpointLoop(reported, FRAME, executor, 0.0, 1.0, lambda: 10.4, lateness_s=0.3,
                        link_clock=lambda: 100.4)
    for step in range(3):
        loop.take(step, 10.0 if step == 2 else step - 10.0)
    sample = loop.sample(2)
    assert sample is not None and sample.late_s == pytest.approx(0.05)


def test_the_first_sample_passes_no_cell_the_vehicle_left_before_the_first_step() -> None:
    """The link kept positions from before the loop began (the climb, a hover elsewhere): they are no
    step's, and the first record must not say its vehicle passed them."""
    executor = PlanExecutor((0, 0, 0))
    vehicle = FakeVehicle(FRAME)
    vehicle.over((3, 0, 0), at=1.0)
    vehicle.over((0, 0, 0), at=2.0)
    loop = SetpointLoop(vehicle, FRAME, executor, 0.0, 1.0, lambda: 0.0, lateness_s=0.3, link_clock=lambda: 2.5)
    loop.take(0, 0.0)
    sample = loop.sample(0)
    assert sample is not None and sample.passed == ()


def test_a_sample_taken_late_passes_only_the_cells_reported_before_it_was_due() -> None:
    """A loaded process samples step 2 at 2.4 s, 0.1 s after it was due: the vehicle reported (2,0,0)
    since, on its way on; that cell is the next sample's, not this one's (a bench of 32 drones was
    recorded two cells ahead of its own records)."""
    executor = PlanExecutor((0, 0, 0))
    executor.start(Trajectory(1, ((0, 0, 0), (1, 0, 0), (2, 0, 0))))
    vehicle = FakeVehicle(FRAME, (0, 0, 0), at=100.0)
    now = [0.0]
    loop = SetpointLoop(vehicle, FRAME, executor, 0.0, 1.0, lambda: now[0], lateness_s=0.3,
                        link_clock=lambda: 100.0 + now[0])
    for step in range(3):
        loop.take(step, float(step))
    for step in range(2):
        loop.sample(step)
    vehicle.over((1, 0, 0), at=102.2)
    vehicle.over((2, 0, 0), at=102.35)
    now[0] = 2.4
    late = loop.sample(2)
    assert late is not None and late.passed == ((1, 0, 0),)


@pytest.mark.parametrize("layer, on_time", [(0, True), (1, False)])
def test_a_vehicle_climbing_under_its_lowest_layer_cell_is_in_it(layer: int, on_time: bool) -> None:
    """Below the grid (still climbing, or coming down to land) a vehicle is in its own column, where it
    meets no drone, as in the cell over it: on time there, as the flight record has it (under load the
    suite's drones took off after their plans began, and were called late). Under a higher cell it is not."""
    ws = Workspace.build(size=(4, 4, 2), cell_size_m=2.0, tau_s=1.0)
    frame = GeoFrame(ws)
    cell: Cell = (1, 1, layer)
    climbing = Ned(frame.cell_to_ned(cell).north, frame.cell_to_ned(cell).east, -0.3)
    vehicle = FakeVehicle(frame, at=0.1)
    vehicle.where = climbing

    executor = PlanExecutor(cell)
    loop = SetpointLoop(vehicle, frame, executor, 0.0, 1.0, lambda: 0.2, lateness_s=0.3)
    loop.take(0, 0.0)
    sample = loop.sample(0)
    assert sample is not None and (sample.late_s is not None) == on_time, sample


def test_a_vehicle_still_climbing_when_its_plan_turns_flies_the_turns_cell_first() -> None:
    """Still under the grid two steps into its plan (a late take-off), a vehicle over its start cell is
    two cells, across a corner, from its new target: it is sent through the cell between (the one its
    plan left), not across the corner, and on once over that cell, though still under the grid."""
    ws = Workspace.build(size=(4, 4, 1), cell_size_m=2.0, tau_s=1.0)
    frame = GeoFrame(ws)
    vehicle = FakeVehicle(frame, at=0.0)
    now = [0.0]

    def climbing_over(cell: Cell) -> Ned:
        centre = frame.cell_to_ned(cell)
        return Ned(centre.north, centre.east, -0.3)

    vehicle.where = climbing_over((1, 1, 0))
    executor = PlanExecutor((1, 1, 0))
    executor.start(Trajectory(0, ((1, 1, 0), (1, 2, 0), (2, 2, 0))))
    loop = SetpointLoop(vehicle, frame, executor, 0.0, 1.0, lambda: now[0])
    for step in range(3):
        now[0] = float(step)
        loop.take(step, now[0])
    assert (loop.target, loop.aim) == ((2, 2, 0), (1, 2, 0))
    vehicle.where = climbing_over((1, 2, 0))
    assert loop.advance() and loop.aim == (2, 2, 0)


def test_a_tick_that_takes_time_does_not_date_the_arrival_it_looks_for_too_early() -> None:
    """The drone's tick (its planner) takes 0.2 s at boundary 2; the vehicle reached (1,0,0) 0.15 s
    into the step. A look dated before the tick put the arrival on the boundary: lateness lost, and
    the (0,0,0) positions before it went to the next record, as if the vehicle went back (two
    separation findings at 64 drones)."""
    executor = PlanExecutor((0, 0, 0))
    executor.start(Trajectory(1, ((0, 0, 0), (1, 0, 0), (2, 0, 0))))
    vehicle = FakeVehicle(FRAME, (0, 0, 0), at=100.0)
    now = [0.0]

    def slow_tick(step: int) -> Sequence[object]:
        now[0] += 0.2
        return executor.tick(step)

    loop = SetpointLoop(vehicle, FRAME, executor, 0.0, 1.0, lambda: now[0], tick=slow_tick, lateness_s=0.3,
                        link_clock=lambda: 100.0 + now[0])
    for step in range(2):
        now[0] = float(step)
        loop.take(step, float(step))
        assert loop.sample(step) is not None
    vehicle.over((0, 0, 0), at=102.1)
    vehicle.over((1, 0, 0), at=102.15)
    now[0] = 2.2
    loop.take(2, 2.0)
    arrived = loop.sample(2)
    vehicle.over((2, 0, 0), at=103.1)
    now[0] = 3.1
    loop.take(3, 3.0)
    next_one = loop.sample(3)
    assert arrived is not None and arrived.late_s == pytest.approx(0.15)
    assert arrived.passed[-2:] == ((0, 0, 0), (1, 0, 0))
    assert next_one is not None and went_through(next_one.passed, (1, 0, 0), (2, 0, 0)) == ()


class ArduCopterSink:
    """The fake ArduCopter's physics (:class:`~fleet.sim.physics.Body`) as a setpoint sink, on a clock the
    test moves: each aim is flown as its stream would carry it, a message every 20 ms."""

    def __init__(self, frame: GeoFrame, start: Cell, limits: Limits, clock: Callable[[], float]) -> None:
        self.frame, self.clock, self.body = frame, clock, Body(limits)
        centre = frame.cell_to_ned(start)
        self.body.north, self.body.east = centre.north, centre.east
        self.body.stop()
        self.body.down = centre.down
        self.at = clock()
        self.aim = Aim(centre, None, self.at)
        self.trail = Trail()

    def fly(self) -> None:
        while self.at + 0.02 <= self.clock() + 1e-9:
            self.at += 0.02
            motion = self.aim.at(self.at)
            where, v = motion.where, motion.velocity or Ned(0.0, 0.0, 0.0)
            self.body.step(Target(where.north, where.east, where.down, v.north, v.east, v.down), 0.02)
            self.trail.add(Position(Ned(self.body.north, self.body.east, self.body.down), self.at))

    async def send_position_target(self, target: Ned, sweep: Sweep | None = None) -> None:
        self.fly()
        self.aim = Aim(target, sweep, self.clock())

    def last_position(self) -> Position | None:
        self.fly()
        return Position(Ned(self.body.north, self.body.east, self.body.down), self.at)

    def positions_since(self, at: float) -> list[Position]:
        self.fly()
        return self.trail.since(at)


#: Straight on, a turn, a staircase (a diagonal), a wait, back the way it came, a turn into a stop.
EVERY_KIND = Trajectory(1, (
    *((2, y, 0) for y in range(2, 7)), *((x, 6, 0) for x in range(3, 6)),
    *itertools.chain.from_iterable(((5 + i, 7 + i, 0), (6 + i, 7 + i, 0)) for i in range(4)),
    (9, 10, 0), (9, 10, 0), (9, 10, 0), (9, 11, 0), (9, 12, 0), (9, 11, 0), (9, 10, 0), (8, 10, 0), (8, 10, 0)))


def test_arducopter_at_the_bench_limits_flies_every_kind_of_step_in_its_cells_within_lambda() -> None:
    """The fake ArduCopter (its shaping measured against SITL), set to a workspace's vehicle limits as
    sim-vehicle sets it, flies a plan of 1 m cells at tau 0.5 s: each step's cell is reached within the
    lambda the workspace derives from those limits, and never a cell the plan does not have."""
    quick = VehicleLimits(speed_m_s=20.0, accel_m_s2=10.0, jerk_m_s3=40.0)  # the coordination bench's
    ws = Workspace.build(size=(14, 14, 1), cell_size_m=1.0, tau_s=0.5, vehicle=quick)
    frame = GeoFrame(ws)
    limits = starting_limits(VehicleConfig(params=limit_params(ws.vehicle, ARDUPILOT)))
    now = [0.0]
    sink = ArduCopterSink(frame, EVERY_KIND.cells[0], limits, lambda: now[0])
    executor = PlanExecutor(EVERY_KIND.cells[0])
    executor.start(EVERY_KIND)
    loop = SetpointLoop(sink, frame, executor, 0.0, ws.tau_s, lambda: now[0], lateness_s=ws.lateness_s)
    samples: list[Sample] = []

    async def fly() -> None:
        for step in range(EVERY_KIND.end_step + 4):
            loop.take(step, now[0])
            await loop.send()
            for tick in range(1, 11):  # looks at 20 Hz; each step sampled lambda after its boundary
                now[0] = step * ws.tau_s + tick * ws.tau_s / 10
                loop.look()
                if loop.advance():
                    await loop.send()
                while len(samples) <= step and now[0] >= len(samples) * ws.tau_s + ws.lateness_s - 1e-9:
                    sample = loop.sample(len(samples))
                    assert sample is not None
                    samples.append(sample)

    asyncio.run(fly())
    flown = [s for s in samples if s.step <= EVERY_KIND.end_step]
    assert len(flown) == EVERY_KIND.end_step + 1
    for s in flown:
        assert s.actual == s.planned and s.late_s is not None and s.late_s <= ws.lateness_s, s
        assert set(s.passed) <= set(EVERY_KIND.cells), s
    assert max(s.late_s or 0.0 for s in flown) > 0.05  # it was late a little: the physics flew it
