"""How each autopilot is flown from a ground station: the rules both link backends follow.

Measured on ArduCopter SITL (V4.7.0-dev) and read in its sources:

* a movement setpoint in GUIDED switches ArduCopter out of its take-off sub-mode into position
  control (``mode_guided.cpp``), which does nothing while the vehicle is landed: a setpoint streamed
  from arming on keeps it on the ground, and it disarms itself ten seconds later. So no setpoint goes
  out from arming until the take-off is complete, which ArduCopter reports itself: its landed state
  is TAKEOFF while it climbs and IN_AIR once done (``GCS_Mavlink.cpp``, ``landed_state()``);
* its motors spool up for about 3.5 s between an accepted NAV_TAKEOFF and leaving the ground;
* it refuses to arm for about 45 s after boot ("Arm: Need Position Estimate"), until its EKF has an
  absolute position, which EKF_STATUS_REPORT says (flags ``POS_HORIZ_ABS`` or, disarmed,
  ``PRED_POS_HORIZ_ABS``: ``Copter::ekf_has_absolute_position``); before that it sends no
  LOCAL_POSITION_NED and a GLOBAL_POSITION_INT at 0 degrees latitude and longitude.

PX4 leaves OFFBOARD without a setpoint stream, so there setpoints stream from the start, and it
climbs to the streamed setpoint by itself.
"""

from __future__ import annotations

from dataclasses import dataclass

from fleet.vehicle.link import Autopilot, LandedState, Telemetry


@dataclass(frozen=True)
class Timeouts:
    """How long a vehicle may take, in seconds: settings, since real vehicles differ."""

    takeoff_start_s: float = 10.0  #: an accepted take-off to leaving the ground (motor spool-up)
    command_s: float = 30.0  #: a whole take-off or landing sequence


DEFAULT_TIMEOUTS = Timeouts()

#: EKF_STATUS_REPORT flags (EKF_STATUS_FLAGS) that give an absolute horizontal position.
EKF_POS_HORIZ_ABS, EKF_PRED_POS_HORIZ_ABS, EKF_CONST_POS_MODE = 16, 512, 128
LIFTOFF_M = 0.3  #: a vehicle that says no landed state is off the ground above this height


def may_stream_setpoints(t: Telemetry) -> bool:
    """Whether movement setpoints may go out now (see the module docstring)."""
    if t.autopilot is not Autopilot.ARDUPILOT:
        return True
    return t.armed and in_air(t)


def in_air(t: Telemetry) -> bool:
    """Flying, its take-off over: IN_AIR by the landed state (ArduCopter says TAKEOFF until its take-off
    is complete), or by the height where the autopilot reports no landed state."""
    if t.landed is LandedState.UNDEFINED:
        return (t.height_m or 0.0) > LIFTOFF_M
    return t.landed is LandedState.IN_AIR


def takeoff_started(t: Telemetry) -> bool:
    """Left the ground, or climbing by the landed state."""
    return t.landed in (LandedState.TAKEOFF, LandedState.IN_AIR) or (
        (t.height_m or 0.0) > LIFTOFF_M and t.landed is not LandedState.ON_GROUND)


def ekf_has_position(flags: int, armed: bool) -> bool:
    """ArduCopter's own rule for arming and for GUIDED (``Copter::ekf_has_absolute_position``)."""
    if not armed:
        return bool(flags & (EKF_POS_HORIZ_ABS | EKF_PRED_POS_HORIZ_ABS))
    return bool(flags & EKF_POS_HORIZ_ABS) and not flags & EKF_CONST_POS_MODE
