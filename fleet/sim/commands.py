"""The fake vehicle's answers to COMMAND_LONG and COMMAND_INT, one function per command: a result
(MAV_RESULT) and the messages that follow its ACK. A command not in :data:`COMMANDS` is unsupported.

Each refuses what its autopilot refuses (see :mod:`fleet.sim.model` for the rules): with the
personality's ``rejected`` result and, where the autopilot says why, a STATUSTEXT.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import TYPE_CHECKING

from fleet.sim import telemetry
from fleet.sim.mav import Message, mavlink2
from fleet.sim.params import Setting
from fleet.sim.personality import ARDUPILOT, Behaviour
from fleet.sim.physics import Target

if TYPE_CHECKING:
    from fleet.sim.model import VehicleModel

ACCEPTED: int = mavlink2.MAV_RESULT_ACCEPTED
UNSUPPORTED: int = mavlink2.MAV_RESULT_UNSUPPORTED
FORCE_MAGIC = 21196  #: MAV_CMD_COMPONENT_ARM_DISARM param2 that forces arming or disarming


@dataclass(frozen=True)
class Command:
    """COMMAND_LONG and COMMAND_INT, alike: params 1..7 (COMMAND_INT's x, y, z as 5..7)."""

    command: int
    params: tuple[float, float, float, float, float, float, float]
    frame: int | None  #: COMMAND_INT's frame; None for COMMAND_LONG
    source: tuple[int, int]


def arm_disarm(m: VehicleModel, cmd: Command, now: float) -> tuple[int, list[Message]]:
    arm, force = _int(cmd.params[0]), _int(cmd.params[1]) == FORCE_MAGIC
    if arm not in (0, 1):
        return mavlink2.MAV_RESULT_DENIED, []
    if arm == 0:
        if m.armed and m.airborne and not force:
            m.text(mavlink2.MAV_SEVERITY_CRITICAL, "Disarm: vehicle is flying")
            return m.personality.rejected, []
        m.disarm(now)
        return ACCEPTED, []
    if m.armed:
        return ACCEPTED, []
    if not force:
        reason = m.arming_problem(now)
        if reason:
            m.text(mavlink2.MAV_SEVERITY_CRITICAL, reason)
            return m.personality.rejected, []
    m.armed = True
    m.flown = False
    m.landed_since = now
    if m.personality is not ARDUPILOT:  # PX4 climbs to the offboard setpoint once spooled up
        m.climb_at = now + m.config.spool_s
    return ACCEPTED, []


def set_mode(m: VehicleModel, cmd: Command, now: float) -> tuple[int, list[Message]]:
    base, main, sub = (_int(p) for p in cmd.params[:3])
    if base is None or main is None:
        return m.personality.rejected, []
    return m.change_mode(base, m.personality.mode_from_command(main, sub or 0), now), []


def takeoff(m: VehicleModel, cmd: Command, now: float) -> tuple[int, list[Message]]:
    """Refused with no effect at all, or accepted: a take-off after the spool-up."""
    p = m.personality
    if not m.armed or m.airborne or m.takeoff_point is not None:
        return p.rejected, []
    if p is ARDUPILOT:
        if m.behaviour is not Behaviour.FOLLOW:
            return p.rejected, []
        height = cmd.params[6]
    else:  # PX4: param7 is AMSL, NaN for the default height
        relative = cmd.frame in (mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)
        alt = cmd.params[6]
        height = (m.params.setting(Setting.TAKEOFF_ALT) if math.isnan(alt)
                  else alt if relative else alt - m.home_global.alt_m)
    if not height > 0:
        return p.rejected, []
    m.climb_at = now + m.config.spool_s
    m.takeoff_point = Target(m.body.north, m.body.east, -height)
    if p is ARDUPILOT:
        m.setpoint = m.takeoff_point  # GUIDED then holds there
    elif p.takeoff_mode:
        m.enter_mode(p.takeoff_mode, now)
    return ACCEPTED, []


def land(m: VehicleModel, cmd: Command, now: float) -> tuple[int, list[Message]]:
    m.enter_mode(m.personality.land_mode, now)
    return ACCEPTED, []


def rtl(m: VehicleModel, cmd: Command, now: float) -> tuple[int, list[Message]]:
    if not m.ready(now):
        return m.personality.rejected, []
    m.enter_mode(m.personality.rtl_mode, now)
    return ACCEPTED, []


def message_interval(m: VehicleModel, cmd: Command, now: float) -> tuple[int, list[Message]]:
    msg_id, interval_us = _int(cmd.params[0]), cmd.params[1]
    if msg_id not in telemetry.STREAMABLE or not math.isfinite(interval_us):
        return m.personality.rejected, []  # HEARTBEAT too: it stays at 1 Hz
    m.streams.set_interval(msg_id, interval_us, now)
    return ACCEPTED, []


def request_message(m: VehicleModel, cmd: Command, now: float) -> tuple[int, list[Message]]:
    build = telemetry.REQUESTABLE.get(_int(cmd.params[0]) or 0)
    msg = None if build is None else build(m, now)
    if msg is None:  # unknown, or not known yet (home before the position estimate)
        return m.personality.rejected, []
    return ACCEPTED, [msg]


def request_version(m: VehicleModel, cmd: Command, now: float) -> tuple[int, list[Message]]:
    return ACCEPTED, [telemetry.autopilot_version(m, now)]


def get_home(m: VehicleModel, cmd: Command, now: float) -> tuple[int, list[Message]]:
    home = telemetry.home_position(m, now)
    return (m.personality.rejected, []) if home is None else (ACCEPTED, [home])


def _int(value: float) -> int | None:
    """A command parameter as an integer; None for NaN or infinity ("no value")."""
    return round(value) if math.isfinite(value) else None


#: A command's answer: model, command, now -> (MAV_RESULT, messages after the ACK).
Run = Callable[["VehicleModel", Command, float], tuple[int, list[Message]]]

#: Read-only: each model takes its own copy.
COMMANDS: Mapping[int, Run] = MappingProxyType({
    mavlink2.MAV_CMD_COMPONENT_ARM_DISARM: arm_disarm,
    mavlink2.MAV_CMD_DO_SET_MODE: set_mode,
    mavlink2.MAV_CMD_NAV_TAKEOFF: takeoff,
    mavlink2.MAV_CMD_NAV_LAND: land,
    mavlink2.MAV_CMD_NAV_RETURN_TO_LAUNCH: rtl,
    mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL: message_interval,
    mavlink2.MAV_CMD_REQUEST_MESSAGE: request_message,
    mavlink2.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: request_version,
    mavlink2.MAV_CMD_GET_HOME_POSITION: get_home,
})
