"""The messages the fake vehicle sends, and when it sends them.

HEARTBEAT goes out at 1 Hz always. Every other message streams only at the interval a
ground station set with MAV_CMD_SET_MESSAGE_INTERVAL (ArduCopter's default stream rates are
all 0; the PX4 personality starts with a default set), or once on MAV_CMD_REQUEST_MESSAGE.
The builders read the model's state and never change it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

from fleet.sim.mav import ENC as _ENC
from fleet.sim.mav import Message, mavlink2

if TYPE_CHECKING:
    from fleet.sim.model import VehicleModel

_SENSORS = (mavlink2.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink2.MAV_SYS_STATUS_SENSOR_3D_ACCEL
            | mavlink2.MAV_SYS_STATUS_SENSOR_3D_MAG | mavlink2.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
            | mavlink2.MAV_SYS_STATUS_SENSOR_GPS | mavlink2.MAV_SYS_STATUS_SENSOR_BATTERY)
_CAPABILITIES = (mavlink2.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | mavlink2.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                 | mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_INT
                 | mavlink2.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                 | mavlink2.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT)
#: How an integer parameter travels in PARAM_VALUE's float (fleet.sim.params): ArduPilot casts it, PX4 copies its bytes.
_PARAM_ENCODING = {mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA: mavlink2.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST,
                   mavlink2.MAV_AUTOPILOT_PX4: mavlink2.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE}
GEOFENCE: int = mavlink2.MAV_SYS_STATUS_GEOFENCE
_UNUSED_CELL = 0xFFFF
HEARTBEAT_PERIOD_S = 1.0
MIN_INTERVAL_S = 0.02  #: 50 Hz at most per message
DEFAULT_INTERVAL_S = 1.0  #: SET_MESSAGE_INTERVAL with 0: "the default rate"


def heartbeat(m: VehicleModel, now: float) -> Message:
    base = mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if m.armed:
        base |= mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
    status = mavlink2.MAV_STATE_ACTIVE if m.armed else mavlink2.MAV_STATE_STANDBY
    return _ENC.heartbeat_encode(mavlink2.MAV_TYPE_QUADROTOR, m.personality.autopilot, base,
                                 m.personality.custom_mode(m.mode), status)


def sys_status(m: VehicleModel, now: float) -> Message:
    fence_present, fence_enabled, fence_health = geofence(m)
    present = _SENSORS | mavlink2.MAV_SYS_STATUS_PREARM_CHECK
    health = _SENSORS if m.gps_fixed(now) else _SENSORS & ~mavlink2.MAV_SYS_STATUS_SENSOR_GPS
    # Both autopilots report their pre-arm checks here, and MAVSDK's health.is_armable reads this bit:
    # ArduPilot (GCS::update_sensor_status_flags) marks it healthy when armed or when the checks pass,
    # PX4 (SYS_STATUS stream) when its health-and-arming checks pass.
    if m.armed or not m.prearm_problem(now):
        health |= mavlink2.MAV_SYS_STATUS_PREARM_CHECK
    b = m.battery
    return _ENC.sys_status_encode(present | fence_present, present | fence_enabled, health | fence_health, 100,
                                  round(b.voltage * 1000), round(b.current_a * 100), b.percent, 0, 0, 0, 0, 0, 0)


def geofence(m: VehicleModel) -> tuple[int, int, int]:
    """SYS_STATUS's GEOFENCE bits: (present, enabled, health). ArduPilot (AC_Fence::sys_status_*): present
    when FENCE_TYPE has a circle or an altitude fence (a polygon one needs points: the fake has none),
    enabled when FENCE_ENABLE too, healthy unless breached (never, here), so a ground station (MAVProxy's
    fence module) sees no breach. PX4's SYS_STATUS carries no geofence bits at all."""
    if "FENCE_TYPE" not in m.params:
        return 0, 0, 0
    circle_or_altitude = 1 | 2 | 8  # AC_FENCE_TYPE_ALT_MAX, _CIRCLE, _ALT_MIN
    present = GEOFENCE if round(m.params.value("FENCE_TYPE")) & circle_or_altitude else 0
    return present, present if m.params.value("FENCE_ENABLE") else 0, GEOFENCE


def battery_status(m: VehicleModel, now: float) -> Message:
    b = m.battery
    cells = [round(b.voltage / b.cells * 1000)] * b.cells + [_UNUSED_CELL] * (10 - b.cells)
    charging = b.current_a < 0
    state = (mavlink2.MAV_BATTERY_CHARGE_STATE_CHARGING if charging
             else mavlink2.MAV_BATTERY_CHARGE_STATE_LOW if b.percent < m.config.min_arm_battery_pct
             else mavlink2.MAV_BATTERY_CHARGE_STATE_OK)
    left = round(b.remaining * b.capacity_mah / 1000 / b.current_a * 3600) if b.current_a > 0.1 else 0
    return _ENC.battery_status_encode(0, mavlink2.MAV_BATTERY_FUNCTION_ALL, mavlink2.MAV_BATTERY_TYPE_LIPO,
                                      2500, cells, round(b.current_a * 100), round(b.consumed_mah),
                                      round(b.energy_j / 100), b.percent, left, state)


def local_position_ned(m: VehicleModel, now: float) -> Message | None:
    """None before the position estimate: both autopilots send none (ArduPilot: no EKF origin yet)."""
    if not m.ready(now):
        return None
    p = m.body
    return _ENC.local_position_ned_encode(m.boot_ms(now), p.north, p.east, p.down, p.vn, p.ve, p.vd)


def global_position_int(m: VehicleModel, now: float) -> Message | None:
    """Before the GPS fix ArduPilot sends its stale location, 0 degrees (its AHRS has no position to
    give; ``GCS_MAVLINK::send_global_position_int`` sends it anyway); PX4 sends nothing until its
    estimate is valid. ArduPilot's comes from the GPS before its EKF uses it."""
    if not (m.gps_fixed(now) if m.personality.stale_position else m.ready(now)):
        return _ENC.global_position_int_encode(m.boot_ms(now), 0, 0, 0, 0, 0, 0, 0, 0) \
            if m.personality.stale_position else None
    g, p = m.global_position(), m.body
    return _ENC.global_position_int_encode(m.boot_ms(now), round(g.lat * 1e7), round(g.lon * 1e7),
                                           round(g.alt_m * 1000), round(p.height * 1000), round(p.vn * 100),
                                           round(p.ve * 100), round(p.vd * 100), _centidegrees(p.yaw))


def gps_raw_int(m: VehicleModel, now: float) -> Message:
    g, p, fixed = m.global_position(), m.body, m.gps_fixed(now)
    fix = m.personality.gps_fix_type if fixed else mavlink2.GPS_FIX_TYPE_NO_FIX
    course = _centidegrees(math.atan2(p.ve, p.vn)) if p.ground_speed > 0.1 else 0
    return _ENC.gps_raw_int_encode(m.boot_ms(now) * 1000, fix, round(g.lat * 1e7) if fixed else 0,
                                   round(g.lon * 1e7) if fixed else 0, round(g.alt_m * 1000) if fixed else 0, 121,
                                   200, round(p.ground_speed * 100), course, 10 if fixed else 0)


#: EKF_STATUS_REPORT flags: before the GPS is used, attitude, velocity and the vertical position only,
#: in constant-position mode; then the relative and absolute horizontal positions too.
EKF_WITHOUT_GPS = 1 | 2 | 4 | 32 | 128
EKF_WITH_GPS = 1 | 2 | 4 | 8 | 16 | 32 | 256 | 512


def ekf_status_report(m: VehicleModel, now: float) -> Message | None:
    """ArduPilot's word on its position estimate (PX4 has no such message)."""
    if m.personality.autopilot != mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA:
        return None
    flags = EKF_WITH_GPS if m.ready(now) else EKF_WITHOUT_GPS
    return _ENC.ekf_status_report_encode(flags, 0.01, 0.02, 0.03, 0.01, 0.0, 0.0)


def extended_sys_state(m: VehicleModel, now: float) -> Message:
    return _ENC.extended_sys_state_encode(mavlink2.MAV_VTOL_STATE_UNDEFINED, m.landed_state())


def attitude(m: VehicleModel, now: float) -> Message:
    p = m.body
    # Tilt into the horizontal acceleration, seen in the body frame.
    fwd = p.an * math.cos(p.yaw) + p.ae * math.sin(p.yaw)
    right = -p.an * math.sin(p.yaw) + p.ae * math.cos(p.yaw)
    return _ENC.attitude_encode(m.boot_ms(now), math.atan2(right, 9.81), -math.atan2(fwd, 9.81), p.yaw,
                                0.0, 0.0, 0.0)


def home_position(m: VehicleModel, now: float) -> Message | None:
    """None before the position estimate: home is set with it."""
    if not m.ready(now):
        return None
    h = m.home_global
    return _ENC.home_position_encode(round(h.lat * 1e7), round(h.lon * 1e7), round(h.alt_m * 1000),
                                     0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, m.boot_ms(now) * 1000)


def autopilot_version(m: VehicleModel, now: float) -> Message:
    capabilities = _CAPABILITIES | _PARAM_ENCODING.get(m.personality.autopilot, 0)
    return _ENC.autopilot_version_encode(capabilities, m.personality.flight_sw_version, 0, 0, 0,
                                         [0] * 8, [0] * 8, [0] * 8, 0, 0, m.config.system_id)


#: Messages a ground station may stream with SET_MESSAGE_INTERVAL (and request once).
#: A builder returns None when the autopilot would send nothing now (no position estimate yet).
STREAMABLE: dict[int, Callable[[VehicleModel, float], Message | None]] = {
    mavlink2.MAVLINK_MSG_ID_SYS_STATUS: sys_status,
    mavlink2.MAVLINK_MSG_ID_BATTERY_STATUS: battery_status,
    mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED: local_position_ned,
    mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: global_position_int,
    mavlink2.MAVLINK_MSG_ID_GPS_RAW_INT: gps_raw_int,
    mavlink2.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: extended_sys_state,
    mavlink2.MAVLINK_MSG_ID_ATTITUDE: attitude,
    mavlink2.MAVLINK_MSG_ID_HOME_POSITION: home_position,
    mavlink2.MAVLINK_MSG_ID_EKF_STATUS_REPORT: ekf_status_report,
}

#: Messages MAV_CMD_REQUEST_MESSAGE can ask for once.
REQUESTABLE: dict[int, Callable[[VehicleModel, float], Message | None]] = {
    **STREAMABLE,
    mavlink2.MAVLINK_MSG_ID_HEARTBEAT: heartbeat,
    mavlink2.MAVLINK_MSG_ID_AUTOPILOT_VERSION: autopilot_version,
}


#: ArduPilot's legacy REQUEST_DATA_STREAM groups (of the messages modelled here).
DATA_STREAMS: dict[int, tuple[int, ...]] = {
    mavlink2.MAV_DATA_STREAM_EXTENDED_STATUS: (mavlink2.MAVLINK_MSG_ID_SYS_STATUS, mavlink2.MAVLINK_MSG_ID_GPS_RAW_INT,
                                               mavlink2.MAVLINK_MSG_ID_EXTENDED_SYS_STATE),
    mavlink2.MAV_DATA_STREAM_POSITION: (mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
                                        mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED),
    mavlink2.MAV_DATA_STREAM_EXTRA1: (mavlink2.MAVLINK_MSG_ID_ATTITUDE,),
    mavlink2.MAV_DATA_STREAM_EXTRA3: (mavlink2.MAVLINK_MSG_ID_BATTERY_STATUS,),
}
DATA_STREAMS[mavlink2.MAV_DATA_STREAM_ALL] = tuple(i for ids in DATA_STREAMS.values() for i in ids)


class Streams:
    """Message id -> interval, and when each is next due. HEARTBEAT is always in.

    The streams a ground station asks for keep time on one grid: such a stream is due at
    ``origin + k * interval``, so streams at the same rate (or at multiples of it) go out in the
    same tick, and in one datagram, as an autopilot's scheduler sends a group of streams together.
    The first rate set places the grid, ``phase`` (a fraction of that interval) after it was set:
    real autopilots send on their own schedulers, out of step with each other; vehicles of one
    simulator given their rates at the same moment would otherwise all send in one burst. (The
    HEARTBEAT and the streams a vehicle boots with keep their own time, from boot.)
    """

    def __init__(self, intervals: dict[int, float], now: float, phase: float = 0.0) -> None:
        self._interval: dict[int, float] = {mavlink2.MAVLINK_MSG_ID_HEARTBEAT: HEARTBEAT_PERIOD_S, **intervals}
        self._due: dict[int, float] = dict.fromkeys(self._interval, now)
        self._phase = phase % 1.0
        self._origin: float | None = None

    def set_interval(self, msg_id: int, interval_us: float, now: float) -> None:
        """MAV_CMD_SET_MESSAGE_INTERVAL's param2: -1 stops, 0 is the default rate, else microseconds."""
        if interval_us < 0:
            self._interval.pop(msg_id, None)
            self._due.pop(msg_id, None)
            return
        interval = DEFAULT_INTERVAL_S if interval_us == 0 else max(MIN_INTERVAL_S, interval_us / 1e6)
        self._interval[msg_id] = interval
        if self._origin is None:
            self._origin = now + self._phase * interval
        self._due[msg_id] = self._origin + math.ceil((now - self._origin) / interval) * interval

    def interval(self, msg_id: int) -> float | None:
        return self._interval.get(msg_id)

    def due(self, now: float) -> list[int]:
        """Ids due at ``now``; each is then next due at its first time after ``now`` on its schedule
        (one interval later, unless a late tick missed more: it keeps its time, so a group stays one)."""
        out = []
        for msg_id, due in self._due.items():
            if now >= due:
                out.append(msg_id)
                interval = self._interval[msg_id]
                self._due[msg_id] = due + (math.floor((now - due) / interval) + 1) * interval
        return out


def statustext(severity: int, text: str) -> Message:
    return _ENC.statustext_encode(severity, text.encode("ascii", "replace")[:50])


def command_ack(command: int, result: int, target: tuple[int, int]) -> Message:
    return _ENC.command_ack_encode(command, result, 0, 0, target[0], target[1])


def ping(time_usec: int, seq: int, target: tuple[int, int]) -> Message:
    return _ENC.ping_encode(time_usec, seq, target[0], target[1])


def mission_ack(result: int, mission_type: int, target: tuple[int, int]) -> Message:
    return _ENC.mission_ack_encode(target[0], target[1], result, mission_type)


def timesync(tc1: int, ts1: int) -> Message:
    return _ENC.timesync_encode(tc1, ts1)


def _centidegrees(rad: float) -> int:
    return round(math.degrees(rad) * 100) % 36000
