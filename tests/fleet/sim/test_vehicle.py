"""The fake vehicle (``drona sim-vehicle``) against pymavlink's stock ground-station connection.

Real MAVLink bytes over UDP and TCP on 127.0.0.1 only, on ports picked free for each test.
The fleet runs in a thread of this process; the ground station is ``mavutil.mavlink_connection``.
Simulated time runs faster (``speedup``) so whole flights take seconds; every wait below is bounded.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import socket
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest

os.environ.setdefault("MAVLINK20", "1")  # before mavutil picks its dialect

from fleet.sim.config import VehicleConfig
from fleet.sim.fleet import FleetConfig, run_fleet
from fleet.sim.personality import PX4, px4_mode
from fleet.sim.ports import free_udp_base
from tests.fleet.sim.vehicle_helpers import GUIDED, ML, POSITION_ONLY, ardupilot, command, ground_station, wait_for

SIGNING_KEY = bytes(range(32))
OFFBOARD, AUTO_LOITER = px4_mode(6), px4_mode(4, 3)


# ------------------------------------------------------------------ harness
def free_tcp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port: int = probe.getsockname()[1]
        return port


@contextlib.contextmanager
def sim_fleet(config: FleetConfig) -> Iterator[None]:
    """Run the fleet in a thread with its own event loop; stop it (bounded) on exit."""
    ready = threading.Event()
    box: dict[str, Any] = {}

    async def main() -> None:
        box["loop"], box["stop"] = asyncio.get_running_loop(), asyncio.Event()
        await run_fleet(config, None, box["stop"], on_ready=lambda nodes: ready.set())

    def target() -> None:
        try:
            asyncio.run(main())
        except BaseException as exc:  # handed to the test thread below
            box["error"] = exc
            ready.set()

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    assert ready.wait(5), "the fleet did not start"
    if "error" in box:
        raise box["error"]
    try:
        yield
    finally:
        box["loop"].call_soon_threadsafe(box["stop"].set)
        thread.join(5)
        assert not thread.is_alive(), "the fleet did not stop"
        if "error" in box:
            raise box["error"]


def mode_after(gcs: Any) -> int:
    return int(wait_for(gcs, "HEARTBEAT").custom_mode)


def drain(gcs: Any, seconds: float) -> list[Any]:
    out, deadline = [], time.monotonic() + seconds
    while (left := deadline - time.monotonic()) > 0:
        msg = gcs.recv_match(blocking=True, timeout=left)
        if msg is not None:
            out.append(msg)
    return out


# ------------------------------------------------------------------ ArduCopter
def test_ardupilot_guided_flight_over_tcp() -> None:
    port = free_tcp_port()
    config = FleetConfig(vehicle=ardupilot(ready_after_s=20.0), tcp=True, base_port=port, speedup=10.0)
    with sim_fleet(config), ground_station(f"tcp:127.0.0.1:{port}") as gcs:
        hb = wait_for(gcs, "HEARTBEAT")
        assert (hb.type, hb.autopilot, hb.custom_mode) == (ML.MAV_TYPE_QUADROTOR, ML.MAV_AUTOPILOT_ARDUPILOTMEGA, 0)
        assert hb.base_mode & ML.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        assert {m.get_type() for m in drain(gcs, 0.3)} == {"HEARTBEAT"}  # stream rates are 0 until asked

        # Before the position estimate, disarmed: GUIDED is taken (ArduCopter checks nothing while
        # disarmed); arming fails with a reason.
        assert command(gcs, ML.MAV_CMD_DO_SET_MODE, 1, GUIDED) == ML.MAV_RESULT_ACCEPTED
        assert mode_after(gcs) == GUIDED
        assert command(gcs, ML.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ML.MAV_RESULT_FAILED
        assert "Need Position Estimate" in wait_for(gcs, "STATUSTEXT").text

        for msg_id, interval_us in ((ML.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 100_000),
                                    (ML.MAVLINK_MSG_ID_BATTERY_STATUS, 1_000_000),
                                    (ML.MAVLINK_MSG_ID_GPS_RAW_INT, 1_000_000)):
            assert command(gcs, ML.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, interval_us) == ML.MAV_RESULT_ACCEPTED
        assert wait_for(gcs, "BATTERY_STATUS").battery_remaining == 100
        wait_for(gcs, "GPS_RAW_INT", 10, lambda m: m.fix_type >= 3)

        wait_for(gcs, "LOCAL_POSITION_NED", 5)  # with the estimate: the local position
        assert command(gcs, ML.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ML.MAV_RESULT_ACCEPTED
        assert wait_for(gcs, "HEARTBEAT").base_mode & ML.MAV_MODE_FLAG_SAFETY_ARMED
        assert command(gcs, ML.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 10) == ML.MAV_RESULT_ACCEPTED
        wait_for(gcs, "LOCAL_POSITION_NED", 5, lambda m: abs(m.z + 10) < 0.25)
        assert command(gcs, ML.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 10) == ML.MAV_RESULT_FAILED  # airborne

        # ArduCopter's 10 m/s (WPNAV_SPEED 1000 cm/s) slowed to 5 m/s by the ground station, in flight.
        gcs.mav.param_set_send(1, 1, b"WPNAV_SPEED", 500, ML.MAV_PARAM_TYPE_REAL32)
        assert wait_for(gcs, "PARAM_VALUE", 3, lambda m: m.param_id == "WPNAV_SPEED").param_value == 500
        gcs.mav.set_position_target_local_ned_send(0, 1, 1, ML.MAV_FRAME_LOCAL_NED, POSITION_ONLY,
                                                   20, 0, -10, 0, 0, 0, 0, 0, 0, 0, 0)
        peak, settled_since = 0.0, None
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline:
            pos = wait_for(gcs, "LOCAL_POSITION_NED")
            peak = max(peak, math.hypot(pos.vx, pos.vy))
            if math.dist((pos.x, pos.y, pos.z), (20, 0, -10)) < 0.25:
                settled_since = settled_since or pos.time_boot_ms
                if pos.time_boot_ms - settled_since > 2000:  # stayed 2 s (simulated) within 0.25 m
                    break
            else:
                settled_since = None
        else:
            pytest.fail(f"did not settle at (20, 0, -10); last {pos}")
        assert 4.0 < peak <= 5.0 + 1e-4

        assert command(gcs, ML.MAV_CMD_NAV_LAND) == ML.MAV_RESULT_ACCEPTED
        wait_for(gcs, "HEARTBEAT", 8, lambda m: not m.base_mode & ML.MAV_MODE_FLAG_SAFETY_ARMED)  # disarms on landing
        assert abs(wait_for(gcs, "LOCAL_POSITION_NED").z) < 0.05
        assert command(gcs, ML.MAV_CMD_COMPONENT_ARM_DISARM, 0) == ML.MAV_RESULT_ACCEPTED
        assert wait_for(gcs, "BATTERY_STATUS").battery_remaining < 100  # the flight drew current


def test_ardupilot_command_rules_over_udp() -> None:
    base = free_udp_base(1)
    with ground_station(f"udpin:127.0.0.1:{base}") as gcs, \
            sim_fleet(FleetConfig(vehicle=ardupilot(ready_after_s=0.001), base_port=base, speedup=10.0)):
        wait_for(gcs, "HEARTBEAT")
        takeoff = (ML.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 5)
        assert command(gcs, *takeoff) == ML.MAV_RESULT_FAILED  # disarmed, STABILIZE
        assert command(gcs, ML.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ML.MAV_RESULT_ACCEPTED
        assert command(gcs, *takeoff) == ML.MAV_RESULT_FAILED  # armed, but not GUIDED
        assert command(gcs, ML.MAV_CMD_DO_SET_MODE, 1, GUIDED) == ML.MAV_RESULT_ACCEPTED
        assert command(gcs, *takeoff) == ML.MAV_RESULT_ACCEPTED

        assert command(gcs, ML.MAV_CMD_DO_FLIGHTTERMINATION, 1) == ML.MAV_RESULT_UNSUPPORTED
        gcs.mav.command_int_send(1, 1, ML.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, ML.MAV_CMD_DO_REPOSITION, 0, 0,
                                 -1, 0, 0, 0, 0, 0, 10)
        assert wait_for(gcs, "COMMAND_ACK").result == ML.MAV_RESULT_UNSUPPORTED
        gcs.mav.set_mode_send(1, ML.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 5)  # LOITER by SET_MODE
        assert wait_for(gcs, "COMMAND_ACK").result == ML.MAV_RESULT_ACCEPTED
        assert mode_after(gcs) == 5

        assert command(gcs, ML.MAV_CMD_REQUEST_MESSAGE, ML.MAVLINK_MSG_ID_AUTOPILOT_VERSION) == ML.MAV_RESULT_ACCEPTED
        assert wait_for(gcs, "AUTOPILOT_VERSION").capabilities & ML.MAV_PROTOCOL_CAPABILITY_MAVLINK2
        assert command(gcs, ML.MAV_CMD_REQUEST_MESSAGE, ML.MAVLINK_MSG_ID_HOME_POSITION) == ML.MAV_RESULT_ACCEPTED
        assert wait_for(gcs, "HOME_POSITION").latitude != 0
        gcs.mav.timesync_send(0, 123456)
        assert wait_for(gcs, "TIMESYNC").ts1 == 123456
        gcs.mav.request_data_stream_send(1, 1, ML.MAV_DATA_STREAM_POSITION, 4, 1)  # legacy stream rates
        assert wait_for(gcs, "GLOBAL_POSITION_INT").lat != 0


def test_ardupilot_refuses_to_arm_on_low_battery_and_disarms_itself() -> None:
    base = free_udp_base(1)
    low = FleetConfig(vehicle=ardupilot(ready_after_s=0.001, battery_pct=10), base_port=base, speedup=10.0)
    with ground_station(f"udpin:127.0.0.1:{base}") as gcs, sim_fleet(low):
        wait_for(gcs, "HEARTBEAT")
        assert command(gcs, ML.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ML.MAV_RESULT_FAILED
        assert "Battery" in wait_for(gcs, "STATUSTEXT").text
    idle = FleetConfig(vehicle=ardupilot(ready_after_s=0.001, auto_disarm_s=5.0), base_port=base, speedup=10.0)
    with ground_station(f"udpin:127.0.0.1:{base}") as gcs, sim_fleet(idle):
        wait_for(gcs, "HEARTBEAT")
        assert command(gcs, ML.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ML.MAV_RESULT_ACCEPTED
        wait_for(gcs, "HEARTBEAT", 1, lambda m: m.base_mode & ML.MAV_MODE_FLAG_SAFETY_ARMED)
        wait_for(gcs, "HEARTBEAT", 3, lambda m: not m.base_mode & ML.MAV_MODE_FLAG_SAFETY_ARMED)


# ------------------------------------------------------------------ PX4
def test_px4_offboard_needs_a_setpoint_stream() -> None:
    base = free_udp_base(1)
    config = FleetConfig(vehicle=VehicleConfig(personality=PX4, ready_after_s=0.001), base_port=base, speedup=1.0)
    with ground_station(f"udpin:127.0.0.1:{base}") as gcs, sim_fleet(config):
        hb = wait_for(gcs, "HEARTBEAT")
        assert (hb.autopilot, hb.custom_mode) == (ML.MAV_AUTOPILOT_PX4, AUTO_LOITER)
        wait_for(gcs, "LOCAL_POSITION_NED")  # PX4 streams a default set

        offboard = (ML.MAV_CMD_DO_SET_MODE, ML.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0)
        assert command(gcs, *offboard) == ML.MAV_RESULT_TEMPORARILY_REJECTED
        assert mode_after(gcs) == AUTO_LOITER

        def setpoint() -> None:
            gcs.mav.set_position_target_local_ned_send(0, 1, 1, ML.MAV_FRAME_LOCAL_NED, POSITION_ONLY,
                                                       0, 0, -3, 0, 0, 0, 0, 0, 0, 0, 0)

        received: list[Any] = []
        for _ in range(6):  # 10 Hz for 0.6 s
            setpoint()
            received += drain(gcs, 0.1)
        gcs.mav.command_long_send(1, 1, *offboard[:1], 0, *offboard[1:], 0, 0, 0, 0)
        gcs.mav.command_long_send(1, 1, ML.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
        for _ in range(30):  # keep streaming 3 s: it arms, switches, spools up (1 s) and climbs to 3 m
            setpoint()
            received += drain(gcs, 0.1)
        acks = {m.command: m.result for m in received if m.get_type() == "COMMAND_ACK"}
        assert acks == {ML.MAV_CMD_DO_SET_MODE: ML.MAV_RESULT_ACCEPTED,
                        ML.MAV_CMD_COMPONENT_ARM_DISARM: ML.MAV_RESULT_ACCEPTED}
        assert [m.custom_mode for m in received if m.get_type() == "HEARTBEAT"][-1] == OFFBOARD
        assert [m.z for m in received if m.get_type() == "LOCAL_POSITION_NED"][-1] < -2.5

        # The stream stops: after COM_OF_LOSS_T (1 s) without setpoints it falls back to AUTO.LOITER, still flying.
        hb = wait_for(gcs, "HEARTBEAT", 3, lambda m: m.custom_mode != OFFBOARD)
        assert hb.custom_mode == AUTO_LOITER
        assert hb.base_mode & ML.MAV_MODE_FLAG_SAFETY_ARMED
        assert wait_for(gcs, "EXTENDED_SYS_STATE").landed_state == ML.MAV_LANDED_STATE_IN_AIR


# ------------------------------------------------------------------ signing
def test_signing_ignores_unsigned_commands() -> None:
    base = free_udp_base(1)
    config = FleetConfig(vehicle=ardupilot(ready_after_s=0.001), base_port=base, speedup=10.0, signing_key=SIGNING_KEY)
    with ground_station(f"udpin:127.0.0.1:{base}") as gcs, sim_fleet(config):
        wait_for(gcs, "HEARTBEAT")
        gcs.mav.command_long_send(1, 1, ML.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
        assert not [m for m in drain(gcs, 0.5) if m.get_type() == "COMMAND_ACK"]  # ignored: no ACK
        assert not wait_for(gcs, "HEARTBEAT").base_mode & ML.MAV_MODE_FLAG_SAFETY_ARMED
        gcs.setup_signing(SIGNING_KEY, sign_outgoing=True)
        assert command(gcs, ML.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ML.MAV_RESULT_ACCEPTED
        assert wait_for(gcs, "HEARTBEAT").get_signed()
