"""The pymavlink backend's telemetry: which streams it asks for, and the latest messages read as a
:class:`~fleet.vehicle.link.Telemetry`.

Positions: without a frame they are LOCAL_POSITION_NED (the autopilot's local NED frame, origin at
its EKF origin, usually home); with a :class:`~drona_gcs.geo.GeoFrame` GLOBAL_POSITION_INT in that
workspace's frame, so vehicles with different homes share one frame.
"""

from __future__ import annotations

from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from drona_gcs.geo import GeoFrame, GeoPoint, Ned
from fleet.vehicle.link import Autopilot, LandedState, Position, Share, Telemetry, not_ready
from fleet.vehicle.policy import ekf_has_position
from fleet.vehicle.session import MavlinkSession

Message = Any  # pymavlink's MAVLink_message: untyped
#: Streams requested with MAV_CMD_SET_MESSAGE_INTERVAL: message id -> rate as a fraction of ``stream_hz``.
STREAMS = {mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED: Share.POSITION,
           mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: Share.POSITION,
           mavlink2.MAVLINK_MSG_ID_BATTERY_STATUS: Share.STATUS, mavlink2.MAVLINK_MSG_ID_SYS_STATUS: Share.STATUS,
           mavlink2.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: Share.LANDED, mavlink2.MAVLINK_MSG_ID_GPS_RAW_INT: Share.GPS}
#: With a workspace frame, positions and velocities come from GLOBAL_POSITION_INT alone: the local
#: position is asked off (rates are set per link: a GCS sharing the vehicle keeps its own).
FRAMED_STREAMS = {**STREAMS, mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED: Share.OFF}
#: ArduPilot's own word on its position estimate (see fleet.vehicle.policy); PX4 does not know the message.
ARDUPILOT_STREAMS = {mavlink2.MAVLINK_MSG_ID_EKF_STATUS_REPORT: Share.STATUS}
#: The message types kept as the latest of their kind: what telemetry is read from.
KEPT = ("LOCAL_POSITION_NED", "GLOBAL_POSITION_INT", "SYS_STATUS", "BATTERY_STATUS", "GPS_RAW_INT",
        "EXTENDED_SYS_STATE", "EKF_STATUS_REPORT")
_UNKNOWN_U16 = 0xFFFF
POSITION_KINDS = frozenset({"LOCAL_POSITION_NED", "GLOBAL_POSITION_INT"})


def streams_for(frame: GeoFrame | None, autopilot: Autopilot | None) -> dict[int, Share]:
    """The telemetry asked for: message id -> rate as a share of ``stream_hz``."""
    common = STREAMS if frame is None else FRAMED_STREAMS
    return {**common, **ARDUPILOT_STREAMS} if autopilot is Autopilot.ARDUPILOT else common


class Latest:
    """The latest message of each kept type, with the link clock time it came."""

    def __init__(self) -> None:
        self.kept: dict[str, tuple[float, Message]] = {}
        #: the position last read, and the frame it is in, until a position comes (read at every look)
        self._where: tuple[GeoFrame | None, Position | None] | None = None

    def keep(self, msg: Message, now: float) -> None:
        kind = msg.get_type()
        self.kept[kind] = (now, msg)
        if kind in POSITION_KINDS:
            self._where = None

    def clear(self) -> None:
        self.kept.clear()
        self._where = None

    def get(self, kind: str) -> Message | None:
        entry = self.kept.get(kind)
        return None if entry is None else entry[1]

    def position(self, frame: GeoFrame | None) -> Position | None:
        """LOCAL_POSITION_NED; with ``frame``, GLOBAL_POSITION_INT in the workspace frame."""
        if self._where is None or self._where[0] is not frame:
            self._where = (frame, self._position(frame))
        return self._where[1]

    def _position(self, frame: GeoFrame | None) -> Position | None:
        if (entry := self.kept.get("LOCAL_POSITION_NED" if frame is None else "GLOBAL_POSITION_INT")) is None:
            return None
        at, msg = entry
        if frame is None:
            return Position(Ned(msg.x, msg.y, msg.z), at)
        if msg.lat == msg.lon == 0:  # ArduPilot before its first estimate: stale zeros
            return None
        return Position(frame.global_to_ned(_geo(msg)), at)

    def global_position(self) -> GeoPoint | None:
        msg = self.get("GLOBAL_POSITION_INT")
        return None if msg is None or msg.lat == msg.lon == 0 else _geo(msg)

    def telemetry(self, session: MavlinkSession, frame: GeoFrame | None) -> Telemetry:
        local, glob, gps = self.get("LOCAL_POSITION_NED"), self.get("GLOBAL_POSITION_INT"), self.get("GPS_RAW_INT")
        battery, status, state = self.get("BATTERY_STATUS"), self.get("SYS_STATUS"), self.get("EXTENDED_SYS_STATE")
        pct, volts = None, None
        if status is not None:
            pct = status.battery_remaining if status.battery_remaining >= 0 else None
            volts = status.voltage_battery / 1000 if status.voltage_battery != _UNKNOWN_U16 else None
        if battery is not None:  # per-cell voltages, better than SYS_STATUS's
            pct = battery.battery_remaining if battery.battery_remaining >= 0 else pct
            volts = sum(v for v in battery.voltages if v != _UNKNOWN_U16) / 1000 or volts
        landed = LandedState.UNDEFINED
        if state is not None and state.landed_state in iter(LandedState):
            landed = LandedState(state.landed_state)
        return Telemetry(session.autopilot, session.armed, session.mode, self.position(frame),
                         _velocity(local, glob, frame), self.global_position(),
                         None if glob is None else glob.relative_alt / 1000, pct, volts,
                         0 if gps is None else gps.fix_type, 0 if gps is None else gps.satellites_visible,
                         landed, session.heartbeat_at, self._position_ok(session), _prearm_ok(status),
                         session.prearm_text())

    def _position_ok(self, session: MavlinkSession) -> bool | None:
        """ArduPilot's EKF on its position (not reported yet: not ok); None for autopilots that do not say."""
        if session.autopilot is not Autopilot.ARDUPILOT:
            return None
        ekf = self.get("EKF_STATUS_REPORT")
        return ekf is not None and ekf_has_position(int(ekf.flags), session.armed)

    def not_ready(self, t: Telemetry) -> str | None:
        """:func:`~fleet.vehicle.link.not_ready`, and a GPS that SYS_STATUS does not call unhealthy."""
        status, gps = self.get("SYS_STATUS"), mavlink2.MAV_SYS_STATUS_SENSOR_GPS
        gps_sick = status is not None and status.onboard_control_sensors_present \
            & status.onboard_control_sensors_enabled & ~status.onboard_control_sensors_health & gps
        return not_ready(t) or ("SYS_STATUS reports the GPS unhealthy" if gps_sick else None)


def _velocity(local: Message | None, glob: Message | None, frame: GeoFrame | None) -> Ned | None:
    """From the message the positions come from: LOCAL_POSITION_NED (m/s), or with a frame (whose
    axes are north, east and down too) GLOBAL_POSITION_INT (cm/s)."""
    if frame is None:
        return None if local is None else Ned(local.vx, local.vy, local.vz)
    return None if glob is None else Ned(glob.vx / 100, glob.vy / 100, glob.vz / 100)


def _prearm_ok(status: Message | None) -> bool | None:
    """SYS_STATUS's pre-arm check bit (ArduPilot: healthy when armed or the checks pass); None if not reported."""
    bit = mavlink2.MAV_SYS_STATUS_PREARM_CHECK
    if status is None or not status.onboard_control_sensors_present & status.onboard_control_sensors_enabled & bit:
        return None
    return bool(status.onboard_control_sensors_health & bit)


def _geo(msg: Message) -> GeoPoint:
    """GLOBAL_POSITION_INT's position."""
    return GeoPoint(msg.lat / 1e7, msg.lon / 1e7, msg.alt / 1000)
