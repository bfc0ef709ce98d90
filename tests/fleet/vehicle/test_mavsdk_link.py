"""MAVSDK's own client (``mavsdk`` 4.x, the ctypes binding of the C++ library) flies the fake vehicle.

For each personality, on the link its real SITL offers (PX4: the vehicle sends UDP to the ground
station's port, MAVSDK listens with ``udpin://``; ArduCopter: a TCP server, MAVSDK connects with
``tcpout://``), the client waits for the autopilot and its health, arms, starts offboard control
(ArduCopter: MAVSDK's offboard is GUIDED, which only flies after a MAV_CMD_NAV_TAKEOFF, so it takes
off first), flies to a local NED setpoint a few metres away, reads battery and position, and lands.

The fake runs in the test's own event loop; MAVSDK's blocking calls run in executor threads. MAVSDK
keeps wall-clock timeouts and streams offboard setpoints at 20 Hz of the wall clock, so simulated
time runs only :data:`SPEEDUP` times faster (PX4's 0.5 s offboard timeout is 0.25 s of wall time).
Every wait is bounded; MAVSDK's own log is printed, so pytest shows it when a test fails.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import time
from collections.abc import AsyncGenerator, AsyncIterator, Callable, Coroutine
from typing import Any, TypeVar

import pytest

from drona_gcs.geo import Ned
from fleet.sim.fleet import placements
from fleet.sim.personality import ARDUPILOT, PX4, Personality
from fleet.vehicle.urls import parse_link_url
from tests.fakes.autopilot import fake_vehicle

try:
    import mavsdk
    from mavsdk.asyncio import Autopilot, ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.mavlink_direct import MavlinkDirectAsync, MavlinkMessage
    from mavsdk.asyncio.plugins.offboard import OffboardAsync, PositionNedYaw
    from mavsdk.asyncio.plugins.telemetry import FlightMode, LandedState, TelemetryAsync

    from fleet.vehicle.mavsdk_link import mavsdk_url
except Exception as exc:  # no package, or its native library does not load here
    _reason = f"MAVSDK cannot run here: {type(exc).__name__}: {exc}"
    print(_reason)
    pytest.skip(_reason, allow_module_level=True)

T = TypeVar("T")

SPEEDUP = 2.0
READY_AFTER_S = 3.0  #: simulated boot to a position estimate, short: this test is about MAVSDK, not the boot
TAKEOFF_ALT_M = 3.0
GOAL = (6.0, 4.0, -4.0)  #: local NED (m) from home, and the yaw below
GOAL_YAW_DEG = 90.0
TOLERANCE_M = 0.3
SET_MESSAGE_INTERVAL, SYS_STATUS = 511, 1  #: MAV_CMD and message id


# ------------------------------------------------------------------ harness
@contextlib.contextmanager
def mavsdk_log() -> Any:
    """Print MAVSDK's log lines with a wall-clock stamp (pytest shows them for a failed test)."""
    start = time.monotonic()

    def on_log(level: Any, message: str, file: str | None, line: int) -> bool:
        print(f"{time.monotonic() - start:7.2f} mavsdk {level.name}: {message}", flush=True)
        return True  # instead of MAVSDK's own printing

    mavsdk.log_subscribe(on_log)
    try:
        yield
    finally:
        mavsdk.log_unsubscribe()


async def bounded(awaitable: Coroutine[Any, Any, T], timeout: float, what: str) -> T:
    try:
        return await asyncio.wait_for(awaitable, timeout)
    except TimeoutError:
        pytest.fail(f"{what}: nothing within {timeout} s")


async def first(stream: AsyncGenerator[T, None], where: Callable[[T], bool], timeout: float, what: str) -> T:
    """The first item of a MAVSDK subscription for which ``where`` holds; fails after ``timeout`` s."""
    last: list[T] = []

    async def find() -> T:
        async for item in stream:
            last[:] = [item]
            if where(item):
                return item
        raise AssertionError(f"{what}: the subscription ended")

    async with contextlib.aclosing(stream):  # unsubscribes, also on a timeout
        try:
            return await asyncio.wait_for(find(), timeout)
        except TimeoutError:
            pytest.fail(f"{what}: not within {timeout} s; last {vars(last[0]) if last else 'nothing'}")


@contextlib.asynccontextmanager
async def sitl_like(personality: Personality) -> AsyncIterator[str]:
    """The shared fake vehicle on its SITL's link, with the personality's own timeouts; yields MAVSDK's
    connection URL."""
    transport = "tcp" if personality is ARDUPILOT else "udp"
    async with fake_vehicle(personality.name, transport, speedup=SPEEDUP, ready_after_s=READY_AFTER_S,
                            auto_disarm_s=None, offboard_timeout_s=None) as fake:
        yield mavsdk_url(parse_link_url(fake.url))


def near(ned: Any, goal: tuple[float, float, float]) -> bool:
    return math.dist((ned.north_m, ned.east_m, ned.down_m), goal) < TOLERANCE_M


# ------------------------------------------------------------------ the flight
async def fly(personality: Personality) -> None:
    ardupilot = personality is ARDUPILOT
    async with sitl_like(personality) as url, \
            Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as client:
        await bounded(client.add_any_connection(url), 5, f"connecting to {url}")
        system = await bounded(client.first_autopilot(timeout_s=10.0), 12, "the autopilot")
        assert system is not None, "no autopilot within 10 s"
        assert await system.autopilot_type() == (Autopilot.ARDUPILOT if ardupilot else Autopilot.PX4)
        telemetry, action, offboard = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system)

        if ardupilot:
            # ArduCopter streams nothing until asked (its SRx_ rates are 0); PX4 has a default set.
            for set_rate in (telemetry.set_rate_position, telemetry.set_rate_position_velocity_ned,
                             telemetry.set_rate_battery):
                await bounded(set_rate(10.0), 5, set_rate.__name__)
            # MAVSDK's health comes from SYS_STATUS, which no set_rate_* asks for (set_rate_health
            # answers UNKNOWN): ask with MAV_CMD_SET_MESSAGE_INTERVAL through MavlinkDirect.
            ack = await bounded(MavlinkDirectAsync(system).send_command(MavlinkMessage(
                message_name="COMMAND_LONG", target_system_id=1, target_component_id=1,
                fields_json=json.dumps({"target_system": 1, "target_component": 1, "command": SET_MESSAGE_INTERVAL,
                                        "confirmation": 0, "param1": SYS_STATUS, "param2": 100_000,
                                        "param3": 0, "param4": 0, "param5": 0, "param6": 0, "param7": 0}))),
                5, "SYS_STATUS interval")
            assert json.loads(ack.fields_json)["result"] == 0, ack.fields_json  # MAV_RESULT_ACCEPTED

        await first(telemetry.subscribe_health(),
                    lambda h: h.is_global_position_ok and h.is_home_position_ok and h.is_armable, 10, "health")

        await bounded(action.arm(), 5, "arm")
        await first(telemetry.subscribe_armed(), bool, 3, "armed")

        hover = (0.0, 0.0, -TAKEOFF_ALT_M)
        if ardupilot:  # GUIDED on the ground waits for a takeoff command before it follows setpoints
            await bounded(action.set_takeoff_altitude(TAKEOFF_ALT_M), 5, "set_takeoff_altitude")
            await bounded(action.takeoff(), 5, "takeoff")
            await first(telemetry.subscribe_position_velocity_ned(), lambda pv: near(pv.position, hover), 15,
                        "takeoff height")

        # Offboard needs a setpoint before it starts (MAVSDK then streams it at 20 Hz).
        await bounded(offboard.set_position_ned(PositionNedYaw(*hover, 0.0)), 2, "first setpoint")
        await bounded(offboard.start(), 5, "offboard start")
        assert await bounded(offboard.is_active(), 2, "offboard is_active")
        # MAVSDK shows PX4's OFFBOARD and ArduCopter's GUIDED alike as its OFFBOARD flight mode.
        await first(telemetry.subscribe_flight_mode(), lambda mode: mode == FlightMode.OFFBOARD, 3, "OFFBOARD mode")

        await bounded(offboard.set_position_ned(PositionNedYaw(*GOAL, GOAL_YAW_DEG)), 2, "goal setpoint")
        settled = await first(telemetry.subscribe_position_velocity_ned(),
                              lambda pv: near(pv.position, GOAL) and math.hypot(pv.velocity.north_m_s,
                                                                                pv.velocity.east_m_s) < 0.2,
                              20, f"settled at {GOAL}")
        assert settled.position.down_m == pytest.approx(GOAL[2], abs=TOLERANCE_M)
        await first(telemetry.subscribe_heading(), lambda h: abs(h.heading_deg - GOAL_YAW_DEG) < 1.0, 5, "heading")

        battery = await first(telemetry.subscribe_battery(), lambda b: math.isfinite(b.remaining_percent), 5,
                              "battery")
        assert 50.0 < battery.remaining_percent <= 100.0
        assert battery.voltage_v > 10.0
        assert battery.current_battery_a > 5.0  # hovering draws current

        (place,) = placements(None, 1)
        want = place.frame.ned_to_global(Ned(place.home.north + GOAL[0], place.home.east + GOAL[1],
                                             place.home.down + GOAL[2]))
        position = await first(telemetry.subscribe_position(), lambda p: near_global(p, want), 5, "global position")
        assert position.relative_altitude_m == pytest.approx(-GOAL[2], abs=TOLERANCE_M)

        await bounded(offboard.stop(), 5, "offboard stop")
        await bounded(action.land(), 5, "land")
        await first(telemetry.subscribe_armed(), lambda armed: not armed, 20, "disarmed after landing")
        landed = await first(telemetry.subscribe_landed_state(), lambda s: s == LandedState.ON_GROUND, 5,
                             "on the ground")
        assert landed == LandedState.ON_GROUND


def near_global(position: Any, want: Any) -> bool:
    if not math.isfinite(position.latitude_deg):
        return False
    north = (position.latitude_deg - want.lat) * 111_320.0
    east = (position.longitude_deg - want.lon) * 111_320.0 * math.cos(math.radians(want.lat))
    return math.hypot(north, east) < TOLERANCE_M


@pytest.mark.parametrize("personality", [PX4, ARDUPILOT], ids=lambda p: p.name)
def test_mavsdk_flies_the_fake_vehicle(personality: Personality) -> None:
    with mavsdk_log():
        asyncio.run(asyncio.wait_for(fly(personality), 40))
