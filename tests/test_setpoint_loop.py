"""The setpoint loop: boundaries on the clock, a steady stream between them, lag detection."""

from __future__ import annotations

import asyncio
import itertools
from collections.abc import Sequence

from drona_gcs.geo import GeoFrame, Ned
from drona_gcs.motion import Trajectory
from drona_gcs.stack.executor import Completed, ExecutorAction, PlanExecutor
from drona_gcs.workspace import Workspace
from fleet.executor import SetpointLoop, StepReport
from fleet.vehicle.link import Position

WS = Workspace.build(size=(6, 4, 1), cell_size_m=4.0, tau_s=0.1)
FRAME = GeoFrame(WS)
TRAJ = Trajectory(2, ((0, 0, 0), (1, 0, 0), (2, 0, 0), (2, 1, 0)))


class RecordingSink:
    """Records every target with its time; reports a position that follows the targets or not."""

    def __init__(self, clock: asyncio.AbstractEventLoop, follow: bool) -> None:
        self.loop, self.follow = clock, follow
        self.sent: list[tuple[float, Ned]] = []
        self.position = Position(FRAME.cell_to_ned((0, 0, 0)), 0.0)

    async def send_position_target(self, target: Ned) -> None:
        self.sent.append((self.loop.time(), target))
        if self.follow:
            self.position = Position(target, self.loop.time())

    def last_position(self) -> Position | None:
        return self.position


async def fly(follow: bool, steps: int = 7, rate: float = 40.0) -> tuple[list[StepReport], list[ExecutorAction],
                                                                       RecordingSink, float]:
    loop = asyncio.get_running_loop()
    sink = RecordingSink(loop, follow)
    executor = PlanExecutor((0, 0, 0))
    executor.start(TRAJ)
    epoch = loop.time() + 0.05
    reports: list[StepReport] = []
    actions: list[ExecutorAction] = []
    stop = asyncio.Event()

    def on_step(report: StepReport, done: Sequence[ExecutorAction]) -> None:
        reports.append(report)
        actions.extend(done)
        if len(reports) == steps:
            stop.set()

    runner = SetpointLoop(sink, FRAME, executor, epoch, 0.1, loop.time, rate_hz=rate)
    await asyncio.wait_for(runner.run(on_step, stop), timeout=10)
    return reports, actions, sink, epoch


def test_boundaries_follow_the_timed_trajectory() -> None:
    reports, actions, sink, epoch = asyncio.run(fly(follow=True))
    assert [r.step for r in reports] == list(range(7))
    assert [r.target for r in reports] == [TRAJ.at(k) for k in range(7)]
    assert [a for a in actions if isinstance(a, Completed)] == [Completed(TRAJ)]
    assert max(r.late_s for r in reports) < 0.05  # generous for a loaded CI machine
    assert not any(r.lagging for r in reports[1:])
    # Every boundary's target is sent at once, then streamed until the next one.
    for k in range(1, 6):
        start, end = epoch + k * 0.1, epoch + (k + 1) * 0.1
        between = [t for t, ned in sink.sent if start <= t < end and ned == FRAME.cell_to_ned(TRAJ.at(k))]
        assert len(between) >= 2, f"step {k}: {len(between)} setpoints"
        gaps = [b - a for a, b in itertools.pairwise(between)]
        assert max(gaps) <= 0.1  # at least 10 Hz


def test_a_drone_that_does_not_follow_is_flagged_lagging() -> None:
    reports, _, _, _ = asyncio.run(fly(follow=False))
    # It stays at (0,0,0): from the step after it should have reached (2,0,0), it lags 8 m > 4 m.
    lagging = [r.step for r in reports if r.lagging]
    assert lagging and lagging[0] == 5
    assert reports[5].actual == (0, 0, 0) and reports[5].error_m == 8.0
