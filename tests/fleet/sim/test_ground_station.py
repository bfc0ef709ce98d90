"""The fake vehicle towards a real ground station: parameters, missions and SYS_STATUS as the autopilots give them.

MAVProxy (from PyPI, a subprocess) connects to ``drona sim-vehicle`` (another subprocess) in each
personality and downloads the parameters and the mission lists, as a pilot's ``param show`` and
``wp list`` do. Against a fake that ignored PARAM_REQUEST_LIST and MISSION_REQUEST_LIST it printed
nothing, timed out on MAVLink FTP and reported a fence breach. The fast tests drive the sans-I/O model:
the parameter protocol, the values driving the flight, the mission protocol and the geofence bits.
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import socket
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from fleet.cli import build_parser
from fleet.cli.sim_vehicle import _config as cli_config
from fleet.sim.config import VehicleConfig
from fleet.sim.fleet import placements
from fleet.sim.ftp import ACK, HEADER, NAK
from fleet.sim.mav import mavlink2
from fleet.sim.model import VehicleModel
from fleet.sim.params import ARDUCOPTER_PARAMS, PARAMS_PER_STEP, TABLES
from fleet.sim.personality import ARDUPILOT, PX4, Personality
from fleet.sim.physics import Limits
from fleet.sim.ports import free_port
from fleet.sim.telemetry import sys_status
from tests.fleet.sim.test_vehicle import (
    GCS,
    POSITION_ONLY,
    REPO,
    ack_of,
    airborne_guided,
    deliver,
    run_for,
    stderr_lines,
)

ML = mavlink2
BOTH = pytest.mark.parametrize("personality", [ARDUPILOT, PX4], ids=lambda p: p.name)
OFFBOARD = 6  #: PX4's main mode
SENDER = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)


# ------------------------------------------------------------------ harness
def vehicle(personality: Personality, **settings: Any) -> VehicleModel:
    (place,) = placements(None, 1)
    settings.setdefault("ready_after_s", 0.001)
    return VehicleModel(VehicleConfig(personality=personality, **settings), place, 0.0)


def answers(model: VehicleModel, msg: Any, now: float = 1.0) -> list[Any]:
    """What the vehicle answers to ``msg``; every answer must encode (its fields within their types)."""
    out = deliver(model, msg, now)
    for reply in out:
        reply.pack(SENDER)
    return out


def streamed(model: VehicleModel, now: float, steps: int = 20) -> list[Any]:
    """The PARAM_VALUEs of ``steps`` steps, checking each step sends at most PARAMS_PER_STEP."""
    out = []
    for i in range(steps):
        values = [m for m in model.step(now + 0.02 * (i + 1)) if m.get_type() == "PARAM_VALUE"]
        assert len(values) <= PARAMS_PER_STEP
        out += values
    for msg in out:
        msg.pack(SENDER)
    return out


def param_set(model: VehicleModel, name: str, value: float, now: float = 1.0) -> list[Any]:
    return answers(model, GCS.param_set_encode(1, 1, name.encode(), value, ML.MAV_PARAM_TYPE_REAL32), now)


def setpoint(model: VehicleModel, now: float, north: float, down: float) -> None:
    deliver(model, GCS.set_position_target_local_ned_encode(0, 1, 1, ML.MAV_FRAME_LOCAL_NED, POSITION_ONLY,
                                                            north, 0, down, 0, 0, 0, 0, 0, 0, 0, 0), now)


def airborne(model: VehicleModel, height: float = 5.0) -> float:
    """Armed and hovering ``height`` m over home: ArduCopter by a GUIDED take-off, PX4 in OFFBOARD."""
    if model.personality is ARDUPILOT:
        return airborne_guided(model, height)
    now = 1.0
    assert ack_of(model, now, ML.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ML.MAV_RESULT_ACCEPTED
    setpoint(model, now, 0.0, -height)
    assert ack_of(model, now, ML.MAV_CMD_DO_SET_MODE, 1, OFFBOARD) == ML.MAV_RESULT_ACCEPTED
    now, _ = fly_to(model, now, 0.0, height, 10.0)
    return now


def fly_to(model: VehicleModel, now: float, north: float, height: float, seconds: float) -> tuple[float, float]:
    """Stream a position setpoint at 10 Hz for ``seconds``; returns the time then and the peak ground speed."""
    peak = 0.0
    for _ in range(round(seconds / 0.1)):
        setpoint(model, now, north, -height)
        now = run_for(model, now, 0.1, dt=0.02)
        peak = max(peak, model.body.ground_speed)
    return now, peak


# ------------------------------------------------------------------ parameters
@BOTH
def test_param_list_streams_every_parameter_with_its_index_paced(personality: Personality) -> None:
    model = vehicle(personality)
    table = TABLES[personality.name]
    first = answers(model, GCS.param_request_list_encode(1, 1))
    assert [m.text for m in first] == (["ArduCopter V4.5.7", "Frame: QUAD/X"] if personality is ARDUPILOT else [])
    values = streamed(model, 1.0)
    if personality is PX4:  # first its hash of every value, for a ground station's cache
        hash_check = values.pop(0)
        assert (hash_check.param_id, hash_check.param_index) == ("_HASH_CHECK", 65535)
    assert [m.param_index for m in values] == list(range(len(table)))
    assert {m.param_count for m in values} == {len(table)}
    assert [(m.param_id, m.param_type) for m in values] == [(p.name, p.type) for p in table]
    by_name = {m.param_id: m for m in values}
    if personality is ARDUPILOT:
        assert (by_name["WPNAV_SPEED"].param_value, by_name["LAND_SPEED"].param_value) == (1000.0, 50.0)
        assert by_name["SYSID_THISMAV"].param_type == ML.MAV_PARAM_TYPE_INT16
    else:  # PX4 sends an INT32's bytes as the float
        assert by_name["MPC_XY_VEL_MAX"].param_value == 12.0
        assert by_name["MAV_SYS_ID"].get_payload()[:4] == (1).to_bytes(4, "little")
    assert not streamed(model, 2.0)  # once


@BOTH
def test_param_read_by_name_or_by_index(personality: Personality) -> None:
    model = vehicle(personality)
    table = TABLES[personality.name]
    speed = "WPNAV_SPEED" if personality is ARDUPILOT else "MPC_XY_VEL_MAX"
    (by_name,) = answers(model, GCS.param_request_read_encode(1, 1, speed.encode(), -1))
    assert (by_name.param_id, by_name.param_index) == (speed, [p.name for p in table].index(speed))
    (by_index,) = answers(model, GCS.param_request_read_encode(1, 1, b"ignored", 2))
    assert (by_index.param_id, by_index.param_index, by_index.param_count) == (table[2].name, 2, len(table))
    assert not answers(model, GCS.param_request_read_encode(1, 1, b"NO_SUCH_PARAM", -1))  # as ArduPilot and PX4
    beyond = answers(model, GCS.param_request_read_encode(1, 1, b"", len(table)))
    assert [m.text for m in beyond] == ([] if personality is ARDUPILOT else [f"[pm] unknown param ID: {len(table)}"])


def test_param_set_stores_and_answers_the_value_as_each_autopilot_does() -> None:
    copter = vehicle(ARDUPILOT)
    (value,) = param_set(copter, "LAND_SPEED", 30.7)  # an INT16: ArduPilot truncates
    assert (value.param_id, value.param_value, value.param_type) == ("LAND_SPEED", 30.0, ML.MAV_PARAM_TYPE_INT16)
    assert copter.params.value("LAND_SPEED") == 30.0
    assert not param_set(copter, "NO_SUCH_PARAM", 1.0)  # ArduPilot: no answer
    assert not param_set(copter, "WPNAV_SPEED", math.nan)
    assert copter.params.value("WPNAV_SPEED") == 1000.0

    px4 = vehicle(PX4)
    bytewise = struct.unpack("<f", (4).to_bytes(4, "little"))[0]  # an INT32 as MAVProxy sends it to PX4
    (value,) = param_set(px4, "GF_ACTION", bytewise)
    assert (value.param_id, value.get_payload()[:4], px4.params.value("GF_ACTION")) == \
        ("GF_ACTION", (4).to_bytes(4, "little"), 4.0)
    assert [m.text for m in param_set(px4, "NO_SUCH_PARAM", 1.0)] == ["[pm] unknown param: NO_SUCH_PARAM"]


@pytest.mark.parametrize(("personality", "name", "value", "speed"),
                         [(ARDUPILOT, "WPNAV_SPEED", 300, 3.0), (PX4, "MPC_XY_VEL_MAX", 3.0, 3.0)],
                         ids=["ardupilot", "px4"])
def test_setting_the_speed_parameter_changes_how_fast_it_flies(personality: Personality, name: str, value: float,
                                                               speed: float) -> None:
    model = vehicle(personality)
    default = model.params.limits.max_speed
    assert default == (10.0 if personality is ARDUPILOT else 12.0)
    now = airborne(model)
    now, peak = fly_to(model, now, 60.0, 5.0, 20.0)
    assert default - 0.05 < peak <= default + 1e-6
    (answer,) = param_set(model, name, value, now)
    assert answer.param_value == value
    now, peak = fly_to(model, now, 0.0, 5.0, 30.0)  # back: the new limit, in flight
    assert speed - 0.05 < peak <= speed + 1e-6
    assert math.hypot(model.body.north, model.body.east) < 0.5


@pytest.mark.parametrize(("personality", "name"), [(ARDUPILOT, "DISARM_DELAY"), (PX4, "COM_DISARM_PRFLT")],
                         ids=["ardupilot", "px4"])
def test_the_disarm_delay_parameter_drives_the_auto_disarm(personality: Personality, name: str) -> None:
    model = vehicle(personality)
    assert model.params.value(name) == 10
    param_set(model, name, 3)
    assert ack_of(model, 1.0, ML.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ML.MAV_RESULT_ACCEPTED
    now = run_for(model, 1.0, 2.5)
    assert model.armed
    run_for(model, now, 1.0)
    assert not model.armed


def test_px4_disarms_com_disarm_land_after_a_touchdown() -> None:
    px4 = vehicle(PX4)
    now = airborne(px4, 2.0)
    end = now + 10
    while px4.airborne and now < end:  # a setpoint under the ground in OFFBOARD, no landing mode
        now, _ = fly_to(px4, now, 0.0, -1.0, 0.1)
    touchdown = now
    while px4.armed and now < end:
        now, _ = fly_to(px4, now, 0.0, -1.0, 0.1)
    assert now - touchdown == pytest.approx(px4.params.value("COM_DISARM_LAND"), abs=0.15)  # 2 s, not 10


def test_px4_takes_off_to_mis_takeoff_alt_and_arducopter_returns_at_rtl_alt() -> None:
    px4 = vehicle(PX4)
    param_set(px4, "MIS_TAKEOFF_ALT", 6.0)
    assert ack_of(px4, 1.0, ML.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ML.MAV_RESULT_ACCEPTED
    assert ack_of(px4, 1.0, ML.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, math.nan) == ML.MAV_RESULT_ACCEPTED
    run_for(px4, 1.0, 10)
    assert px4.body.height == pytest.approx(6.0, abs=0.3)

    copter = vehicle(ARDUPILOT)
    now = airborne(copter)
    now, _ = fly_to(copter, now, 20.0, 5.0, 10.0)
    param_set(copter, "RTL_ALT", 2500, now)  # cm
    assert ack_of(copter, now, ML.MAV_CMD_NAV_RETURN_TO_LAUNCH) == ML.MAV_RESULT_ACCEPTED
    run_for(copter, now, 12)
    assert copter.body.height == pytest.approx(25.0, abs=0.3)


def test_a_config_or_the_cli_gives_the_parameters_their_starting_values() -> None:
    five = vehicle(ARDUPILOT, limits=Limits(max_speed=5), auto_disarm_s=60.0)  # as callers gave them before
    assert (five.params.limits.max_speed, five.params.value("WPNAV_SPEED"), five.params.value("DISARM_DELAY")) == \
        (5.0, 500.0, 60.0)
    px4 = vehicle(PX4, limits=Limits(max_speed=5), offboard_timeout_s=5.0)
    assert (px4.params.value("MPC_XY_VEL_MAX"), px4.params.value("COM_OF_LOSS_T")) == (5.0, 5.0)

    def parsed(*flags: str) -> VehicleConfig:
        return cli_config(build_parser("sim-vehicle").parse_args(["sim-vehicle", *flags])).vehicle

    assert parsed().limits is None and parsed().auto_disarm_s is None  # the autopilot's defaults
    given = vehicle(PX4, limits=parsed("--autopilot", "px4", "--max-speed", "7").limits).params
    assert (given.value("MPC_XY_VEL_MAX"), given.value("MPC_ACC_HOR"), given.value("MPC_LAND_SPEED")) == (7.0, 3.0, 0.7)


def test_px4_answers_parameter_and_mission_requests_for_its_own_system_id_only() -> None:
    broadcast = (GCS.param_request_list_encode(0, 0), GCS.mission_request_list_encode(0, 0, 0))
    px4, copter = vehicle(PX4), vehicle(ARDUPILOT)
    assert not [m for msg in broadcast for m in answers(px4, msg)] and not streamed(px4, 1.0)
    assert [m.get_type() for msg in broadcast for m in answers(copter, msg)] == [
        "STATUSTEXT", "STATUSTEXT", "MISSION_COUNT"]  # ArduPilot takes broadcasts: its banner, the count
    assert len(streamed(copter, 1.0)) == len(ARDUCOPTER_PARAMS)


# ------------------------------------------------------------------ missions
@BOTH
def test_mission_counts_are_ardupilots_home_or_nothing(personality: Personality) -> None:
    model = vehicle(personality)
    counts = {}
    for kind in (ML.MAV_MISSION_TYPE_MISSION, ML.MAV_MISSION_TYPE_FENCE, ML.MAV_MISSION_TYPE_RALLY):
        (reply,) = answers(model, GCS.mission_request_list_encode(1, 1, kind))
        assert (reply.get_type(), reply.mission_type, reply.target_system, reply.target_component) == \
            ("MISSION_COUNT", kind, 255, 190)
        counts[kind] = reply.count
    assert list(counts.values()) == ([1, 0, 0] if personality is ARDUPILOT else [0, 0, 0])
    (unknown,) = answers(model, GCS.mission_request_list_encode(1, 1, 7))
    assert (unknown.get_type(), unknown.type) == ("MISSION_ACK", ML.MAV_MISSION_UNSUPPORTED)


def test_arducopters_mission_item_0_is_home() -> None:
    model = vehicle(ARDUPILOT)
    (item,) = answers(model, GCS.mission_request_int_encode(1, 1, 0, ML.MAV_MISSION_TYPE_MISSION))
    home = model.home_global
    assert (item.get_type(), item.seq, item.command, item.frame, item.autocontinue, item.mission_type) == \
        ("MISSION_ITEM_INT", 0, ML.MAV_CMD_NAV_WAYPOINT, ML.MAV_FRAME_GLOBAL, 1, 0)
    assert (item.x, item.y, item.z) == (round(home.lat * 1e7), round(home.lon * 1e7), pytest.approx(home.alt_m))
    (legacy,) = answers(model, GCS.mission_request_encode(1, 1, 0, ML.MAV_MISSION_TYPE_MISSION))
    assert (legacy.get_type(), legacy.x, legacy.y) == ("MISSION_ITEM", pytest.approx(home.lat), pytest.approx(home.lon))
    booting = vehicle(ARDUPILOT, ready_after_s=30.0)  # home is set with the position estimate
    (early,) = answers(booting, GCS.mission_request_int_encode(1, 1, 0, ML.MAV_MISSION_TYPE_MISSION))
    assert (early.x, early.y, early.z) == (0, 0, 0.0)


@BOTH
def test_a_mission_request_out_of_range(personality: Personality) -> None:
    model = vehicle(personality)
    (count,) = answers(model, GCS.mission_request_list_encode(1, 1, ML.MAV_MISSION_TYPE_MISSION))  # as a GCS does
    assert count.count == (1 if personality is ARDUPILOT else 0)
    beyond = answers(model, GCS.mission_request_int_encode(1, 1, count.count, ML.MAV_MISSION_TYPE_MISSION))
    fence = answers(model, GCS.mission_request_int_encode(1, 1, 0, ML.MAV_MISSION_TYPE_FENCE))
    legacy = answers(model, GCS.mission_request_encode(1, 1, 5, ML.MAV_MISSION_TYPE_MISSION))
    if personality is PX4:  # no transfer under way: PX4 ignores the request without a word
        assert beyond == fence == legacy == []
        return
    # ArduPilot repeats the count ("to educate the GCS"), then refuses; the legacy request only refuses.
    assert [(m.get_type(), getattr(m, "count", None)) for m in beyond] == [("MISSION_COUNT", 1), ("MISSION_ACK", None)]
    for refused, kind in ((beyond[-1], 0), (fence[-1], 1), (legacy[-1], 0)):
        assert (refused.type, refused.mission_type) == (ML.MAV_MISSION_INVALID_SEQUENCE, kind)
    assert len(legacy) == 1


@BOTH
def test_uploads_but_empty_ones_are_refused_and_a_mission_ack_needs_no_answer(personality: Personality) -> None:
    model = vehicle(personality)
    (upload,) = answers(model, GCS.mission_count_encode(1, 1, 3, ML.MAV_MISSION_TYPE_MISSION))
    (empty,) = answers(model, GCS.mission_count_encode(1, 1, 0, ML.MAV_MISSION_TYPE_FENCE))
    (clear,) = answers(model, GCS.mission_clear_all_encode(1, 1, ML.MAV_MISSION_TYPE_ALL))
    assert [(m.type, m.mission_type) for m in (upload, empty, clear)] == [
        (ML.MAV_MISSION_UNSUPPORTED, 0), (ML.MAV_MISSION_ACCEPTED, 1), (ML.MAV_MISSION_ACCEPTED, 255)]
    assert not answers(model, GCS.mission_ack_encode(1, 1, ML.MAV_MISSION_ACCEPTED, 0))
    assert "MISSION_ACK" not in model.unhandled


# ------------------------------------------------------------------ SYS_STATUS and FTP
def test_arducopters_geofence_is_present_healthy_and_enabled_by_fence_enable() -> None:
    copter = vehicle(ARDUPILOT)
    fence = ML.MAV_SYS_STATUS_GEOFENCE
    status = sys_status(copter, 1.0)
    assert status.onboard_control_sensors_present & status.onboard_control_sensors_health & fence
    assert not status.onboard_control_sensors_enabled & fence  # FENCE_ENABLE 0
    param_set(copter, "FENCE_ENABLE", 1)
    assert sys_status(copter, 1.0).onboard_control_sensors_enabled & fence
    px4 = sys_status(vehicle(PX4), 1.0)  # PX4's SYS_STATUS has no geofence bits
    assert not (px4.onboard_control_sensors_present | px4.onboard_control_sensors_health) & fence


@BOTH
def test_ftp_requests_are_refused_at_once_so_a_ground_station_falls_back(personality: Personality) -> None:
    model = vehicle(personality)
    name = b"@PARAM/param.pck"
    open_ro = HEADER.pack(7, 0, 4, len(name), 0, 0, 0, 0) + name  # OpenFileRO, seq 7
    (nak,) = answers(model, GCS.file_transfer_protocol_encode(0, 1, 1, open_ro.ljust(251, b"\0")))
    assert (nak.target_system, nak.target_component) == (255, 190)
    seq, _, opcode, size, req_opcode = HEADER.unpack_from(bytes(nak.payload))[:5]
    assert (seq, opcode, size, req_opcode, nak.payload[HEADER.size]) == (8, NAK, 1, 4, 10)  # ERR_FileNotFound
    terminate = HEADER.pack(9, 0, 1, 0, 0, 0, 0, 0)
    (ack,) = answers(model, GCS.file_transfer_protocol_encode(0, 1, 1, terminate.ljust(251, b"\0")))
    assert HEADER.unpack_from(bytes(ack.payload))[2] == ACK


# ------------------------------------------------------------------ MAVProxy
class MAVProxy:
    """``mavproxy.py`` in a subprocess: its output collected by a thread, commands written to its stdin."""

    def __init__(self, master: str, workdir: Path) -> None:
        script = Path(sys.executable).with_name("mavproxy.py")
        env = {**os.environ, "PYTHONUNBUFFERED": "1", "HOME": str(workdir)}  # no user's .mavinit.scr
        self.proc = subprocess.Popen([sys.executable, str(script), "--master", master], cwd=workdir, env=env,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True)
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    @property
    def output(self) -> str:
        return "\n".join(self.lines)

    def wait_for(self, *texts: str, timeout: float) -> None:
        self.wait_until(lambda out: all(t in out for t in texts), f"{list(texts)}", timeout)

    def wait_until(self, printed: Callable[[str], bool], what: str, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while not printed(self.output):
            if time.monotonic() > deadline or self.proc.poll() is not None:
                pytest.fail(f"MAVProxy did not print {what} within {timeout} s:\n{self.output}")
            time.sleep(0.05)

    def send(self, *commands: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write("".join(f"{c}\n" for c in commands))
        self.proc.stdin.flush()

    def stop(self) -> None:
        """End of input: MAVProxy exits (killed after 10 s)."""
        with contextlib.suppress(BrokenPipeError, OSError):
            assert self.proc.stdin is not None
            self.proc.stdin.close()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self._reader.join(5)
        assert self.proc.stdout is not None
        self.proc.stdout.close()


@contextlib.contextmanager
def sim_vehicle(personality: Personality) -> Iterator[str]:
    """``drona sim-vehicle`` on its SITL's link (ArduPilot: a TCP server, PX4: UDP to the ground station);
    yields MAVProxy's --master."""
    tcp = personality is ARDUPILOT
    port = free_port(socket.SOCK_STREAM if tcp else socket.SOCK_DGRAM)
    flags = ["--autopilot", personality.name, "--base-port", str(port), "--ready-after", "0.2", *(["--tcp"] * tcp)]
    proc = subprocess.Popen([sys.executable, "-m", "fleet.cli", "sim-vehicle", *flags], cwd=REPO,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        assert "sim-vehicle: system 1" in stderr_lines(proc, 1, 10)[0]
        yield f"tcp:127.0.0.1:{port}" if tcp else f"udpin:127.0.0.1:{port}"
    finally:
        proc.terminate()
        try:
            proc.communicate(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()


def shown_values(out: str) -> dict[str, str]:
    """``param show``'s lines (``NAME  value``, after any prompts) as name -> value."""
    return dict(re.findall(r"^(?:\S+> )*([A-Z][A-Z0-9_]+)\s+(-?[\d.]+)$", out, re.MULTILINE))


@BOTH
def test_mavproxy_downloads_the_parameters_and_the_mission(personality: Personality, tmp_path: Path) -> None:
    pytest.importorskip("MAVProxy", reason="MAVProxy (the dev extra) is not installed")
    ardupilot = personality is ARDUPILOT
    count = len(TABLES[personality.name])
    with sim_vehicle(personality) as master:
        mavproxy = MAVProxy(master, tmp_path)
        try:
            mavproxy.wait_for("online system 1", timeout=20)
            # Its stream rates asked again at once (MAVProxy asks every 15 s): SYS_STATUS for the fence module.
            mavproxy.send("set streamrate 5", "wp list", "fence list", "rally list")
            mission = ["Requesting 1 waypoints", "16 0 ", "Saved 1 waypoints"] if ardupilot else \
                ["Requesting 0 waypoints"]
            fence = ["fence present"] if ardupilot else []  # MAVProxy saw ArduCopter's SYS_STATUS
            mavproxy.wait_for(f"Received {count} parameters", *mission, "Requesting 0 fence items",
                              "Requesting 0 rally items", *fence, timeout=20)
            shown = ("WPNAV_SPEED", "SYSID_THISMAV") if ardupilot else ("MPC_XY_VEL_MAX", "MAV_SYS_ID")
            mavproxy.send(*(f"param show {name}" for name in shown))
            mavproxy.wait_until(lambda out: set(shown) <= set(shown_values(out)), f"{shown}'s values", timeout=5)
            time.sleep(1.0)  # whatever MAVProxy has still to say about what it received
        finally:
            mavproxy.stop()
    out = mavproxy.output
    values = shown_values(out)
    if ardupilot:
        assert (values["WPNAV_SPEED"], values["SYSID_THISMAV"]) == ("1000.0", "1.0")
        # Not anchored: under load MAVProxy's prompt may come first on the line.
        (item,) = re.findall(r"(?<!\S)16 0 (\S+) (\S+) (\S+) p1=", out)
        home = placements(None, 1)[0]
        want = home.frame.ned_to_global(home.home)
        assert [float(v) for v in item] == [pytest.approx(want.lat, abs=1e-7), pytest.approx(want.lon, abs=1e-7),
                                            pytest.approx(want.alt_m, abs=1e-3)]
        assert "fence breach" not in out
    else:  # an INT32 sent bytewise, read back as PX4's
        assert (values["MPC_XY_VEL_MAX"], values["MAV_SYS_ID"]) == ("12.0", "1")
        # (Real PX4's SYS_STATUS has no geofence bit, which MAVProxy's fence module reports as a breach.)
    assert not re.search(r"time(d)? ?out", out, re.IGNORECASE), out
    assert "Traceback" not in out
