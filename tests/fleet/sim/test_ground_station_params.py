"""The fake vehicle towards a real ground station: the parameter protocol, and the values driving the
flight, as the autopilots give them (the sans-I/O model).
"""

from __future__ import annotations

import math
import struct
from typing import Any

import pytest

from fleet.cli import build_parser
from fleet.cli.sim_vehicle import _config as cli_config
from fleet.sim.config import VehicleConfig
from fleet.sim.model import VehicleModel
from fleet.sim.params import ARDUCOPTER_PARAMS, PARAMS_PER_STEP, TABLES
from fleet.sim.personality import ARDUPILOT, PX4, Personality
from fleet.sim.physics import Limits
from tests.fleet.sim.ground_station_helpers import BOTH, ML, SENDER, answers, param_set, vehicle
from tests.fleet.sim.vehicle_helpers import GCS, POSITION_ONLY, ack_of, airborne_guided, deliver, run_for

OFFBOARD = 6  #: PX4's main mode


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
    # Far enough to cruise: ArduCopter brakes on a curve of half its acceleration, from 40 m out at 10 m/s.
    now, peak = fly_to(model, now, 150.0, 5.0, 30.0)
    assert default - 0.05 < peak <= default + 1e-6
    (answer,) = param_set(model, name, value, now)
    assert answer.param_value == value
    now, peak = fly_to(model, now, 0.0, 5.0, 60.0)  # back: the new limit, in flight
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
