"""The setpoint loop: boundaries on the clock, one setpoint each (the link streams it), lag detection."""

from __future__ import annotations

import asyncio
import json
import math
import time
from collections.abc import Callable, Sequence

import pytest

from drona_gcs.audit import audit, moves, record_line, went_through
from drona_gcs.geo import GeoFrame, Ned
from drona_gcs.motion import Trajectory
from drona_gcs.stack.executor import Completed, ExecutorAction, PlanExecutor, Setpoint
from drona_gcs.workspace import Cell, Workspace
from fleet.setpoint_loop import Sample, SetpointLoop, StepReport
from fleet.vehicle.link import Position
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


def aimed(step: int) -> Ned:
    """TRAJ goes straight on through (1,0,0) at step 3: the vehicle is sent 0.3 of a cell past its
    centre (4 m cells: 1.2 m east); elsewhere to the centre of the step's cell."""
    centre = FRAME.cell_to_ned(TRAJ.at(step))
    return Ned(centre.north, centre.east + 1.2, centre.down) if step == 3 else centre


def test_boundaries_follow_the_timed_trajectory() -> None:
    reports, actions, sink, epoch = asyncio.run(fly(follow=True))
    assert [r.step for r in reports] == list(range(7))
    assert [r.target for r in reports] == [TRAJ.at(k) for k in range(7)]
    assert [a for a in actions if isinstance(a, Completed)] == [Completed(TRAJ)]
    assert max(r.late_s for r in reports) < 0.05  # generous for a loaded CI machine
    assert not any(r.lagging for r in reports[1:])
    # Every boundary's target is sent once, at the boundary: the link repeats it (a second stream
    # here would double the traffic to the vehicle).
    for k in range(1, 6):
        start, end = epoch + k * 0.1, epoch + (k + 1) * 0.1
        between = [(t, ned) for t, ned in sink.sent if start <= t < end]
        assert [ned for _, ned in between] == [aimed(k)], f"step {k}: {between}"
        assert between[0][0] - start < 0.05


def test_a_drone_that_does_not_follow_is_flagged_lagging() -> None:
    reports, _, _, _ = asyncio.run(fly(follow=False))
    # It stays at (0,0,0): from the step after it should have reached (2,0,0), it lags 8 m > 4 m.
    lagging = [r.step for r in reports if r.lagging]
    assert lagging and lagging[0] == 5
    assert reports[5].actual == (0, 0, 0) and reports[5].error_m == 8.0


class CruisingSink(FakeVehicle):
    """The shared fake vehicle, flying at ``speed`` m/s straight at the last setpoint and stopping on it;
    it records the straight legs it flew (where it was when a new setpoint came, and that setpoint)."""

    def __init__(self, loop: asyncio.AbstractEventLoop, start: Ned, speed: float) -> None:
        super().__init__(FRAME, at=loop.time(), clock=loop.time)
        self.speed, self.here, self.aim = speed, start, start
        self.legs: list[tuple[Ned, Ned]] = []

    def _move(self) -> None:
        now = self.clock()
        gap = math.dist((self.here.north, self.here.east), (self.aim.north, self.aim.east))
        step = min(gap, self.speed * (now - self.at))
        if gap > 0:
            f = step / gap
            self.here = Ned(self.here.north + f * (self.aim.north - self.here.north),
                            self.here.east + f * (self.aim.east - self.here.east), self.aim.down)
        self.where, self.at = self.here, now

    async def send_position_target(self, target: Ned) -> None:
        self._move()
        if target != self.aim:
            self.legs.append((self.here, target))
        self.aim = target
        await super().send_position_target(target)

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
    assert [FRAME.locate(end).cell for _, end in sink.legs] == list(plan.cells[1:])
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
    sent = [FRAME.locate(end).cell for _, end in sink.legs]
    assert [c for i, c in enumerate(sent) if i == 0 or c != sent[i - 1]] == list(ZIGZAG.cells[1:])
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
    assert [FRAME.locate(end).cell for _, end in sink.legs] == list(STRAIGHT.cells[1:])


@pytest.mark.parametrize(("cells_a_step", "lateness_s", "late_steps"), [
    (2.0, 0.15, 0.1),  # at its aim by the next boundary: a fifth of a cell to the next; sampled within the step
    (1.0, 0.36, 0.5),  # never quite at its aim: half a cell to the next; sampled in the next step
])
def test_each_step_is_sampled_lambda_after_its_boundary_with_how_late_the_vehicle_came(
        cells_a_step: float, lateness_s: float, late_steps: float) -> None:
    """A vehicle that flies straight at its setpoint (0.3 of a cell past the centre, on a straight
    line) enters each cell soon after the boundary: every sample, lambda after the boundary, saw it
    in the step's cell, and says how late it came."""
    tau = 0.3
    samples: list[Sample] = []
    cruise(STRAIGHT, cells_a_step, tau, lambda report, _: report.step == 10, check_hz=200.0,
           lateness_s=lateness_s, samples=samples)
    moving = [s for s in samples if 4 <= s.step <= 7]  # under way: the first move starts at a centre
    assert [s.step for s in samples] == list(range(samples[0].step, samples[0].step + len(samples)))
    assert [(s.planned, s.actual) for s in moving] == [(STRAIGHT.at(s.step), STRAIGHT.at(s.step)) for s in moving]
    for s in moving:
        assert s.late_s is not None and late_steps * tau - 0.02 <= s.late_s <= late_steps * tau + 0.06, s


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
