"""A vehicle's parameters judged against the workspace's ``vehicle`` limits."""

from __future__ import annotations

from drona_gcs.workspace import ARDUCOPTER, VehicleLimits
from fleet.vehicle.limits import parameters_to_read, shortfalls
from fleet.vehicle.link import Autopilot

#: ArduCopter 4.5's defaults, as its parameters hold them (cm, cdeg), and SITL's speedup.
DEFAULTS = {"WPNAV_SPEED": 1000.0, "WPNAV_ACCEL": 250.0, "PSC_JERK_XY": 5.0, "WPNAV_SPEED_UP": 250.0,
            "WPNAV_SPEED_DN": 150.0, "WPNAV_ACCEL_Z": 100.0, "PSC_JERK_Z": 5.0, "ANGLE_MAX": 3000.0,
            "SIM_SPEEDUP": 1.0}


def test_an_arducopter_at_its_defaults_flies_the_default_workspace_and_is_read_whole() -> None:
    assert set(parameters_to_read(Autopilot.ARDUPILOT)) == set(DEFAULTS)
    assert shortfalls(Autopilot.ARDUPILOT, DEFAULTS, ARDUCOPTER) == []


def test_each_limit_set_short_is_named_with_what_it_gives() -> None:
    quicker = VehicleLimits(speed_m_s=12.0, accel_m_s2=3.0, jerk_m_s3=6.0, climb_m_s=3.0, descent_m_s=2.0,
                            accel_z_m_s2=1.5, jerk_z_m_s3=8.0)
    assert shortfalls(Autopilot.ARDUPILOT, DEFAULTS, quicker) == [
        "WPNAV_SPEED 1000 gives 10, under the workspace's vehicle.speed_m_s 12",
        "WPNAV_ACCEL 250 gives 2.5, under the workspace's vehicle.accel_m_s2 3",
        "PSC_JERK_XY 5 gives 5, under the workspace's vehicle.jerk_m_s3 6",
        "WPNAV_SPEED_UP 250 gives 2.5, under the workspace's vehicle.climb_m_s 3",
        "WPNAV_SPEED_DN 150 gives 1.5, under the workspace's vehicle.descent_m_s 2",
        "WPNAV_ACCEL_Z 100 gives 1, under the workspace's vehicle.accel_z_m_s2 1.5",
        "PSC_JERK_Z 5 gives 5, under the workspace's vehicle.jerk_z_m_s3 8"]


def test_the_lean_angle_bounds_the_acceleration_and_silence_is_a_shortfall() -> None:
    """WPNAV_ACCEL 1000 at the default 30 degrees flies 5.66 m/s², not 10."""
    tuned = {**DEFAULTS, "WPNAV_ACCEL": 1000.0}
    assert shortfalls(Autopilot.ARDUPILOT, tuned, VehicleLimits(accel_m_s2=10.0)) == [
        "ANGLE_MAX 3000 leans to 5.66 m/s² at most, under the workspace's vehicle.accel_m_s2 10"]
    assert shortfalls(Autopilot.ARDUPILOT, {**tuned, "ANGLE_MAX": 4600.0}, VehicleLimits(accel_m_s2=10.0)) == []
    silent = {k: v for k, v in DEFAULTS.items() if k != "PSC_JERK_XY"}
    assert shortfalls(Autopilot.ARDUPILOT, silent, ARDUCOPTER) == [
        "PSC_JERK_XY did not answer (the workspace's vehicle.jerk_m_s3 is 5)"]


def test_a_sped_up_simulator_flies_its_limits_in_the_fleets_seconds() -> None:
    """At SIM_SPEEDUP 6, WPNAV_ACCEL 250 is 90 m/s² on the wall clock, PSC_JERK_XY 5 is 1080 m/s³."""
    fast = {**DEFAULTS, "SIM_SPEEDUP": 6.0}
    assert shortfalls(Autopilot.ARDUPILOT, fast, ARDUCOPTER.sped_up(6.0)) == []
    assert shortfalls(Autopilot.ARDUPILOT, DEFAULTS, ARDUCOPTER.sped_up(6.0))[0].startswith(
        "WPNAV_SPEED 1000 gives 10, under the workspace's vehicle.speed_m_s 60")


def test_px4_is_judged_by_its_own_parameters_and_an_unknown_autopilot_not_at_all() -> None:
    px4 = {"MPC_XY_VEL_MAX": 12.0, "MPC_ACC_HOR": 3.0, "MPC_Z_VEL_MAX_UP": 3.0, "MPC_Z_VEL_MAX_DN": 1.0,
           "MPC_ACC_UP_MAX": 4.0, "MPC_ACC_DOWN_MAX": 0.5}
    assert set(parameters_to_read(Autopilot.PX4)) == set(px4)
    assert shortfalls(Autopilot.PX4, px4, ARDUCOPTER) == [
        "MPC_Z_VEL_MAX_DN 1 gives 1, under the workspace's vehicle.descent_m_s 1.5",
        "MPC_ACC_DOWN_MAX 0.5 gives 0.5, under the workspace's vehicle.accel_z_m_s2 1"]
    assert parameters_to_read(Autopilot.OTHER) == [] and shortfalls(Autopilot.OTHER, {}, ARDUCOPTER) == []
