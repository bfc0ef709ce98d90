"""The fake vehicle's sans-I/O model, driven by ``now``: setpoints, battery, acks, prearm checks,
and the streams of a fleet's vehicles.
"""

from __future__ import annotations

import itertools
import math
import os
import statistics
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

os.environ.setdefault("MAVLINK20", "1")  # before mavutil picks its dialect

from drona_gcs.workspace_files import load_workspace
from fleet.sim.config import VehicleConfig
from fleet.sim.fleet import pack_datagrams, placements
from fleet.sim.mav import mavlink2
from fleet.sim.model import VehicleModel
from fleet.sim.personality import ARDUPILOT, PX4
from fleet.sim.telemetry import Streams, battery_status, sys_status
from tests.fleet.sim.vehicle_helpers import GCS, ML, POSITION_ONLY, ack_of, airborne_guided, ardupilot, deliver, run_for


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
    assert model.body.vn == pytest.approx(2.0, abs=0.05)  # closed in on as ArduCopter's shaping does
    now = run_for(model, now, 4)  # ArduCopter stops a velocity setpoint that is not renewed for 3 s
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
