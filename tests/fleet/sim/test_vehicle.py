"""The fake vehicle (``drona sim-vehicle``) against pymavlink's stock ground-station connection.

Real MAVLink bytes over UDP and TCP on 127.0.0.1 only, on ports picked free for each test.
The fleet runs in a thread of this process (or, for the CLI test, in a subprocess); the
ground station is ``mavutil.mavlink_connection``. Simulated time runs faster (``speedup``)
so whole flights take seconds; every wait below is bounded.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import math
import os
import re
import select
import signal
import socket
import statistics
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

os.environ.setdefault("MAVLINK20", "1")  # before mavutil picks its dialect
from pymavlink import mavutil

from drona_gcs.geo import GeoFrame
from drona_gcs.workspace_files import load_workspace
from fleet.cli import main as drona_main
from fleet.sim.config import VehicleConfig
from fleet.sim.fleet import FleetConfig, pack_datagrams, placements, run_fleet
from fleet.sim.mav import mavlink2
from fleet.sim.model import VehicleModel
from fleet.sim.personality import ARDUPILOT, PX4, px4_mode
from fleet.sim.ports import free_udp_base
from fleet.sim.telemetry import Streams, battery_status, sys_status
from fleet.sim.transport import SERIAL_TX_BUFFER, PtyLink

ML = mavutil.mavlink
REPO = Path(__file__).resolve().parents[3]
SIGNING_KEY = bytes(range(32))
GUIDED, STABILIZE = 4, 0
POSITION_ONLY = 0b110111111000  # SET_POSITION_TARGET type_mask: use x, y, z only
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


@contextlib.contextmanager
def ground_station(url: str) -> Iterator[Any]:
    gcs = mavutil.mavlink_connection(url, source_system=255)
    try:
        yield gcs
    finally:
        gcs.close()


def wait_for(gcs: Any, kind: str, timeout: float = 5.0,
             where: Callable[[Any], bool] = lambda m: True) -> Any:
    """The next ``kind`` message for which ``where`` holds; fails after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while (left := deadline - time.monotonic()) > 0:
        msg = gcs.recv_match(type=kind, blocking=True, timeout=left)
        if msg is not None and where(msg):
            return msg
    pytest.fail(f"no {kind} within {timeout} s")


def command(gcs: Any, cmd: int, *params: float, target: int = 1, timeout: float = 3.0) -> int:
    """Send COMMAND_LONG; return the result of its COMMAND_ACK."""
    p = [*params, 0, 0, 0, 0, 0, 0, 0][:7]
    gcs.mav.command_long_send(target, 1, cmd, 0, *p)
    return int(wait_for(gcs, "COMMAND_ACK", timeout, lambda m: m.command == cmd).result)


def mode_after(gcs: Any) -> int:
    return int(wait_for(gcs, "HEARTBEAT").custom_mode)


def drain(gcs: Any, seconds: float) -> list[Any]:
    out, deadline = [], time.monotonic() + seconds
    while (left := deadline - time.monotonic()) > 0:
        msg = gcs.recv_match(blocking=True, timeout=left)
        if msg is not None:
            out.append(msg)
    return out


def ardupilot(**vehicle: Any) -> VehicleConfig:
    return replace(VehicleConfig(personality=ARDUPILOT), **vehicle)


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


# ------------------------------------------------------------------ the command
def test_cli_runs_two_vehicles_and_stops_on_sigterm(write_file: Callable[[str, str], Path]) -> None:
    ws_file = write_file("ws.yaml", "size: [4, 4, 1]\ncell_size_m: 5\n"
                         "geo_origin: {lat: 37.87, lon: -122.27, alt_m: 52}\n"
                         "drones: {d1: [1, 0, 0], d2: [3, 2, 0]}\n")
    frame = GeoFrame(load_workspace(ws_file))
    base = free_udp_base(2)
    with ground_station(f"udpin:127.0.0.1:{base}") as g1, ground_station(f"udpin:127.0.0.1:{base + 1}") as g2:
        proc = subprocess.Popen([sys.executable, "-m", "fleet.cli", "sim-vehicle", "--workspace", str(ws_file),
                                 "--count", "2", "--base-port", str(base), "--speedup", "5", "--autopilot", "px4",
                                 "--ready-after", "1"],
                                cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        try:
            for gcs, sysid, cell in ((g1, 1, (1, 0, 0)), (g2, 2, (3, 2, 0))):
                hb = wait_for(gcs, "HEARTBEAT", 10)
                assert hb.get_srcSystem() == sysid  # PX4 SITL instances are systems 1, 2, ...
                wait_for(gcs, "GPS_RAW_INT", 5, lambda m: m.fix_type >= 3)  # after its --ready-after
                assert command(gcs, ML.MAV_CMD_REQUEST_MESSAGE, ML.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
                               target=sysid) == ML.MAV_RESULT_ACCEPTED
                pos, want = wait_for(gcs, "GLOBAL_POSITION_INT"), frame.cell_to_global(cell)
                assert (pos.lat, pos.lon, pos.relative_alt) == (round(want.lat * 1e7), round(want.lon * 1e7), 0)
        finally:
            err = terminate(proc)
        assert proc.returncode == 0, err.decode()


def terminate(proc: subprocess.Popen[bytes]) -> bytes:
    """SIGTERM, then what is left of its stderr once it exits (killed, and the test failed, after 5 s)."""
    proc.send_signal(signal.SIGTERM)
    try:
        return proc.communicate(timeout=5)[1]
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        raise


def stderr_lines(proc: subprocess.Popen[bytes], count: int, timeout: float) -> list[str]:
    """The first ``count`` lines the process writes to stderr, waiting at most ``timeout`` s in all."""
    assert proc.stderr is not None
    lines: list[str] = []
    buffer, deadline = b"", time.monotonic() + timeout
    while len(lines) < count and (left := deadline - time.monotonic()) > 0:
        readable, _, _ = select.select([proc.stderr], [], [], left)
        if not readable:
            break
        chunk = os.read(proc.stderr.fileno(), 4096)
        if not chunk:
            break
        buffer += chunk
        *done, buffer = buffer.split(b"\n")
        lines += [line.decode() for line in done]
    assert len(lines) >= count, f"wanted {count} lines on stderr, got {lines} {buffer!r}"
    return lines[:count]


def test_cli_serial_vehicles_say_their_device_and_answer_on_it() -> None:
    """``--serial``: each vehicle on a pseudo-terminal whose device it prints; a ground station opens
    that device as a serial port (pymavlink through pyserial) at the baud rate."""
    proc = subprocess.Popen([sys.executable, "-m", "fleet.cli", "sim-vehicle", "--serial", "--baud", "115200",
                             "--count", "2", "--speedup", "5"],
                            cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        lines = stderr_lines(proc, 2, 10)
        sysid = 1  # every ArduPilot SITL instance is system 1: the link tells them apart
        for line in lines:
            found = re.fullmatch(rf"drona sim-vehicle: system {sysid} \(ardupilot\) serial (/dev/\S+) at 115200 baud",
                                 line)
            assert found, line
            with ground_station(found[1]) as gcs:
                assert wait_for(gcs, "HEARTBEAT", 10).get_srcSystem() == sysid
                assert command(gcs, ML.MAV_CMD_REQUEST_MESSAGE, ML.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
                               target=sysid) == ML.MAV_RESULT_ACCEPTED
    finally:
        err = terminate(proc)
    assert proc.returncode == 0, err.decode()


def test_cli_says_on_exit_when_a_serial_line_had_no_room() -> None:
    """300 baud carries 30 bytes a second; PX4 streams several kilobytes a second from boot at
    speedup 5: past the UART's buffer, most of it has no room."""
    proc = subprocess.Popen([sys.executable, "-m", "fleet.cli", "sim-vehicle", "--serial", "--baud", "300",
                             "--autopilot", "px4", "--speedup", "5"],
                            cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        stderr_lines(proc, 1, 10)  # serving
        time.sleep(1.0)
    finally:
        err = terminate(proc)
    assert proc.returncode == 0, err.decode()
    assert re.search(r"system 1: the serial line had no room for \d+ of \d+ bytes \(\d+\.\d%\)", err.decode())


@pytest.mark.parametrize("flags, problem", [
    (["--serial", "--tcp"], "not allowed with argument"),
    (["--serial", "--baud", "0"], "--baud must be > 0, got 0"),
    (["--baud", "9600"], "--baud is the rate of a serial line: it needs --serial"),
    (["--serial", "--base-port", "5760"], "--base-port: a serial line has no port"),
    (["--param", "FOO=1"], "--param: ardupilot has no parameter FOO"),
    (["--param", "PSC_JERK_XY"], "--param must be NAME=VALUE with a finite number, got 'PSC_JERK_XY'"),
    (["--autopilot", "px4", "--param", "PSC_JERK_XY=10"], "--param: px4 has no parameter PSC_JERK_XY"),
])
def test_cli_refuses_serial_flags_that_do_not_fit(flags: list[str], problem: str,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    try:
        code: str | int | None = drona_main(["sim-vehicle", *flags])
    except SystemExit as exc:  # argparse's own refusals
        code = exc.code
    assert code == 2
    assert problem in capsys.readouterr().err


def test_a_serial_line_drains_at_its_baud_rate_and_skips_what_has_no_room() -> None:
    """9600 baud is 960 bytes a second. The UART's transmit buffer holds 1 KiB: of 30 messages of
    100 bytes sent at once, 10 are queued and 20 skipped, whole. The queued ones reach the other
    end one by one, none before its last byte is through (a timer never fires early)."""
    async def scenario() -> None:
        loop = asyncio.get_running_loop()
        got: list[bytes] = []
        heard, all_in = asyncio.Event(), asyncio.Event()

        def on_data(data: bytes) -> None:
            got.append(data)
            heard.set()

        link = await PtyLink.open(9600, lambda: on_data)
        ground = -1
        arrived, times = bytearray(), []
        try:
            ground = os.open(link.device, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)

            def readable() -> None:
                arrived.extend(os.read(ground, 4096))
                times.append((loop.time(), len(arrived)))
                if len(arrived) >= 1000:
                    all_in.set()

            loop.add_reader(ground, readable)
            start, frame = loop.time(), bytes(range(100))
            for _ in range(30):
                link.send(frame)
            assert link.unsent == (30 - SERIAL_TX_BUFFER // len(frame)) * len(frame)  # 10 fit in 1 KiB
            async with asyncio.timeout(10):
                await all_in.wait()
            assert bytes(arrived) == frame * 10
            assert all(at - start >= total / 960 - 1e-3 for at, total in times), times
            os.write(ground, b"the other way")
            async with asyncio.timeout(5):
                await heard.wait()
            assert b"".join(got) == b"the other way"
        finally:
            if ground >= 0:
                loop.remove_reader(ground)
                os.close(ground)
            link.close()

    asyncio.run(scenario())


def test_a_serial_line_nobody_reads_loses_whole_messages_only() -> None:
    """Nobody has the device open while 40 kB go out, twice what the terminal holds: what is read
    once somebody opens it starts and ends on message boundaries (a message cut by the full
    terminal is not half there)."""
    async def scenario() -> bytes:
        link = await PtyLink.open(100_000_000, lambda: lambda data: None)  # 10 MB/s: the buffer never fills
        try:
            for i in range(400):
                link.send(bytes([i % 256]) * 100)
                await asyncio.sleep(0)  # a tick apart, as the fake's telemetry is
            await asyncio.sleep(link.queued() / link.rate + 0.05)  # until the last one is through
            ground = os.open(link.device, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
            try:
                data = b""
                while select.select([ground], [], [], 0.1)[0]:
                    data += os.read(ground, 65536)
                return data
            finally:
                os.close(ground)
        finally:
            link.close()

    data = asyncio.run(scenario())
    assert 0 < len(data) < 40_000 and len(data) % 100 == 0, len(data)
    chunks = [data[i:i + 100] for i in range(0, len(data), 100)]
    assert all(chunk == chunk[:1] * 100 for chunk in chunks), [c[:1] + c[-1:] for c in chunks if c != c[:1] * 100]


def test_cli_refuses_more_vehicles_than_drones(write_file: Callable[[str, str], Path],
                                               capsys: pytest.CaptureFixture[str]) -> None:
    ws_file = write_file("ws.yaml", "size: [4, 4, 1]\ndrones: {d1: [1, 0, 0]}\n")
    assert drona_main(["sim-vehicle", "--workspace", str(ws_file), "--count", "2"]) == 2
    assert "has 1 drone(s), 2 vehicles asked for" in capsys.readouterr().err


# ------------------------------------------------------------------ the sans-I/O model, driven by `now`
GCS = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)


def deliver(model: VehicleModel, msg: Any, now: float) -> list[Any]:
    """Pack as a ground station would and decode as the vehicle's link does, then handle."""
    decoder = mavlink2.MAVLink(None)
    return [out for m in decoder.parse_buffer(msg.pack(GCS)) or () for out in model.handle(m, now)]


def ack_of(model: VehicleModel, now: float, cmd: int, *params: float) -> int:
    p = [*params, 0, 0, 0, 0, 0, 0, 0][:7]
    replies = deliver(model, GCS.command_long_encode(model.config.system_id, 1, cmd, 0, *p), now)
    return int(next(m.result for m in replies if m.get_type() == "COMMAND_ACK"))


def run_for(model: VehicleModel, now: float, seconds: float, dt: float = 0.1) -> float:
    for _ in range(round(seconds / dt)):
        now += dt
        model.step(now)
    return now


def airborne_guided(model: VehicleModel, height: float) -> float:
    now = model.config.ready_s
    assert ack_of(model, now, ML.MAV_CMD_DO_SET_MODE, 1, GUIDED) == ML.MAV_RESULT_ACCEPTED
    assert ack_of(model, now, ML.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ML.MAV_RESULT_ACCEPTED
    assert ack_of(model, now, ML.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, height) == ML.MAV_RESULT_ACCEPTED
    return run_for(model, now, 10)


def test_model_global_setpoint_battery_rtl_and_charging(write_file: Callable[[str, str], Path]) -> None:
    ws = load_workspace(write_file("ws.yaml", "size: [6, 6, 1]\ncell_size_m: 5\n"
                                   "geo_origin: {lat: 37.87, lon: -122.27, alt_m: 52}\n"
                                   "charging_stations: [[1, 1, 0]]\ndrones: {d1: [1, 1, 0]}\n"))
    (place,) = placements(ws, 1)
    model = VehicleModel(ardupilot(ready_after_s=0.001), place, 0.0)
    now = airborne_guided(model, 10)
    assert model.body.height == pytest.approx(10, abs=0.25)

    goal = place.frame.cell_to_global((4, 3, 0))
    deliver(model, GCS.set_position_target_global_int_encode(
        0, 1, 1, ML.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, POSITION_ONLY, round(goal.lat * 1e7), round(goal.lon * 1e7),
        12.0, 0, 0, 0, 0, 0, 0, 0, 0), now)
    now = run_for(model, now, 20)
    want = place.frame.cell_to_ned((4, 3, 0))
    b, home = model.body, place.home
    assert math.dist((b.north, b.east, b.down), (want.north - home.north, want.east - home.east, -12)) < 0.25
    assert model.battery.remaining < 1.0 and model.battery.current_a > 10

    assert ack_of(model, now, ML.MAV_CMD_NAV_RETURN_TO_LAUNCH) == ML.MAV_RESULT_ACCEPTED
    now = run_for(model, now, 60)
    assert (model.armed, model.airborne) == (False, False)  # home, landed, disarmed
    assert math.hypot(model.body.north, model.body.east) < 0.6
    drained = model.battery.remaining
    now = run_for(model, now, 20)  # (not full yet: a charge of 10 A)
    assert model.battery.remaining > drained  # home is on a charging station
    assert battery_status(model, now).current_battery < 0


def test_model_velocity_setpoint_times_out_in_guided() -> None:
    (place,) = placements(None, 1)
    model = VehicleModel(ardupilot(ready_after_s=0.001), place, 0.0)
    now = airborne_guided(model, 5)
    velocity_only = 0b110111000111
    deliver(model, GCS.set_position_target_local_ned_encode(0, 1, 1, ML.MAV_FRAME_LOCAL_NED, velocity_only,
                                                            0, 0, 0, 2.0, 0, 0, 0, 0, 0, 0, 0), now)
    now = run_for(model, now, 2.5)
    assert model.body.vn == pytest.approx(2.0, abs=0.01)
    now = run_for(model, now, 3)  # ArduCopter stops a velocity setpoint that is not renewed for 3 s
    assert model.body.ground_speed < 0.01
    assert model.body.height == pytest.approx(5, abs=0.25)


def test_model_px4_takeoff_default_height_then_loiter() -> None:
    (place,) = placements(None, 1)
    model = VehicleModel(VehicleConfig(personality=PX4, ready_after_s=0.001), place, 0.0)
    assert ack_of(model, 1.0, ML.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, math.nan) == ML.MAV_RESULT_TEMPORARILY_REJECTED
    assert ack_of(model, 1.0, ML.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ML.MAV_RESULT_ACCEPTED
    # A take-off refused (its AMSL altitude below home) is refused with no effect: no mode change, no climb.
    below_home = model.home_global.alt_m - 5
    refused = ML.MAV_RESULT_TEMPORARILY_REJECTED
    assert ack_of(model, 1.0, ML.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, below_home) == refused
    run_for(model, 1.0, 3)
    assert (model.mode, model.body.height, model.takeoff_point) == ("AUTO.LOITER", 0.0, None)
    assert ack_of(model, 4.0, ML.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, math.nan) == ML.MAV_RESULT_ACCEPTED
    assert model.mode == "AUTO.TAKEOFF"
    run_for(model, 4.0, 8)
    assert model.mode == "AUTO.LOITER"
    assert model.body.height == pytest.approx(2.5, abs=0.3)


@pytest.mark.parametrize("personality", [ARDUPILOT, PX4], ids=lambda p: p.name)
def test_model_acks_every_command_even_with_nan_params(personality: Any) -> None:
    (place,) = placements(None, 1)
    model = VehicleModel(VehicleConfig(personality=personality, ready_after_s=0.001), place, 0.0)
    for cmd in [*model._commands, ML.MAV_CMD_DO_FLIGHTTERMINATION]:
        assert ack_of(model, 1.0, cmd, *[math.nan] * 7) in (ML.MAV_RESULT_ACCEPTED, ML.MAV_RESULT_DENIED,
                                                             ML.MAV_RESULT_FAILED, ML.MAV_RESULT_UNSUPPORTED,
                                                             ML.MAV_RESULT_TEMPORARILY_REJECTED)
    assert not model.armed  # a NaN arm request is refused, not taken as 0 or 1


@pytest.mark.parametrize("personality", [ARDUPILOT, PX4], ids=lambda p: p.name)
def test_model_reports_its_prearm_checks_in_sys_status(personality: Any) -> None:
    (place,) = placements(None, 1)
    model = VehicleModel(VehicleConfig(personality=personality, ready_after_s=2.0), place, 0.0)
    prearm = ML.MAV_SYS_STATUS_PREARM_CHECK
    booting = sys_status(model, 1.0)
    assert booting.onboard_control_sensors_present & booting.onboard_control_sensors_enabled & prearm
    assert not booting.onboard_control_sensors_health & prearm  # no position estimate yet: cannot arm
    assert sys_status(model, 2.0).onboard_control_sensors_health & prearm
    model.battery.remaining = 0.1
    assert not sys_status(model, 2.0).onboard_control_sensors_health & prearm


def test_model_px4_answers_ping_requests_and_ardupilot_does_not() -> None:
    (place,) = placements(None, 1)
    px4 = VehicleModel(VehicleConfig(personality=PX4), place, 0.0)
    (pong,) = deliver(px4, GCS.ping_encode(123456, 7, 0, 0), 1.0)
    assert (pong.get_type(), pong.time_usec, pong.seq, pong.target_system, pong.target_component) == \
        ("PING", 123456, 7, 255, 190)
    assert not deliver(px4, GCS.ping_encode(123456, 8, 1, 1), 1.0)  # a reply to our own ping: nothing
    assert not deliver(VehicleModel(VehicleConfig(personality=ARDUPILOT), place, 0.0),
                       GCS.ping_encode(123456, 7, 0, 0), 1.0)


def test_sim_vehicle_refuses_a_workspace_too_fast_for_its_vehicles(tmp_path: Path) -> None:
    fast = tmp_path / "fast.yaml"
    fast.write_text("size: [4, 4, 1]\ncell_size_m: 10\ntau_s: 1\ndrones: {a: [0, 0, 0]}\n")
    done = subprocess.run([sys.executable, "-m", "fleet.cli", "sim-vehicle", "--workspace", str(fast),
                           "--max-speed", "5"], capture_output=True, text=True, timeout=30, check=False)
    assert done.returncode == 2
    assert "tau_s: one cell per tau needs 10.00 m/s" in done.stderr


def test_vehicles_given_a_rate_at_once_stream_out_of_step_with_each_other() -> None:
    """Like independent autopilots: the same 4 Hz asked of 4 vehicles at the same moment gives each a
    message every 0.25 s, but not in one burst."""
    position = mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
    vehicles = [Streams({}, 0.0, phase=sysid * 0.6180339887) for sysid in range(1, 5)]
    for streams in vehicles:
        streams.set_interval(position, 250_000, 0.0)
    ticks = [k * 0.02 for k in range(1, 101)]  # 2 s of the simulator's 50 Hz steps
    sent = [[t for t in ticks if position in streams.due(t)] for streams in vehicles]
    assert all(7 <= len(times) <= 8 for times in sent)  # 4 Hz each
    assert all(0.23 <= b - a <= 0.27 for times in sent for a, b in itertools.pairwise(times))  # +/- a step
    firsts = [times[0] for times in sent]
    assert len({round(t, 3) for t in firsts}) == len(vehicles)  # no two in the same step
    assert max(firsts) - min(firsts) > 0.1


def test_a_vehicles_streams_asked_one_by_one_leave_together_and_keep_their_time() -> None:
    """A ground station asks for its streams one command after another: those at one rate (or at a
    multiple of it) still go out in the same tick, as an autopilot's stream groups do, and a late
    tick does not shift them apart."""
    local, glob = mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
    battery = mavlink2.MAVLINK_MSG_ID_BATTERY_STATUS
    streams = Streams({}, 0.0, phase=0.3)
    streams.set_interval(local, 100_000, 0.011)  # asked 20 ms apart, each acknowledged in between
    streams.set_interval(glob, 100_000, 0.031)
    streams.set_interval(battery, 400_000, 0.051)
    # The simulator's 50 Hz ticks, then one 0.263 s late (a stalled process): its ticks shift.
    ticks = [k * 0.02 for k in range(1, 151)] + [3.263 + k * 0.02 for k in range(50)]
    sent = {t: set(streams.due(t)) - {mavlink2.MAVLINK_MSG_ID_HEARTBEAT} for t in ticks}
    with_local = [t for t, ids in sent.items() if local in ids]
    assert all(glob in sent[t] for t in with_local) and all(local in sent[t] for t, ids in sent.items() if glob in ids)
    assert all(local in ids for ids in sent.values() if battery in ids)  # a quarter of the rate, same ticks
    assert 0.08 < statistics.median(b - a for a, b in itertools.pairwise(with_local)) < 0.12


def test_a_ticks_messages_share_datagrams_up_to_the_size_limit() -> None:
    frames = [bytes([i]) * size for i, size in enumerate([300, 500, 400, 900, 2000, 10])]
    datagrams = list(pack_datagrams(frames, limit=1400))
    assert b"".join(datagrams) == b"".join(frames)  # nothing lost, nothing reordered
    assert [len(d) for d in datagrams] == [1200, 900, 2000, 10]  # a frame over the limit goes alone
    assert list(pack_datagrams([])) == []


def test_cli_instance_starts_from_that_drone_and_is_refused_past_the_last(
        write_file: Callable[[str, str], Path], capsys: pytest.CaptureFixture[str]) -> None:
    ws_file = write_file("ws.yaml", "size: [4, 4, 1]\ndrones: {d1: [1, 0, 0], d2: [3, 0, 0]}\n")
    assert drona_main(["sim-vehicle", "--workspace", str(ws_file), "--instance", "1", "--count", "2"]) == 2
    assert "has 2 drone(s), 2 vehicles asked for from instance 1" in capsys.readouterr().err
    ws = load_workspace(ws_file)
    (place,) = placements(ws, 2, first=1)
    assert (math.floor(place.home.east / ws.cell_size_m), math.floor(place.home.north / ws.cell_size_m)) == (3, 0)
