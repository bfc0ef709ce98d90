"""Contract tests of the vehicle link against the fake vehicle: a whole flight, setpoints, and a link in a
workspace frame (refusals, lost streams and silence: test_link_failures.py).

Every backend in :data:`~tests.fakes.autopilot.BACKENDS` runs the same scenarios against the fake
vehicle of :mod:`tests.fakes.autopilot` (both personalities, UDP, TCP and serial). Simulated time runs
``SPEEDUP`` times faster (a 20 Hz setpoint stream is 2 Hz simulated, PX4's minimum). Every wait is
bounded and each scenario has an overall deadline.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import itertools
import math
import statistics
import time
from collections.abc import Callable

import pytest
from pymavlink import mavutil

from drona_gcs.geo import GeoPoint, Ned
from fleet.clock import cancel_all
from fleet.sim.fleet import placements
from fleet.sim.mav import mavlink2
from fleet.vehicle.link import Autopilot, LandedState, Position, Sweep, Telemetry, VehicleLink, not_ready
from fleet.vehicle.policy import in_air
from tests.fakes.autopilot import SPEEDUP, connected, fake_vehicle, run
from tests.fleet.vehicle.link_helpers import backends, personalities, transports


async def following_5_m_up(link: VehicleLink) -> None:
    """Ready, armed, 5 m up and in the mode that follows setpoints."""
    await link.wait_ready(timeout=5)
    await link.arm()
    await link.takeoff(5.0)
    await link.wait_until(lambda t: (t.height_m or 0) > 4.7, 5, "5 m up")
    await link.follow_setpoints()


def near(target: Ned, tolerance: float) -> Callable[[Telemetry], bool]:
    def check(t: Telemetry) -> bool:
        p = t.position
        return p is not None and math.dist((p.ned.north, p.ned.east, p.ned.down),
                                           (target.north, target.east, target.down)) < tolerance
    return check


AUTOPILOTS = {"ardupilot": Autopilot.ARDUPILOT, "px4": Autopilot.PX4}
FOLLOW = {"ardupilot": "GUIDED", "px4": "OFFBOARD"}


# ------------------------------------------------------------------ contract: a whole flight
@backends
@personalities
@transports
def test_connect_arm_take_off_follow_setpoints_and_land(backend: str, personality: str, transport: str) -> None:
    async def scenario() -> None:
        async with fake_vehicle(personality, transport) as fake, connected(backend, fake) as link:
            await link.wait_ready(timeout=5)
            t = link.telemetry()
            assert t.autopilot is AUTOPILOTS[personality]
            assert not t.armed and t.battery_pct == 100 and t.battery_v is not None and t.battery_v > 16
            assert t.gps_fix >= 3 and t.global_position is not None and t.heartbeat_at is not None
            assert near(Ned(0, 0, 0), 0.05)(t)
            await link.wait_until(lambda t: t.landed is LandedState.ON_GROUND, 2, "the landed state")

            await link.arm()
            assert link.telemetry().armed
            await link.takeoff(5.0)
            await link.wait_until(lambda t: (t.height_m or 0) > 4.7, 5, "5 m up")
            await link.follow_setpoints()
            assert link.telemetry().mode == FOLLOW[personality]

            target = Ned(10.0, 5.0, -6.0)
            await link.send_position_target(target)
            await link.wait_until(near(target, 0.3), 5, "the target")
            t = link.telemetry()
            assert t.mode == FOLLOW[personality] and t.landed is LandedState.IN_AIR
            assert t.global_position is not None and abs(t.global_position.alt_m - 584.0 - 6.0) < 0.5

            await link.land()
            # Position and landed state come in different messages at different rates (as from a
            # real autopilot): the position may lag the landed state by a message.
            t = await link.wait_until(lambda t: not t.armed and t.landed is LandedState.ON_GROUND
                                      and t.position is not None and abs(t.position.ned.down) < 0.05,
                                      5, "touchdown on the ground")
            assert t.battery_pct is not None and t.battery_pct < 100  # the flight drew current
            await link.disarm()  # already disarmed on touchdown: acknowledged, nothing changes

    run(scenario)


@backends
def test_arducopter_gets_no_setpoint_from_arming_until_its_takeoff_is_over(backend: str) -> None:
    """ArduCopter in GUIDED leaves its take-off for position control at the first setpoint, and then
    stays on the ground. The agent's setpoint loop sends a target at every step boundary whatever the
    vehicle does: the link must hold them back until the take-off is over (IN_AIR), then stream."""
    async def scenario() -> None:
        async with fake_vehicle("ardupilot", "udp") as fake, connected(backend, fake) as link:
            await link.wait_ready(timeout=5)
            await link.follow_setpoints()
            target = Ned(3.0, 0.0, -6.0)

            async def setpoint_loop() -> None:
                while True:
                    await link.send_position_target(target)
                    await asyncio.sleep(0.05)

            loop = asyncio.create_task(setpoint_loop())
            try:
                await link.arm()
                await link.takeoff(6.0)
                await link.wait_until(in_air, 5, "the end of the take-off")
                assert (link.telemetry().height_m or 0.0) > 5.4
                await link.wait_until(near(target, 0.3), 5, "the setpoint, once in the air")
            finally:
                await cancel_all([loop])

    run(scenario)


@backends
@personalities
def test_a_landing_given_up_before_its_confirmation_does_not_outlive_follow_setpoints(
        backend: str, personality: str) -> None:
    """The agent abandons a landing when a new plan wants the drone back up. If the LAND was already
    sent, the last HEARTBEAT still shows the follow mode: switching back must not trust it, or the
    vehicle lands (and disarms) under a drone the stack believes is flying its plan."""
    async def scenario() -> None:
        async with fake_vehicle(personality, "udp") as fake, connected(backend, fake) as link:
            await following_5_m_up(link)
            here = Ned(0.0, 0.0, -5.0)
            await link.send_position_target(here)

            landing = asyncio.create_task(link.land())
            await asyncio.sleep(0)  # the LAND is on its way; its confirmation is not
            landing.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await landing
            assert link.telemetry().mode == FOLLOW[personality], "the mode changed before the test could ask"

            await link.follow_setpoints()
            await link.send_position_target(here)
            started = time.monotonic()
            while time.monotonic() - started < 1.0:  # 10 s simulated: a LAND would be well under way
                t = link.telemetry()
                assert t.mode == FOLLOW[personality] and t.armed, f"it left for {t.mode} (armed {t.armed})"
                await asyncio.sleep(0.05)
            assert near(here, 0.5)(link.telemetry())

    run(scenario)


def test_the_link_repeats_the_last_setpoint_at_its_rate_and_px4_stays_in_offboard() -> None:
    """The setpoint loop sends a target once per step boundary; the link keeps it coming at
    ``setpoint_hz``, or PX4 (a stream under 2 Hz) leaves OFFBOARD between boundaries."""
    async def scenario() -> None:
        async with fake_vehicle("px4", "udp") as fake, connected("pymavlink", fake, setpoint_hz=8.0) as link:
            await following_5_m_up(link)
            await link.send_position_target(Ned(0.0, 0.0, -5.0))
            await asyncio.sleep(1.2)  # twice the fake's offboard timeout (5 s simulated)
            assert link.telemetry().mode == "OFFBOARD"
        # What reached the vehicle: one setpoint every 1/8 s (simulated: SPEEDUP times that).
        times = list(fake.nodes[0].model.setpoint_times)
        gaps = [(b - a) / SPEEDUP for a, b in itertools.pairwise(times)]
        assert len(gaps) >= 5 and 0.09 < statistics.median(gaps) < 0.16, gaps

    run(scenario)


def test_a_target_sent_again_is_left_to_the_repeats_and_a_new_one_goes_at_once() -> None:
    """A drone at rest is sent the same target at every step boundary: the link repeats it anyway, so
    only a new target (or the first after the setpoints stopped) goes out at once."""
    async def scenario() -> None:
        # setpoint_hz 0.1: no repeat within the test
        async with fake_vehicle("ardupilot", "udp") as fake, connected("pymavlink", fake, setpoint_hz=0.1) as link:
            model = fake.nodes[0].model
            await following_5_m_up(link)
            heard, last = len(model.setpoint_times), None
            for target in (Ned(0.0, 0.0, -5.0),) * 4 + (Ned(1.0, 0.0, -5.0),) * 2:
                await link.send_position_target(target)
                if target != last:  # it arrives (within a bound) ...
                    for _ in range(100):
                        if len(model.setpoint_times) > heard:
                            break
                        await asyncio.sleep(0.02)
                await asyncio.sleep(0.2)  # ... and nothing more comes
                got, heard = len(model.setpoint_times) - heard, len(model.setpoint_times)
                assert got == (0 if target == last else 1), f"{got} setpoints for {target}"
                last = target

    run(scenario)


@backends
def test_a_sweep_is_streamed_as_a_target_moving_on_with_its_velocity_fed_forward(backend: str) -> None:
    """Sent along a sweep, an ArduCopter gets, at each message of the stream, where the sweep has got
    to and its velocity; once the sweep is over, its end, still. In real time: the fake moves a target
    on between two messages as ArduCopter does, by the velocity over simulated seconds."""
    async def scenario() -> None:
        async with fake_vehicle("ardupilot", "udp", speedup=1.0, spool_up_s=0.5) as fake, \
                connected(backend, fake) as link:
            model = fake.nodes[0].model
            await following_5_m_up(link)
            here = link.last_position()
            assert here is not None
            start = Ned(here.ned.north, here.ned.east, -5.0)
            await link.send_position_target(start, Sweep(Ned(0.0, 2.0, 0.0), 1.0))
            await asyncio.sleep(0.5)
            midway = model.setpoint
            assert midway is not None and midway.east is not None and midway.north is not None
            assert (midway.vn, midway.ve, midway.vd) == (0.0, 2.0, 0.0)
            assert midway.east - start.east == pytest.approx(1.0, abs=0.3)
            assert midway.north == pytest.approx(start.north)
            await asyncio.sleep(1.0)
            over = model.setpoint
            assert over is not None and (over.vn, over.ve, over.vd) == (0.0, 0.0, 0.0)
            assert (over.north, over.east) == pytest.approx((start.north, start.east + 2.0), abs=1e-3)

    run(scenario)


def test_a_vehicle_that_reports_no_battery_level_is_not_ready() -> None:
    """An autopilot with no battery monitor sends battery_remaining -1 (the links' None): the battery
    monitor could not keep the drone above its threshold, so the agent must not fly it."""
    ready = Telemetry(Autopilot.ARDUPILOT, False, "GUIDED", Position(Ned(0, 0, 0), 1.0), None,
                      GeoPoint(47.0, 8.0, 500.0), 0.0, 80, 16.0, 3, 10, LandedState.ON_GROUND, 1.0)
    assert not_ready(ready) is None
    assert not_ready(dataclasses.replace(ready, battery_pct=None)) == "no battery level (BATTERY_STATUS or SYS_STATUS)"
    assert not_ready(dataclasses.replace(ready, gps_fix=2)) == "GPS fix type 2, need a 3D fix"


# ------------------------------------------------------------------ contract: the workspace frame
@backends
def test_a_link_in_a_workspace_frame_flies_global_setpoints(backend: str) -> None:
    """With a GeoFrame, positions and targets are in the workspace's frame, not the vehicle's local one."""
    place = placements(None, 1)[0]  # where the fake stands without a workspace

    async def scenario() -> None:
        async with fake_vehicle("px4", "udp") as fake, connected(backend, fake, frame=place.frame) as link:
            await link.wait_ready(timeout=5)
            assert near(place.home, 0.05)(link.telemetry())
            await link.arm()
            await link.takeoff(3.0)
            await link.wait_until(lambda t: (t.height_m or 0) > 2.7, 5, "3 m up")
            await link.follow_setpoints()
            target = Ned(place.home.north + 4.0, place.home.east - 3.0, -4.0)
            sent_at = link.clock()
            await link.send_position_target(target)
            # On the way north and west: the velocity says so, in the frame's axes.
            t = await link.wait_until(lambda t: t.velocity is not None and math.hypot(t.velocity.north,
                                                                                      t.velocity.east) > 1.0,
                                      5, "the flight to the target")
            assert t.velocity is not None and t.velocity.north > 0 > t.velocity.east, t.velocity
            assert math.hypot(t.velocity.north, t.velocity.east) < 20, f"not in m/s: {t.velocity}"
            t = await link.wait_until(near(target, 0.3), 5, "the target")
            assert t.mode == "OFFBOARD"
            # Every position on the way is kept, in order: the flight record's cells in between.
            trail = link.positions_since(sent_at)
            assert trail[-1] == link.last_position() and len(trail) >= 5, trail
            assert all(a.at < b.at for a, b in itertools.pairwise(trail))
            assert trail[0].ned.north < place.home.north + 1.0 < place.home.north + 3.0 < trail[-1].ned.north
            if backend == "pymavlink":
                # Positions and velocities come from GLOBAL_POSITION_INT: the local position, which
                # PX4 streams by default, is asked off (it was a third of what a vehicle sent).
                streams = fake.nodes[0].model.streams
                local = streams.interval(mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED)
                glob = streams.interval(mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT)
                assert glob is not None and local is None, (local, glob)

    run(scenario)


@backends
def test_parameters_are_read_by_name_as_the_autopilot_stores_them(backend: str) -> None:
    """PARAM_REQUEST_READ by name: an ArduCopter's WPNAV_ACCEL as set (cm/s²), and SITL's SIM_SPEEDUP
    (the fake's speedup); a PX4's MPC_ACC_HOR at its default. What the agent judges its limits by. PARAM_SET
    answered with the value held, as an agent sets GUID_TIMEOUT."""
    async def scenario() -> None:
        async with fake_vehicle("ardupilot", "udp", params=(("WPNAV_ACCEL", 400.0),)) as fake, \
                connected(backend, fake) as link:
            assert await link.read_parameters(["WPNAV_ACCEL", "SIM_SPEEDUP"]) == {
                "WPNAV_ACCEL": 400.0, "SIM_SPEEDUP": SPEEDUP}
            assert await link.set_parameter("GUID_TIMEOUT", 0.25) == 0.25  # what an agent sets (half of tau)
            assert await link.read_parameters(["GUID_TIMEOUT"]) == {"GUID_TIMEOUT": 0.25}
        async with fake_vehicle("px4", "udp") as fake, connected(backend, fake) as link:
            assert await link.read_parameters(["MPC_ACC_HOR"]) == {"MPC_ACC_HOR": 3.0}

    run(scenario)


def _set_as_another_ground_station(port: int, name: str, value: float) -> float:
    """PARAM_SET from a ground station of its own (blocking: run it in a thread); the value it was answered."""
    station = mavutil.mavlink_connection(f"tcp:127.0.0.1:{port}", source_system=250)
    try:
        station.wait_heartbeat(timeout=5)
        station.mav.param_set_send(1, 1, name.encode(), value, mavlink2.MAV_PARAM_TYPE_REAL32)
        answer = station.recv_match(type="PARAM_VALUE", blocking=True, timeout=5)
        assert answer is not None, "no PARAM_VALUE for the set"
        return float(answer.param_value)
    finally:
        station.close()


@backends
def test_a_parameter_another_ground_station_sets_is_heard_unasked(backend: str) -> None:
    """ArduPilot tells every ground station of a parameter set (``GCS::send_parameter_value``, to all active
    channels): a limit lowered in flight by another station reaches the agent, which asked for nothing."""
    async def scenario() -> None:
        async with fake_vehicle("ardupilot", "tcp") as fake, connected(backend, fake) as link:
            assert await link.read_parameters(["WPNAV_SPEED"]) == {"WPNAV_SPEED": 1000.0}
            port = int(fake.url.rsplit(":", 1)[1])
            assert await asyncio.to_thread(_set_as_another_ground_station, port, "WPNAV_SPEED", 300.0) == 300.0
            for _ in range(100):  # bounded: 5 s
                if link.parameters_heard().get("WPNAV_SPEED") == 300.0:
                    break
                await asyncio.sleep(0.05)
            assert link.parameters_heard()["WPNAV_SPEED"] == 300.0

    run(scenario)
