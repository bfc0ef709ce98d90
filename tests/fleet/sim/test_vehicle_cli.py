"""The fake vehicle's command (``drona sim-vehicle``), run in a subprocess: its vehicles, serial
lines, the flags it refuses and how it stops.
"""

from __future__ import annotations

import asyncio
import json
import math
import os
import re
import select
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

os.environ.setdefault("MAVLINK20", "1")  # before mavutil picks its dialect

from drona_gcs.geo import GeoFrame
from drona_gcs.workspace_files import load_workspace
from fleet.cli import main as drona_main
from fleet.sim.fleet import placements
from fleet.sim.ports import free_udp_base
from fleet.sim.transport import SERIAL_TX_BUFFER, PtyLink
from tests.fleet.sim.vehicle_helpers import ML, REPO, command, ground_station, stderr_lines, wait_for


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


def test_cli_records_where_each_vehicle_was_at_each_step(write_file: Callable[[str, str], Path],
                                                         tmp_path: Path) -> None:
    """``--record``: a line per vehicle per step (tau 0.2 s), from the vehicles' physics, under its own
    drone's name and start cell; refused without a workspace."""
    ws_file = write_file("ws.yaml", "size: [4, 4, 1]\ncell_size_m: 1\ntau_s: 0.2\n"
                         "drones: {d1: [1, 0, 0], d2: [3, 2, 0]}\n")
    record = tmp_path / "truth.jsonl"
    assert drona_main(["sim-vehicle", "--record", str(record)]) == 2
    proc = subprocess.Popen([sys.executable, "-m", "fleet.cli", "sim-vehicle", "--workspace", str(ws_file),
                             "--count", "2", "--base-port", str(free_udp_base(2)), "--record", str(record)],
                            cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        stderr_lines(proc, 2, 10)  # both vehicles up
        time.sleep(1.5)  # a real-time record: some steps of it
    finally:
        err = terminate(proc)
    assert proc.returncode == 0, err.decode()
    lines = [json.loads(line) for line in record.read_text().splitlines()]
    for drone, cell in (("d1", [1, 0, 0]), ("d2", [3, 2, 0])):
        steps = [r["step"] for r in lines if r["drone"] == drone]
        assert len(steps) >= 5 and steps == list(range(steps[0], steps[0] + len(steps))), steps
        assert {tuple(r["cell"]) for r in lines if r["drone"] == drone} == {tuple(cell)}
    assert all(r["planned"] is None and r["delta"] == 0 for r in lines)


def test_cli_instance_starts_from_that_drone_and_is_refused_past_the_last(
        write_file: Callable[[str, str], Path], capsys: pytest.CaptureFixture[str]) -> None:
    ws_file = write_file("ws.yaml", "size: [4, 4, 1]\ndrones: {d1: [1, 0, 0], d2: [3, 0, 0]}\n")
    assert drona_main(["sim-vehicle", "--workspace", str(ws_file), "--instance", "1", "--count", "2"]) == 2
    assert "has 2 drone(s), 2 vehicles asked for from instance 1" in capsys.readouterr().err
    ws = load_workspace(ws_file)
    (place,) = placements(ws, 2, first=1)
    assert (math.floor(place.home.east / ws.cell_size_m), math.floor(place.home.north / ws.cell_size_m)) == (3, 0)
