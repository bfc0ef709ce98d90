"""The MAVSDK backend's telemetry: the subscriptions' latest values read as a
:class:`~fleet.vehicle.link.Telemetry` (MAVSDK's own types, and SYS_STATUS and EKF_STATUS_REPORT as
MavlinkDirect's JSON fields). Positions are local NED, or with a frame the global position in the
workspace's frame, as with the pymavlink backend."""

from __future__ import annotations

import math
from typing import Any

from drona_gcs.geo import GeoFrame, GeoPoint, Ned
from fleet.vehicle.link import Autopilot, LandedState, Position, Share, Telemetry
from fleet.vehicle.policy import ekf_has_position
from fleet.vehicle.session import MavlinkSession

PREARM_CHECK = 1 << 28  #: MAV_SYS_STATUS_PREARM_CHECK
#: MAVSDK telemetry kept as latest values, with its rate (a share of ``stream_hz``).
TELEMETRY = {"position": Share.POSITION, "position_velocity_ned": Share.POSITION, "battery": Share.STATUS,
             "gps_info": Share.GPS, "landed_state": Share.LANDED}
POSITION_NAMES = frozenset({"position", "position_velocity_ned"})  #: what Subscribed.position reads


class Subscribed:
    """The latest value of each subscription (and MavlinkDirect message), with the link clock time it came."""

    def __init__(self) -> None:
        self.kept: dict[str, tuple[float, Any]] = {}

    def keep(self, name: str, value: Any, now: float) -> None:
        self.kept[name] = (now, value)

    def value(self, name: str) -> Any:
        entry = self.kept.get(name)
        return None if entry is None else entry[1]

    def position(self, frame: GeoFrame | None) -> Position | None:
        """The local NED position; with ``frame``, the global position in the workspace frame."""
        if (entry := self.kept.get("position_velocity_ned" if frame is None else "position")) is None:
            return None
        at, value = entry
        if frame is None:
            p = value.position
            return None if math.isnan(p.north_m) else Position(Ned(p.north_m, p.east_m, p.down_m), at)
        g = self.global_position()
        return None if g is None else Position(frame.global_to_ned(g), at)

    def global_position(self) -> GeoPoint | None:
        p = self.value("position")
        if p is None or math.isnan(p.latitude_deg) or p.latitude_deg == p.longitude_deg == 0:
            return None  # ArduPilot before its first estimate sends stale zeros
        return GeoPoint(p.latitude_deg, p.longitude_deg, p.absolute_altitude_m)

    def telemetry(self, session: MavlinkSession, frame: GeoFrame | None) -> Telemetry:
        pv, glob, battery = self.value("position_velocity_ned"), self.value("position"), self.value("battery")
        gps, landed = self.value("gps_info"), self.value("landed_state")
        pct = round(battery.remaining_percent) if battery is not None and math.isfinite(battery.remaining_percent) \
            else None
        volts = battery.voltage_v if battery is not None and math.isfinite(battery.voltage_v) else None
        height = glob.relative_altitude_m if glob is not None and math.isfinite(glob.relative_altitude_m) else None
        velocity = None if pv is None else Ned(pv.velocity.north_m_s, pv.velocity.east_m_s, pv.velocity.down_m_s)
        return Telemetry(session.autopilot, session.armed, session.mode, self.position(frame), velocity,
                         self.global_position(), height, pct, volts, 0 if gps is None else int(gps.fix_type),
                         0 if gps is None else gps.num_satellites,
                         LandedState(int(landed)) if landed is not None else LandedState.UNDEFINED,
                         session.heartbeat_at, self._position_ok(session), self._prearm_ok(), session.prearm_text())

    def _position_ok(self, session: MavlinkSession) -> bool | None:
        """ArduPilot's EKF on its position (not reported yet: not ok); None for autopilots that do not say."""
        if session.autopilot is not Autopilot.ARDUPILOT:
            return None
        ekf = self.value("EKF_STATUS_REPORT")
        return ekf is not None and ekf_has_position(int(ekf["flags"]), session.armed)

    def _prearm_ok(self) -> bool | None:
        status = self.value("SYS_STATUS")
        if status is None or not int(status["onboard_control_sensors_present"]) \
                & int(status["onboard_control_sensors_enabled"]) & PREARM_CHECK:
            return None
        return bool(int(status["onboard_control_sensors_health"]) & PREARM_CHECK)
