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

Both links follow :class:`AutopilotPolicy` for what to send (which mode a take-off is sent in, what
NAV_TAKEOFF's altitude means), and an :class:`Expectation` for what confirms an acknowledged command
from the HEARTBEATs after its ACK: an autopilot may ACK what it does not do.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from drona_gcs.errors import VehicleError
from fleet.vehicle.link import Autopilot, LandedState, Telemetry


@dataclass(frozen=True)
class Timeouts:
    """How long a vehicle may take, in seconds: settings, since real vehicles differ."""

    takeoff_start_s: float = 10.0  #: an accepted take-off to leaving the ground (motor spool-up)
    command_s: float = 30.0  #: a whole take-off or landing sequence


DEFAULT_TIMEOUTS = Timeouts()
CONFIRM_HEARTBEATS = 2  #: PX4 may send one more HEARTBEAT with the old state after its ACK


class Command(enum.IntEnum):
    """The MAV_CMDs both links send."""

    NAV_LAND = 21
    NAV_TAKEOFF = 22
    DO_SET_MODE = 176
    COMPONENT_ARM_DISARM = 400
    SET_MESSAGE_INTERVAL = 511


class Result(enum.IntEnum):
    """MAV_RESULT: anything but ACCEPTED (and IN_PROGRESS, which is no answer yet) is a refusal."""

    ACCEPTED = 0
    TEMPORARILY_REJECTED = 1
    DENIED = 2
    UNSUPPORTED = 3
    FAILED = 4
    IN_PROGRESS = 5


SERIOUS = 4  #: MAV_SEVERITY_WARNING: STATUSTEXTs at this severity or worse explain a refusal
CUSTOM_MODE_ENABLED = 1  #: MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, DO_SET_MODE's first param


def explains_refusal(severity: int) -> bool:
    return severity <= SERIOUS


@dataclass(frozen=True)
class AutopilotPolicy:
    """How one autopilot is commanded (see the module docstring)."""

    follow_mode: str | None  #: the mode that follows setpoints (None: none known)
    land_mode: str | None  #: the mode a NAV_LAND puts it in (None: none known)
    takeoff_mode: str | None  #: switched to before NAV_TAKEOFF (ArduCopter takes off in GUIDED only)
    takeoff_amsl: bool  #: NAV_TAKEOFF's altitude is above mean sea level (PX4), not above home
    setpoints_first: bool  #: refuses its follow mode until setpoints stream (PX4's OFFBOARD)
    setpoints_in_takeoff: bool  #: may get setpoints before its take-off is over (ArduCopter may not)


POLICIES = {
    Autopilot.ARDUPILOT: AutopilotPolicy("GUIDED", "LAND", "GUIDED", takeoff_amsl=False, setpoints_first=False,
                                         setpoints_in_takeoff=False),
    Autopilot.PX4: AutopilotPolicy("OFFBOARD", "AUTO.LAND", None, takeoff_amsl=True, setpoints_first=True,
                                   setpoints_in_takeoff=True),
    Autopilot.OTHER: AutopilotPolicy(None, None, None, takeoff_amsl=True, setpoints_first=False,
                                     setpoints_in_takeoff=True),
}


def policy_of(autopilot: Autopilot | None) -> AutopilotPolicy:
    """An autopilot's policy; one not known yet is flown as :attr:`Autopilot.OTHER`."""
    return POLICIES[autopilot or Autopilot.OTHER]


def takeoff_params(t: Telemetry, altitude_m: float, who: str) -> tuple[float, ...]:
    """NAV_TAKEOFF's seven params for a climb to ``altitude_m`` above home. PX4 wants the altitude
    AMSL: home's is the global position's altitude minus the height above home."""
    if not altitude_m > 0:
        raise ValueError(f"takeoff altitude must be > 0, got {altitude_m}")
    if not policy_of(t.autopilot).takeoff_amsl:
        return 0, 0, 0, 0, 0, 0, altitude_m
    if t.global_position is None or t.height_m is None:
        raise VehicleError(f"{who}: no global position, cannot take off")
    return 0, 0, 0, math.nan, math.nan, math.nan, t.global_position.alt_m - t.height_m + altitude_m


@dataclass(frozen=True)
class Expectation:
    """What the HEARTBEATs after a command's ACK must show: the armed state, the mode (None: any)."""

    label: str  #: the command, as a refusal names it
    armed: bool | None = None
    mode: str | None = None

    def met(self, armed: bool, mode: str | None) -> bool:
        return (self.armed is None or armed == self.armed) and (self.mode is None or mode == self.mode)

    def failure(self, mode: str | None) -> str:
        """What the vehicle did instead, in the vehicle's mode ``mode``."""
        if self.armed is not None:
            return "is still disarmed" if self.armed else "is still armed"
        return f"stayed in {mode}"


def arming(arm: bool) -> Expectation:
    return Expectation("ARM" if arm else "DISARM", armed=arm)


def switching(mode: str, label: str = "") -> Expectation:
    return Expectation(label or f"DO_SET_MODE {mode}", mode=mode)


def landing(autopilot: Autopilot | None) -> Expectation:
    """A landing is confirmed by the land mode, where the autopilot has one."""
    return Expectation("LAND", mode=policy_of(autopilot).land_mode)


#: EKF_STATUS_REPORT flags (EKF_STATUS_FLAGS) that give an absolute horizontal position.
EKF_POS_HORIZ_ABS, EKF_PRED_POS_HORIZ_ABS, EKF_CONST_POS_MODE = 16, 512, 128
LIFTOFF_M = 0.3  #: a vehicle that says no landed state is off the ground above this height


def may_stream_setpoints(t: Telemetry) -> bool:
    """Whether movement setpoints may go out now (see the module docstring)."""
    return policy_of(t.autopilot).setpoints_in_takeoff or (t.armed and in_air(t))


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
