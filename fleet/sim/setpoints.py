"""SET_POSITION_TARGET_LOCAL_NED and SET_POSITION_TARGET_GLOBAL_INT to a controller :class:`Target`.

``type_mask`` bits set mean "ignore": 1, 2, 4 the x, y, z position; 8, 16, 32 the velocity;
64..256 the acceleration (fed forward, horizontally, with a position and a velocity); 1024 yaw;
2048 yaw rate. On each axis group
(horizontal, vertical) a given position wins over a velocity; nothing given there means
"velocity 0" (stop on that axis). A message that gives neither position nor velocity
anywhere (only yaw, say) leaves the motion target as it was.

Local frames: LOCAL_NED (absolute, in the vehicle's local frame), LOCAL_OFFSET_NED (position
relative to the vehicle), BODY_NED and BODY_OFFSET_NED (relative, rotated by the heading).
Global frames: GLOBAL(_INT) is AMSL, GLOBAL_RELATIVE_ALT(_INT) and GLOBAL_TERRAIN_ALT(_INT)
are above home (flat ground). Other frames are not supported: the message is dropped.
"""

from __future__ import annotations

import math

from drona_gcs.geo import GeoFrame, GeoPoint, Ned
from fleet.sim.mav import Message, mavlink2
from fleet.sim.physics import Body, Target

IGNORE_X, IGNORE_Y, IGNORE_Z = 1, 2, 4
IGNORE_VX, IGNORE_VY, IGNORE_VZ = 8, 16, 32
IGNORE_AX, IGNORE_AY = 64, 128
IGNORE_YAW = 1024

_OFFSET_FRAMES = {mavlink2.MAV_FRAME_LOCAL_OFFSET_NED, mavlink2.MAV_FRAME_BODY_NED, mavlink2.MAV_FRAME_BODY_OFFSET_NED}
_BODY_FRAMES = {mavlink2.MAV_FRAME_BODY_NED, mavlink2.MAV_FRAME_BODY_OFFSET_NED}
_LOCAL_FRAMES = {mavlink2.MAV_FRAME_LOCAL_NED} | _OFFSET_FRAMES
_AMSL_FRAMES = {mavlink2.MAV_FRAME_GLOBAL, mavlink2.MAV_FRAME_GLOBAL_INT}
_RELATIVE_FRAMES = {mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                    mavlink2.MAV_FRAME_GLOBAL_TERRAIN_ALT, mavlink2.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT}

#: (target or None when the message moves nothing, yaw or None), or None for an unsupported frame.
Update = tuple[Target | None, float | None] | None


def setpoint_from_local(msg: Message, body: Body) -> Update:
    frame = msg.coordinate_frame
    if frame not in _LOCAL_FRAMES:
        return None
    x, y, z, vx, vy, vz, ax, ay = msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz, msg.afx, msg.afy
    if frame in _BODY_FRAMES:
        x, y = _rotate(x, y, body.yaw)
        vx, vy = _rotate(vx, vy, body.yaw)
        ax, ay = _rotate(ax, ay, body.yaw)
    if frame in _OFFSET_FRAMES:
        x, y, z = x + body.north, y + body.east, z + body.down
    return _target(msg.type_mask, (x, y, z), (vx, vy, vz), msg.yaw, (ax, ay))


def setpoint_from_global(msg: Message, geo: GeoFrame, home: Ned) -> Update:
    frame = msg.coordinate_frame
    if frame in _AMSL_FRAMES:
        amsl = msg.alt
    elif frame in _RELATIVE_FRAMES:
        amsl = geo.origin.alt_m - home.down + msg.alt
    else:
        return None
    ned = geo.global_to_ned(GeoPoint(msg.lat_int / 1e7, msg.lon_int / 1e7, amsl))
    position = (ned.north - home.north, ned.east - home.east, ned.down - home.down)
    return _target(msg.type_mask, position, (msg.vx, msg.vy, msg.vz), msg.yaw, (msg.afx, msg.afy))


def _target(mask: int, pos: tuple[float, float, float], vel: tuple[float, float, float], yaw: float,
            accel: tuple[float, float]) -> Update:
    yaw_out = None if mask & IGNORE_YAW or not math.isfinite(yaw) else yaw
    has_h_pos = not mask & (IGNORE_X | IGNORE_Y) and math.isfinite(pos[0]) and math.isfinite(pos[1])
    has_v_pos = not mask & IGNORE_Z and math.isfinite(pos[2])
    vn = 0.0 if mask & IGNORE_VX or not math.isfinite(vel[0]) else vel[0]
    ve = 0.0 if mask & IGNORE_VY or not math.isfinite(vel[1]) else vel[1]
    vd = 0.0 if mask & IGNORE_VZ or not math.isfinite(vel[2]) else vel[2]
    all_vel = IGNORE_VX | IGNORE_VY | IGNORE_VZ
    moves = has_h_pos or has_v_pos or mask & all_vel != all_vel
    if not moves:
        return None, yaw_out
    # An acceleration is fed forward only with a horizontal position and velocity (ArduCopter's posvelaccel).
    an, ae = accel if has_h_pos and not mask & (IGNORE_AX | IGNORE_AY) and all(map(math.isfinite, accel)) else (0, 0)
    return Target(north=pos[0] if has_h_pos else None, east=pos[1] if has_h_pos else None,
                  down=pos[2] if has_v_pos else None, vn=vn, ve=ve, vd=vd, an=an, ae=ae), yaw_out


def _rotate(forward: float, right: float, yaw: float) -> tuple[float, float]:
    return (forward * math.cos(yaw) - right * math.sin(yaw), forward * math.sin(yaw) + right * math.cos(yaw))
