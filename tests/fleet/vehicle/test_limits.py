"""A vehicle's parameters judged against the workspace's ``vehicle`` limits."""

from __future__ import annotations

import asyncio

import pytest

from drona_gcs.workspace import ARDUCOPTER, VehicleLimits
from fleet.vehicle.limits import bound_flying_on, parameters_to_read, shortfalls
from fleet.vehicle.link import Autopilot
from tests.fakes.vehicle import FakeVehicle

#: ArduCopter 4.5's defaults, as its parameters hold them (cm, cdeg, s), and SITL's speedup.
DEFAULTS = {"WPNAV_SPEED": 1000.0, "WPNAV_ACCEL": 250.0, "PSC_JERK_XY": 5.0, "WPNAV_SPEED_UP": 250.0,
            "WPNAV_SPEED_DN": 150.0, "WPNAV_ACCEL_Z": 100.0, "PSC_JERK_Z": 5.0, "ANGLE_MAX": 3000.0,
            "GUID_TIMEOUT": 3.0, "SIM_SPEEDUP": 1.0}
TAU = 0.5
#: As an agent leaves them at tau 0.5 s: flying on a quarter of a second at most once it stops.
READY = {**DEFAULTS, "GUID_TIMEOUT": 0.25}


def test_an_arducopter_at_its_defaults_flies_the_default_workspace_and_is_read_whole() -> None:
    assert set(parameters_to_read(Autopilot.ARDUPILOT)) == set(DEFAULTS)
    assert shortfalls(Autopilot.ARDUPILOT, READY, ARDUCOPTER, TAU) == []


def test_an_arducopter_that_would_fly_on_seconds_once_its_agent_stops_is_named() -> None:
    """GUID_TIMEOUT 3 (its default): a killed agent's vehicle flew on 3 s along its last sweep, four cells
    across its peers' paths. Half a period keeps it in the next cell of its plan."""
    assert shortfalls(Autopilot.ARDUPILOT, DEFAULTS, ARDUCOPTER, TAU) == [
        "GUID_TIMEOUT 3 flies it on 3 s along its last setpoint once its agent stops, over half a period (0.25 s)"]
    assert shortfalls(Autopilot.ARDUPILOT, {**DEFAULTS, "SIM_SPEEDUP": 12.0}, ARDUCOPTER.sped_up(12.0), TAU) == []
    silent = {k: v for k, v in READY.items() if k != "GUID_TIMEOUT"}
    assert shortfalls(Autopilot.ARDUPILOT, silent, ARDUCOPTER, TAU) == [
        "GUID_TIMEOUT did not answer (a vehicle may fly on 0.25 s at most once its agent stops)"]
    assert shortfalls(Autopilot.ARDUPILOT, silent, ARDUCOPTER, TAU, unanswered=False) == []


@pytest.mark.parametrize("speedup, held, expected", [(1.0, 3.0, 0.25), (6.0, 3.0, 1.5), (1.0, 0.2, None)])
def test_an_agent_sets_how_long_its_arducopter_flies_on_to_half_a_period(speedup: float, held: float,
                                                                          expected: float | None) -> None:
    """In the simulator's own seconds when sped up; one set shorter already is left as it is."""
    vehicle = FakeVehicle()
    vehicle.parameters = {**READY, "GUID_TIMEOUT": held, "SIM_SPEEDUP": speedup}
    values = asyncio.run(bound_flying_on(vehicle, Autopilot.ARDUPILOT, dict(vehicle.parameters), TAU, "d1"))
    assert values["GUID_TIMEOUT"] == (held if expected is None else expected)
    assert vehicle.commands == ([] if expected is None else ["PARAM_SET GUID_TIMEOUT"])
    px4 = asyncio.run(bound_flying_on(vehicle, Autopilot.PX4, {"MPC_ACC_HOR": 3.0}, TAU, "d1"))
    assert px4 == {"MPC_ACC_HOR": 3.0}


def test_each_limit_set_short_is_named_with_what_it_gives() -> None:
    quicker = VehicleLimits(speed_m_s=12.0, accel_m_s2=3.0, jerk_m_s3=6.0, climb_m_s=3.0, descent_m_s=2.0,
                            accel_z_m_s2=1.5, jerk_z_m_s3=8.0)
    assert shortfalls(Autopilot.ARDUPILOT, READY, quicker, TAU) == [
        "WPNAV_SPEED 1000 gives 10, under the workspace's vehicle.speed_m_s 12",
        "WPNAV_ACCEL 250 gives 2.5, under the workspace's vehicle.accel_m_s2 3",
        "PSC_JERK_XY 5 gives 5, under the workspace's vehicle.jerk_m_s3 6",
        "WPNAV_SPEED_UP 250 gives 2.5, under the workspace's vehicle.climb_m_s 3",
        "WPNAV_SPEED_DN 150 gives 1.5, under the workspace's vehicle.descent_m_s 2",
        "WPNAV_ACCEL_Z 100 gives 1, under the workspace's vehicle.accel_z_m_s2 1.5",
        "PSC_JERK_Z 5 gives 5, under the workspace's vehicle.jerk_z_m_s3 8"]


def test_the_lean_angle_bounds_the_acceleration_and_silence_is_a_shortfall() -> None:
    """WPNAV_ACCEL 1000 at the default 30 degrees flies 5.66 m/s², not 10."""
    tuned = {**READY, "WPNAV_ACCEL": 1000.0}
    assert shortfalls(Autopilot.ARDUPILOT, tuned, VehicleLimits(accel_m_s2=10.0), TAU) == [
        "ANGLE_MAX 3000 leans to 5.66 m/s² at most, under the workspace's vehicle.accel_m_s2 10"]
    assert shortfalls(Autopilot.ARDUPILOT, {**tuned, "ANGLE_MAX": 4600.0}, VehicleLimits(accel_m_s2=10.0), TAU) == []
    silent = {k: v for k, v in READY.items() if k != "PSC_JERK_XY"}
    assert shortfalls(Autopilot.ARDUPILOT, silent, ARDUCOPTER, TAU) == [
        "PSC_JERK_XY did not answer (the workspace's vehicle.jerk_m_s3 is 5)"]


def test_a_sped_up_simulator_flies_its_limits_in_the_fleets_seconds() -> None:
    """At SIM_SPEEDUP 6, WPNAV_ACCEL 250 is 90 m/s² on the wall clock, PSC_JERK_XY 5 is 1080 m/s³."""
    fast = {**READY, "SIM_SPEEDUP": 6.0}
    assert shortfalls(Autopilot.ARDUPILOT, fast, ARDUCOPTER.sped_up(6.0), TAU) == []
    assert shortfalls(Autopilot.ARDUPILOT, READY, ARDUCOPTER.sped_up(6.0), TAU)[0].startswith(
        "WPNAV_SPEED 1000 gives 10, under the workspace's vehicle.speed_m_s 60")


def test_px4_is_judged_by_its_own_parameters_and_an_unknown_autopilot_not_at_all() -> None:
    px4 = {"MPC_XY_VEL_MAX": 12.0, "MPC_ACC_HOR": 3.0, "MPC_Z_VEL_MAX_UP": 3.0, "MPC_Z_VEL_MAX_DN": 1.0,
           "MPC_ACC_UP_MAX": 4.0, "MPC_ACC_DOWN_MAX": 0.5}
    assert set(parameters_to_read(Autopilot.PX4)) == set(px4)
    assert shortfalls(Autopilot.PX4, px4, ARDUCOPTER, TAU) == [
        "MPC_Z_VEL_MAX_DN 1 gives 1, under the workspace's vehicle.descent_m_s 1.5",
        "MPC_ACC_DOWN_MAX 0.5 gives 0.5, under the workspace's vehicle.accel_z_m_s2 1"]
    assert parameters_to_read(Autopilot.OTHER) == [] and shortfalls(Autopilot.OTHER, {}, ARDUCOPTER, TAU) == []
