"""How each autopilot is commanded (fleet.vehicle.policy): what to send, what confirms it."""

from __future__ import annotations

import dataclasses
import math

import pytest

from drona_gcs.errors import VehicleError
from drona_gcs.geo import GeoPoint
from fleet.vehicle.link import Autopilot, LandedState, Telemetry
from fleet.vehicle.policy import (
    Expectation,
    arming,
    ekf_has_position,
    explains_refusal,
    in_air,
    landing,
    may_stream_setpoints,
    policy_of,
    switching,
    takeoff_params,
    takeoff_started,
)

GROUND = Telemetry(Autopilot.ARDUPILOT, True, "GUIDED", None, None, GeoPoint(47.0, 8.0, 584.5), 0.5, 90, 16.0, 3,
                   10, LandedState.ON_GROUND, 1.0)


def test_arducopter_takes_off_in_guided_to_a_height_above_home() -> None:
    assert policy_of(Autopilot.ARDUPILOT).takeoff_mode == "GUIDED"
    assert takeoff_params(GROUND, 8.0, "d1") == (0, 0, 0, 0, 0, 0, 8.0)


def test_px4_takes_off_to_an_altitude_above_mean_sea_level_with_the_rest_unset() -> None:
    px4 = dataclasses.replace(GROUND, autopilot=Autopilot.PX4)
    assert policy_of(Autopilot.PX4).takeoff_mode is None
    params = takeoff_params(px4, 8.0, "d1")
    assert params[:3] == (0, 0, 0) and all(math.isnan(p) for p in params[3:6])
    assert params[6] == pytest.approx(584.5 - 0.5 + 8.0)
    with pytest.raises(VehicleError, match="d1: no global position"):
        takeoff_params(dataclasses.replace(px4, height_m=None), 8.0, "d1")


@pytest.mark.parametrize("altitude", [0.0, -1.0, math.nan])
def test_a_takeoff_goes_up(altitude: float) -> None:
    with pytest.raises(ValueError, match="must be > 0"):
        takeoff_params(GROUND, altitude, "d1")


def test_an_autopilot_not_known_yet_is_flown_with_no_mode_names() -> None:
    assert policy_of(None) is policy_of(Autopilot.OTHER)
    assert policy_of(None).follow_mode is None and policy_of(None).land_mode is None
    assert landing(None).met(True, "custom_mode=77")
    assert (policy_of(Autopilot.ARDUPILOT).follow_mode, policy_of(Autopilot.PX4).follow_mode) == ("GUIDED", "OFFBOARD")
    assert policy_of(Autopilot.PX4).setpoints_first and not policy_of(Autopilot.ARDUPILOT).setpoints_first


def test_arducopter_gets_setpoints_only_armed_and_once_its_takeoff_is_over() -> None:
    """A setpoint ends ArduCopter's take-off: it stays on the ground and disarms."""
    taking_off = dataclasses.replace(GROUND, landed=LandedState.TAKEOFF, height_m=3.0)
    assert not may_stream_setpoints(GROUND) and not may_stream_setpoints(taking_off)
    up = dataclasses.replace(taking_off, landed=LandedState.IN_AIR)
    assert may_stream_setpoints(up)
    assert not may_stream_setpoints(dataclasses.replace(up, armed=False))
    for autopilot in (Autopilot.PX4, Autopilot.OTHER):
        assert may_stream_setpoints(dataclasses.replace(GROUND, autopilot=autopilot, armed=False))


def test_without_a_landed_state_the_height_tells() -> None:
    unknown = dataclasses.replace(GROUND, landed=LandedState.UNDEFINED, height_m=0.2)
    assert not in_air(unknown) and not takeoff_started(unknown)
    assert in_air(dataclasses.replace(unknown, height_m=0.4))
    assert takeoff_started(dataclasses.replace(unknown, height_m=0.4))
    assert not takeoff_started(dataclasses.replace(GROUND, height_m=0.8)), "on the ground above home"
    assert takeoff_started(dataclasses.replace(GROUND, landed=LandedState.TAKEOFF))
    assert not in_air(dataclasses.replace(GROUND, landed=LandedState.TAKEOFF, height_m=5.0))


def test_expectations_say_what_confirms_and_what_went_wrong() -> None:
    assert arming(True) == Expectation("ARM", armed=True) and arming(False).label == "DISARM"
    assert arming(True).met(True, None) and not arming(True).met(False, "GUIDED")
    assert arming(False).failure("GUIDED") == "is still armed"
    guided = switching("GUIDED")
    assert guided.label == "DO_SET_MODE GUIDED" and guided.met(False, "GUIDED") and not guided.met(True, "LAND")
    assert guided.failure("STABILIZE") == "stayed in STABILIZE"
    assert landing(Autopilot.PX4).mode == "AUTO.LAND" and landing(Autopilot.ARDUPILOT).mode == "LAND"


def test_warnings_and_worse_explain_a_refusal() -> None:
    assert explains_refusal(4) and explains_refusal(0) and not explains_refusal(5) and not explains_refusal(6)


def test_arducopters_rule_for_a_position_estimate() -> None:
    horiz_abs, pred_horiz_abs, const_pos = 16, 512, 128
    assert ekf_has_position(pred_horiz_abs, armed=False) and not ekf_has_position(pred_horiz_abs, armed=True)
    assert ekf_has_position(horiz_abs, armed=True)
    assert not ekf_has_position(horiz_abs | const_pos, armed=True)
    assert not ekf_has_position(0, armed=False)
