"""The fake vehicle refuses what the real autopilot refuses: each behaviour measured on ArduCopter SITL
(V4.7.0-dev; the step response at commit 90700977c5) that a ground station must cope with, on the
sans-I/O model driven by ``now``.

A ground station that passes against a forgiving fake and then leaves no real vehicle on the ground
is what these tests are for: each one failed on the fake before it was made this strict.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, TypeVar

import pytest

from fleet.sim.config import VehicleConfig
from fleet.sim.fleet import FleetConfig, SimClock, build_nodes, placements
from fleet.sim.mav import mavlink2
from fleet.sim.model import VehicleModel
from fleet.sim.params import ParamStore, Setting
from fleet.sim.personality import ARDUPILOT, PX4
from fleet.sim.telemetry import ekf_status_report, global_position_int, gps_raw_int, local_position_ned
from fleet.vehicle.policy import ekf_has_position
from tests.fleet.sim.vehicle_helpers import GCS, POSITION_ONLY, POSITION_VELOCITY, ack_of, deliver, run_for

ML = mavlink2
GUIDED = 4
ARM, TAKEOFF, SET_MODE = ML.MAV_CMD_COMPONENT_ARM_DISARM, ML.MAV_CMD_NAV_TAKEOFF, ML.MAV_CMD_DO_SET_MODE
M = TypeVar("M")


def arducopter(**settings: Any) -> VehicleModel:
    (place,) = placements(None, 1)
    return VehicleModel(VehicleConfig(personality=ARDUPILOT, **settings), place, 0.0)


def armed_and_taking_off(model: VehicleModel, now: float, height: float = 10.0) -> None:
    assert ack_of(model, now, SET_MODE, 1, GUIDED) == ML.MAV_RESULT_ACCEPTED
    assert ack_of(model, now, ARM, 1) == ML.MAV_RESULT_ACCEPTED
    assert ack_of(model, now, TAKEOFF, 0, 0, 0, 0, 0, 0, height) == ML.MAV_RESULT_ACCEPTED


def sent(message: M | None) -> M:
    """A message the model sends (None: it sends none)."""
    assert message is not None
    return message


def setpoint(model: VehicleModel, now: float, north: float, east: float, down: float) -> None:
    deliver(model, GCS.set_position_target_local_ned_encode(0, 1, 1, ML.MAV_FRAME_LOCAL_NED, POSITION_ONLY,
                                                            north, east, down, 0, 0, 0, 0, 0, 0, 0, 0), now)


def test_arducopter_takes_41_s_from_boot_to_its_position_estimate_and_says_so() -> None:
    """A GPS fix after about 10 s (type 6 in SITL), the EKF's absolute position after about 41.5 s. Before
    it: no local position, a global position at 0 degrees until the fix, arming refused; disarmed,
    GUIDED is taken anyway."""
    model = arducopter()
    assert (model.config.gps_s, model.config.ready_s) == (10.0, 41.5)
    early, fixed, ready = 5.0, 20.0, 42.0
    assert gps_raw_int(model, early).fix_type < 3 and sent(global_position_int(model, early)).lat == 0
    assert local_position_ned(model, early) is None
    assert gps_raw_int(model, fixed).fix_type == ML.GPS_FIX_TYPE_RTK_FIXED
    assert sent(global_position_int(model, fixed)).lat != 0 and local_position_ned(model, fixed) is None
    assert not ekf_has_position(sent(ekf_status_report(model, fixed)).flags, armed=False)
    assert ack_of(model, fixed, SET_MODE, 1, GUIDED) == ML.MAV_RESULT_ACCEPTED and model.mode == "GUIDED"
    assert ack_of(model, fixed, ARM, 1) == ML.MAV_RESULT_FAILED
    assert ekf_has_position(sent(ekf_status_report(model, ready)).flags, armed=False)
    assert local_position_ned(model, ready) is not None
    assert ack_of(model, ready, ARM, 1) == ML.MAV_RESULT_ACCEPTED


def test_the_boot_to_ready_time_may_be_shortened_but_not_switched_off() -> None:
    assert arducopter(ready_after_s=0.5).config.ready_s == 0.5
    with pytest.raises(ValueError, match="ready_after_s must be > 0"):
        VehicleConfig(personality=ARDUPILOT, ready_after_s=0.0)


def test_arducopter_spools_up_for_seconds_then_says_takeoff_until_it_is_up() -> None:
    """Its landed state: on the ground through the spool-up (3.5 s), taking off while it climbs, in the
    air once the take-off is over; ground stations wait on that, not on a timer of their own."""
    model = arducopter(ready_after_s=1.0)
    armed_and_taking_off(model, 1.0)
    now = run_for(model, 1.0, 3.0)
    assert (model.body.height, model.landed_state()) == (0.0, ML.MAV_LANDED_STATE_ON_GROUND)
    now = run_for(model, now, 1.5)
    assert model.body.height > 0.0 and model.landed_state() == ML.MAV_LANDED_STATE_TAKEOFF
    run_for(model, now, 12.0)
    assert model.body.height == pytest.approx(10.0, abs=0.3)
    assert model.landed_state() == ML.MAV_LANDED_STATE_IN_AIR


@pytest.mark.parametrize("after_s", [0.5, 3.0], ids=["at-once", "during-the-spool-up"])
def test_a_position_target_cancels_arducopters_takeoff_and_it_disarms_on_the_ground(after_s: float) -> None:
    """A setpoint in GUIDED switches ArduCopter to position control, which does nothing while landed:
    the take-off is over before it began. The vehicle stays down and disarms itself (DISARM_DELAY)."""
    model = arducopter(ready_after_s=1.0)
    armed_and_taking_off(model, 1.0)
    now = run_for(model, 1.0, after_s)
    setpoint(model, now, 0.0, 0.0, -10.0)  # where the take-off was going
    now = run_for(model, now, 8.0)
    assert (model.body.height, model.landed_state()) == (0.0, ML.MAV_LANDED_STATE_ON_GROUND)
    run_for(model, now, model.params.value("DISARM_DELAY"))
    assert not model.armed


def test_a_position_target_once_the_takeoff_is_over_is_flown() -> None:
    model = arducopter(ready_after_s=1.0)
    armed_and_taking_off(model, 1.0, height=5.0)
    now = run_for(model, 1.0, 10.0)
    assert model.landed_state() == ML.MAV_LANDED_STATE_IN_AIR
    setpoint(model, now, 8.0, 0.0, -5.0)
    run_for(model, now, 8.0)
    assert model.body.north == pytest.approx(8.0, abs=0.3)


def test_arducopter_carries_a_target_given_with_a_velocity_on_until_its_guided_timeout() -> None:
    """GUIDED takes a position given with a velocity as a moving target (``set_destination_posvelaccel``:
    its position controller moves the target on at the velocity, and feeds the velocity forward); with
    no update for GUID_TIMEOUT (3 s) the velocity is zeroed and the target stays where it got to."""
    model = arducopter(ready_after_s=1.0)
    armed_and_taking_off(model, 1.0, height=5.0)
    now = run_for(model, 1.0, 10.0)
    deliver(model, GCS.set_position_target_local_ned_encode(0, 1, 1, ML.MAV_FRAME_LOCAL_NED, POSITION_VELOCITY,
                                                            0.0, 0.0, -5.0, 0.0, 1.0, 0.0, 0, 0, 0, 0, 0), now)
    now = run_for(model, now, 2.0)
    carried = model.setpoint
    assert carried is not None and (carried.east, carried.ve) == pytest.approx((2.0, 1.0), abs=0.05)
    assert 1.0 < model.body.east < 2.0  # it keeps up, a little behind
    now = run_for(model, now, 3.0)
    stopped = model.setpoint
    assert stopped is not None and (stopped.east, stopped.ve) == pytest.approx((3.0, 0.0), abs=0.05)
    run_for(model, now, 5.0)
    assert model.body.east == pytest.approx(3.0, abs=0.1)


def test_every_arducopter_sitl_is_system_1_and_px4_instances_count_up() -> None:
    for personality, expected in ((ARDUPILOT, [1, 1, 1]), (PX4, [1, 2, 3])):
        config = FleetConfig(count=3, vehicle=dataclasses.replace(VehicleConfig(), personality=personality))
        nodes = build_nodes(config, None, SimClock())
        assert [node.system_id for node in nodes] == expected


def test_a_higher_wpnav_accel_closes_in_on_a_setpoint_more_slowly_as_arducopter_does() -> None:
    """ArduCopter shapes a position setpoint with the gain PSC_JERK_XY / (2 WPNAV_ACCEL): a real SITL
    flown one 1 m cell per 0.5 s reached its cells 1.3 s late at WPNAV_ACCEL 250 and 2.2 s at 500."""
    store = ParamStore(VehicleConfig(personality=ARDUPILOT))
    assert store.limits.gain == pytest.approx(1.0)
    store.set("WPNAV_ACCEL", 500.0)
    assert (store.limits.max_accel, store.limits.gain) == pytest.approx((5.0, 0.5))


def test_arducopters_lean_angle_and_attitude_controller_bound_its_acceleration_and_jerk() -> None:
    """``AC_PosControl::set_max_speed_accel_NE_m``: the jerk is at most half the root of the acceleration
    times the angular acceleration ATC_ACCEL_R_MAX/P_MAX allow (times g; 0: no bound), and the
    acceleration at most what ANGLE_MAX's lean gives. PSC_JERK_XY 20 at WPNAV_ACCEL 500 shapes at 15.3 m/s³;
    WPNAV_ACCEL 1000 flies at 5.66 m/s² at the default 30 degrees."""
    store = ParamStore(VehicleConfig(personality=ARDUPILOT))
    store.set("WPNAV_ACCEL", 500.0)
    store.set("PSC_JERK_XY", 20.0)
    assert store.limits.jerk == pytest.approx(0.5 * math.sqrt(5.0 * 1100 * math.pi / 180 * 9.80665))
    store.set("ATC_ACCEL_R_MAX", 0.0)
    store.set("ATC_ACCEL_P_MAX", 0.0)
    assert store.limits.jerk == 20.0
    store.set("WPNAV_ACCEL", 1000.0)
    assert store.limits.max_accel == pytest.approx(9.80665 * math.tan(math.radians(30)))
    store.set("ANGLE_MAX", 4600)
    assert store.limits.max_accel == 10.0


def test_the_battery_capacity_parameter_sets_how_fast_the_charge_falls() -> None:
    """The monitor counts the charge down from the capacity it is told (BATT_CAPACITY, PX4's BAT1_CAPACITY):
    a bigger pack lasts longer."""
    drained = {}
    for capacity in (5000.0, 20000.0):
        model = arducopter(ready_after_s=1.0)
        model.params.set("BATT_CAPACITY", capacity)
        armed_and_taking_off(model, 1.0)
        run_for(model, 1.0, 60.0)
        drained[capacity] = 1.0 - model.battery.remaining
    assert drained[5000.0] > 0 and drained[5000.0] == pytest.approx(4 * drained[20000.0], rel=0.05)
    px4 = ParamStore(VehicleConfig(personality=PX4))
    px4.set("BAT1_CAPACITY", 20000.0)
    assert px4.setting(Setting.BATTERY_CAPACITY) == 20000.0


def _crossings(model: VehicleModel, now: float, east: float, marks: tuple[float, ...]) -> tuple[list[float], float]:
    """Flown to ``east`` metres east for 10 s: the seconds until it is ``marks`` metres east of where it was,
    and the furthest east it went."""
    start, furthest = model.body.east, 0.0
    found: list[float] = []
    setpoint(model, now, model.body.north, start + east, model.body.down)
    for tick in range(1, 500):
        model.step(now + tick * 0.02)
        furthest = max(furthest, model.body.east - start)
        while len(found) < len(marks) and furthest >= marks[len(found)]:
            found.append(tick * 0.02)
    return found, furthest


def test_a_step_from_a_hover_is_crossed_as_late_as_a_real_arducopter_crosses_it() -> None:
    """ArduCopter SITL at its defaults (commit 90700977c5), hovering in GUIDED and sent 1 m east: 0.5 m after
    1.28 s, 0.9 m after 2.12 s, at most 1.02 m. Its jerk-limited shaping makes the start that slow; the fake
    without it crossed 0.5 m after 0.87 s, and so flew its plans' cells earlier than real vehicles fly them."""
    model = arducopter(ready_after_s=1.0)
    armed_and_taking_off(model, 1.0, height=2.0)
    now = run_for(model, 1.0, 15.0, dt=0.02)
    (half, most), furthest = _crossings(model, now, 1.0, (0.5, 0.9))
    assert half == pytest.approx(1.28, abs=0.1)
    assert most == pytest.approx(2.12, abs=0.1)
    assert furthest == pytest.approx(1.02, abs=0.04)


def _climbs(model: VehicleModel, now: float, up: float) -> tuple[list[float], float]:
    """Sent ``up`` metres up (negative: down) for 12 s: the seconds until it is half and 0.9 of the way,
    and the furthest share of the way it went."""
    start, furthest = model.body.down, 0.0
    found: list[float] = []
    setpoint(model, now, model.body.north, model.body.east, start - up)
    for tick in range(1, 600):
        model.step(now + tick * 0.02)
        furthest = max(furthest, (start - model.body.down) / up)
        while len(found) < 2 and furthest >= (0.5, 0.9)[len(found)]:
            found.append(tick * 0.02)
    return found, furthest


@pytest.mark.parametrize("up, real", [(1.0, (1.18, 1.74, 1.066)), (-1.0, (1.18, 1.76, 1.061)),
                                      (2.0, (1.58, 2.44, 1.027))])
def test_a_climb_from_a_hover_is_as_late_as_a_real_arducopters(up: float, real: tuple[float, float, float]) -> None:
    """ArduCopter SITL at its defaults (commit 90700977c5), hovering in GUIDED at 5 m and sent 1 m up, then
    down, then 2 m up: half way, 0.9 of the way (seconds), the furthest share. It shapes its vertical
    target as its horizontal one (WPNAV_ACCEL_Z 1 m/s², PSC_JERK_Z 5 m/s³); the fake without that,
    at 2.5 m/s², was half way up 1 m after 0.72 s: into a layer's cell earlier than a real one."""
    model = arducopter(ready_after_s=1.0)
    armed_and_taking_off(model, 1.0, height=5.0)
    now = run_for(model, 1.0, 20.0, dt=0.02)
    (half, most), furthest = _climbs(model, now, up)
    assert half == pytest.approx(real[0], abs=0.1)
    assert real[1] - 0.1 <= most <= real[1] + 0.3  # never sooner there than the real one
    assert 1.0 <= furthest <= real[2]


def test_a_take_off_climbs_as_late_as_a_real_arducopters() -> None:
    """ArduCopter SITL, taking off to 10 m in GUIDED: off the ground after 3.86 s (its spool-up), 5 m
    after 6.54 s, 9.75 m after 9.8 s. The fake climbing at 2.5 m/s² was at 9.75 m after 8.5 s."""
    model = arducopter(ready_after_s=1.0)
    armed_and_taking_off(model, 1.0, height=10.0)
    marks, found = (0.1, 5.0, 9.75), list[float]()
    for tick in range(1, 1000):
        model.step(1.0 + tick * 0.02)
        while len(found) < len(marks) and model.body.height >= marks[len(found)]:
            found.append(tick * 0.02)
    for seen, real in zip(found, (3.86, 6.54, 9.8), strict=True):
        assert real - 0.1 <= seen <= real + 0.6
