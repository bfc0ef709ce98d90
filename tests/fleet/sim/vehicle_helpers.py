"""Shared harness of the fake vehicle's tests (``test_vehicle*.py``, ``test_ground_station*.py``,
``test_strictness.py``): a fleet in a thread, pymavlink's ground-station connection, waits that are
bounded, and the sans-I/O model driven by ``now``.
"""

from __future__ import annotations

import contextlib
import os
import select
import subprocess
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

os.environ.setdefault("MAVLINK20", "1")  # before mavutil picks its dialect
from pymavlink import mavutil

from fleet.sim.config import VehicleConfig
from fleet.sim.mav import mavlink2
from fleet.sim.model import VehicleModel
from fleet.sim.personality import ARDUPILOT

ML = mavutil.mavlink
REPO = Path(__file__).resolve().parents[3]
GUIDED, STABILIZE = 4, 0
POSITION_ONLY = 0b110111111000  # SET_POSITION_TARGET type_mask: use x, y, z only
POSITION_VELOCITY = 0b110111000000  # x, y, z and vx, vy, vz


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


def ardupilot(**vehicle: Any) -> VehicleConfig:
    return replace(VehicleConfig(personality=ARDUPILOT), **vehicle)


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
    return run_for(model, now, 12)  # ArduCopter SITL: 9.75 m of a 10 m take-off after 9.8 s
