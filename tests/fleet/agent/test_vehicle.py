"""The agent's take-off and landing supervisor against the fake vehicle (real MAVLink on 127.0.0.1).

A drone told to land and then, mid-descent, given a new plan must climb back at once: the plan's
lead time covers a take-off, not the rest of a descent first.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from typing import Any

import pytest

from drona_gcs.geo import Ned
from fleet.agent.vehicle import VehicleSupervisor
from fleet.clock import cancel_all
from fleet.vehicle.link import LandedState, Sweep, Telemetry, VehicleLink
from tests.fakes.autopilot import SPEEDUP, connected, fake_vehicle, run
from tests.fakes.vehicle import FakeVehicle

FLIGHT_ALT_M = 8.0


@contextlib.asynccontextmanager
async def supervising(personality: str, stream_hz: float = 10.0) -> AsyncIterator[
        tuple[VehicleLink, VehicleSupervisor, list[str | None], list[Any]]]:
    """A fake vehicle and its supervisor, with setpoints to ``target[0]`` streamed as the agent's
    setpoint loop does, whatever the supervisor does; the alarms it raises are kept."""
    async with fake_vehicle(personality, "udp") as fake, connected("pymavlink", fake, stream_hz=stream_hz) as link:
        await link.wait_ready(timeout=5)
        alarms: list[str | None] = []
        target: list[Any] = [Ned(0.0, 0.0, -FLIGHT_ALT_M)]
        supervisor = VehicleSupervisor("d1", link, FLIGHT_ALT_M, alarms.append, lambda: target[0], arrival_m=0.5)

        async def stream() -> None:
            while True:  # to target[0], or along a sweep given after it (from where it starts)
                await link.send_position_target(*(target[1:] if len(target) > 1 else (target[0], None)))
                await asyncio.sleep(0.05)

        runner, streamer = asyncio.create_task(supervisor.run()), asyncio.create_task(stream())
        try:
            yield link, supervisor, alarms, target
        finally:
            supervisor.stop()
            await asyncio.wait_for(runner, 5)
            await cancel_all([streamer])


@pytest.mark.parametrize("personality", ["ardupilot", "px4"])
def test_a_plan_during_the_descent_turns_the_landing_into_a_climb(personality: str) -> None:
    async def scenario() -> None:
        async with supervising(personality) as (link, supervisor, alarms, _):
            supervisor.want_airborne(True)
            await asyncio.wait_for(supervisor.reached.wait(), 15)
            await link.wait_until(lambda t: (t.height_m or 0.0) > FLIGHT_ALT_M - 0.5, 10, "the flight altitude")

            supervisor.want_airborne(False)
            await link.wait_until(lambda t: (t.height_m or FLIGHT_ALT_M) < FLIGHT_ALT_M - 2.0, 10, "the descent")
            lowest = FLIGHT_ALT_M

            def track(t: Telemetry) -> bool:
                nonlocal lowest
                lowest = min(lowest, t.height_m if t.height_m is not None else lowest)
                assert t.landed is not LandedState.ON_GROUND, "it came down to the ground first"
                return supervisor.reached.is_set() and (t.height_m or 0.0) > FLIGHT_ALT_M - 0.5

            supervisor.want_airborne(True)  # a new plan, mid-descent
            await link.wait_until(track, 15, "the climb back to the flight altitude")
            assert lowest > 0.5, f"it went down to {lowest:.2f} m before climbing back"
            assert link.telemetry().armed and supervisor.settled
            assert [a for a in alarms if a is not None] == []

    run(scenario)


def test_a_vehicle_still_moving_over_its_landing_cell_is_landed_once_it_is_all_but_still() -> None:
    """LAND brakes to a stop from wherever it starts. A plan's last step slows its vehicle down to stop
    at the cell's centre, and the vehicle, trailing, passes within the arrival radius still moving:
    sent down then, it came down further on. The supervisor waits for it to be still."""
    async def scenario() -> None:
        async with supervising("ardupilot") as (link, supervisor, _, target):
            supervisor.want_airborne(True)
            await asyncio.wait_for(supervisor.reached.wait(), 15)
            await link.wait_until(lambda t: (t.height_m or 0.0) > FLIGHT_ALT_M - 0.5, 10, "the flight altitude")
            here = link.last_position()
            assert here is not None
            start, seconds = Ned(here.ned.north, here.ned.east, -FLIGHT_ALT_M), 1.0 / SPEEDUP
            # 3 m north in a simulated second, slowing evenly to a stop there (in the ground station's time)
            target[0] = Ned(start.north + 3.0, start.east, -FLIGHT_ALT_M)
            sweep = Sweep(Ned(6.0 / seconds, 0.0, 0.0), seconds, Ned(-6.0 / seconds**2, 0.0, 0.0))
            target += [start, sweep]
            supervisor.want_airborne(False)  # at once: the landing waits for the arrival
            await asyncio.wait_for(supervisor.reached.wait(), 30)
            down = await link.wait_until(lambda t: t.landed is LandedState.ON_GROUND, 15, "the touchdown")
            assert down.position is not None
            assert abs(down.position.ned.north - target[0].north) < 0.2, (down.position.ned, target[0])

    run(scenario)


@pytest.mark.parametrize("personality", ["ardupilot", "px4"])
def test_a_vehicle_down_by_itself_raises_the_question_and_needs_no_landing(personality: str) -> None:
    """A failsafe (or a pilot) lands the vehicle under a drone the stack still flies: the supervisor
    says so, and a landing asked for afterwards is already done, wherever the plan's cell is."""
    async def scenario() -> None:
        async with supervising(personality) as (link, supervisor, alarms, target):
            supervisor.want_airborne(True)
            await asyncio.wait_for(supervisor.reached.wait(), 15)
            assert supervisor.settled and not supervisor.grounded_by_itself()

            await link.land()  # not the supervisor's doing
            await link.wait_until(lambda t: not t.armed and t.landed is LandedState.ON_GROUND, 10, "touchdown")
            assert supervisor.grounded_by_itself()

            target[0] = Ned(6.0, 6.0, -FLIGHT_ALT_M)  # the plan flew on meanwhile
            supervisor.want_airborne(False)
            await asyncio.wait_for(supervisor.reached.wait(), 3)
            assert not supervisor.airborne and not supervisor.grounded_by_itself()
            assert [a for a in alarms if a is not None] == []

    run(scenario)


@pytest.mark.parametrize("personality", ["ardupilot", "px4"])
def test_a_vehicle_just_taken_off_is_not_down_by_itself(personality: str) -> None:
    """The landed state comes at half the position rate (2 Hz with ``--telemetry-hz`` 4, as the
    coordination bench runs its agents): a vehicle climbs past half a metre before it says it left
    the ground. Taken up, it must not look grounded by itself on the last report from before the
    take-off: the agent would hand its mail back and ground it for good."""
    async def scenario() -> None:
        async with supervising(personality, stream_hz=1.0) as (link, supervisor, alarms, _):
            for _ in range(3):  # one take-off can win the race by luck
                supervisor.want_airborne(True)
                await asyncio.wait_for(supervisor.reached.wait(), 15)
                assert supervisor.settled
                assert not supervisor.grounded_by_itself(), f"just taken off, yet down: {link.telemetry()}"
                supervisor.want_airborne(False)
                await asyncio.wait_for(supervisor.reached.wait(), 30)
            assert [a for a in alarms if a is not None] == []

    run(scenario)


def guided_climbs(vehicle: FakeVehicle) -> None:
    """ArduCopter in GUIDED while the link waits: it climbs to the setpoints, unless it counts itself on the
    ground."""
    if vehicle.landed is not LandedState.ON_GROUND:
        vehicle.landed, vehicle.height_m = LandedState.IN_AIR, 2.0


def arducopter(landed: LandedState, height_m: float = 0.3, refuses: bool = True) -> FakeVehicle:
    """An ArduCopter link in GUIDED, armed, reporting ``landed`` at ``height_m`` above home. Its
    NAV_TAKEOFF is refused in the air (as ArduCopter refuses it), on the ground too if ``refuses``,
    or climbs; told nothing else it climbs to the setpoints, unless it counts itself on the ground."""
    vehicle = FakeVehicle(on_wait=guided_climbs)
    vehicle.landed, vehicle.height_m = landed, height_m
    if refuses:
        vehicle.refuse["NAV_TAKEOFF"] = 4  # MAV_RESULT_FAILED
    return vehicle


def launch_once(link: FakeVehicle) -> tuple[list[str | None], bool]:
    """The supervisor asked to fly once: the alarms it raised, and whether it ended airborne."""
    async def scenario() -> tuple[list[str | None], bool]:
        alarms: list[str | None] = []
        supervisor = VehicleSupervisor("d1", link, FLIGHT_ALT_M, alarms.append,
                                       lambda: Ned(0.0, 0.0, -FLIGHT_ALT_M), arrival_m=0.5)
        supervisor.want_airborne(True)
        runner = asyncio.create_task(supervisor.run())
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(supervisor.reached.wait(), 0.5)
        supervisor.stop()
        await asyncio.wait_for(runner, 5)
        return alarms, supervisor.airborne

    return asyncio.run(scenario())


@pytest.mark.parametrize("landed, refused", [(LandedState.LANDING, False), (LandedState.ON_GROUND, True)])
def test_a_takeoff_refused_in_the_air_is_no_failure_and_on_the_ground_it_is(landed: LandedState,
                                                                            refused: bool) -> None:
    """A landing called back just above the ground: telemetry still says LANDING at 0.3 m, so the
    supervisor asks for a take-off, which ArduCopter refuses in the air. The vehicle climbs anyway
    (GUIDED): no alarm, no retry a second later. On the ground, the refusal is an alarm."""
    link = arducopter(landed, refuses=refused)
    alarms, airborne = launch_once(link)
    assert link.commands == ["FOLLOW_SETPOINTS", "NAV_TAKEOFF"]
    if refused:
        assert not airborne and alarms == ["vehicle: cannot take off: NAV_TAKEOFF rejected with result 4"]
    else:
        assert airborne and [a for a in alarms if a is not None] == []


def test_a_vehicle_on_the_ground_above_home_still_gets_its_takeoff() -> None:
    """On the ground but 0.8 m above home (ground higher than home, a drifted barometer): ArduCopter
    lifts off in GUIDED only once told to take off. Taken for flying by its height, it was never
    told, and the climb waited out its timeout."""
    link = arducopter(LandedState.ON_GROUND, height_m=0.8, refuses=False)
    alarms, airborne = launch_once(link)
    assert link.commands == ["FOLLOW_SETPOINTS", "NAV_TAKEOFF"]
    assert airborne and [a for a in alarms if a is not None] == []
