"""What the MAVSDK backend builds for MAVSDK: its connection strings, and the MAVLink messages it
sends through MavlinkDirect (COMMAND_LONG, and ArduPilot's position setpoints) as JSON fields; and
the session's messages it reads from MavlinkDirect's JSON (:func:`inbound`); PARAM_REQUEST_READ too."""

from __future__ import annotations

import asyncio
import json
import math
from typing import Any

from mavsdk.plugins.mavlink_direct import MavlinkMessage

from drona_gcs.geo import GeoFrame
from fleet.vehicle.link import POSITION_ONLY, POSITION_VELOCITY, STILL, Motion
from fleet.vehicle.policy import Result
from fleet.vehicle.session import CommandAck, Heartbeat, Inbound, StatusText
from fleet.vehicle.urls import LinkUrl, Scheme

SYS_STATUS, EXTENDED_SYS_STATE, EKF_STATUS_REPORT = 1, 245, 193  #: message ids MAVSDK has no set_rate_* for
LOCAL_NED, GLOBAL_INT = 1, 5  #: MAV_FRAME
#: MAVSDK's ActionResult/OffboardResult name -> MAV_RESULT, when no COMMAND_ACK says better.
RESULTS = {"COMMAND_DENIED": Result.DENIED, "COMMAND_DENIED_LANDED_STATE_UNKNOWN": Result.DENIED,
           "COMMAND_DENIED_NOT_LANDED": Result.DENIED, "BUSY": Result.TEMPORARILY_REJECTED,
           "UNSUPPORTED": Result.UNSUPPORTED}
#: Results that mean no answer came: a link problem, not a refusal.
UNANSWERED = {"NO_SYSTEM", "CONNECTION_ERROR", "TIMEOUT", "UNKNOWN"}
PARAM_REAL32 = 9  #: MAV_PARAM_TYPE_REAL32


def inbound(msg: MavlinkMessage) -> Inbound:
    """A HEARTBEAT, COMMAND_ACK or STATUSTEXT from MavlinkDirect, as the session takes it."""
    fields = json.loads(msg.fields_json)
    if msg.message_name == "HEARTBEAT":
        return Heartbeat.decode(None, int(fields["custom_mode"]), int(fields["base_mode"]))
    if msg.message_name == "COMMAND_ACK":
        return CommandAck(int(fields["command"]), int(fields["result"]))
    return StatusText(int(fields["severity"]), str(fields["text"]))


def mavsdk_url(url: LinkUrl) -> str:
    """Our connection string in MAVSDK's form: our ``tcp://`` (a client) is its ``tcpout://``."""
    host = f"[{url.host}]" if ":" in url.host else url.host
    return {Scheme.UDPIN: f"udpin://{host}:{url.port}", Scheme.UDPOUT: f"udpout://{host}:{url.port}",
            Scheme.TCP: f"tcpout://{host}:{url.port}", Scheme.SERIAL: f"serial://{url.device}:{url.baud}"}[url.scheme]


def command_long(sysid: int, command: int, params: tuple[float, ...]) -> MavlinkMessage:
    """COMMAND_LONG to the autopilot of ``sysid``, its params padded to seven."""
    p = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
    fields = {"target_system": sysid, "target_component": 1, "command": command, "confirmation": 0,
              # JSON has no NaN: MavlinkDirect sends null as NaN (PX4: "unset")
              **{f"param{i + 1}": None if math.isnan(v) else v for i, v in enumerate(p)}}
    return MavlinkMessage(message_name="COMMAND_LONG", target_system_id=sysid, target_component_id=1,
                          fields_json=json.dumps(fields))


def param_request_read(sysid: int, name: str) -> MavlinkMessage:
    """PARAM_REQUEST_READ of parameter ``name`` from the autopilot of ``sysid`` (by name: index -1)."""
    fields = {"target_system": sysid, "target_component": 1, "param_id": name, "param_index": -1}
    return MavlinkMessage(message_name="PARAM_REQUEST_READ", target_system_id=sysid, target_component_id=1,
                          fields_json=json.dumps(fields))


def param_set(sysid: int, name: str, value: float) -> MavlinkMessage:
    """PARAM_SET of parameter ``name`` of the autopilot of ``sysid`` to ``value`` (as a float)."""
    fields = {"target_system": sysid, "target_component": 1, "param_id": name, "param_value": value,
              "param_type": PARAM_REAL32}
    return MavlinkMessage(message_name="PARAM_SET", target_system_id=sysid, target_component_id=1,
                          fields_json=json.dumps(fields))


def setpoint(sysid: int, motion: Motion, frame: GeoFrame | None, now: float) -> MavlinkMessage:
    """SET_POSITION_TARGET_LOCAL_NED to where ``motion`` is, its velocity fed forward (a position only
    without one); with ``frame``, SET_POSITION_TARGET_GLOBAL_INT."""
    ms = round((now % 4e6) * 1000)
    target, v = motion.where, motion.velocity or STILL
    mask = POSITION_ONLY if motion.velocity is None else POSITION_VELOCITY
    fields: dict[str, float | int] = {"time_boot_ms": ms, "target_system": sysid, "target_component": 1,
                                      "type_mask": mask,
                                      "vx": v.north, "vy": v.east, "vz": v.down,
                                      **dict.fromkeys(("afx", "afy", "afz", "yaw", "yaw_rate"), 0.0)}
    if frame is None:
        name = "SET_POSITION_TARGET_LOCAL_NED"
        fields.update(coordinate_frame=LOCAL_NED, x=target.north, y=target.east, z=target.down)
    else:
        name, g = "SET_POSITION_TARGET_GLOBAL_INT", frame.ned_to_global(target)
        fields.update(coordinate_frame=GLOBAL_INT, lat_int=round(g.lat * 1e7), lon_int=round(g.lon * 1e7),
                      alt=g.alt_m)
    return MavlinkMessage(message_name=name, target_system_id=sysid, target_component_id=1,
                          fields_json=json.dumps(fields))


def settle(future: asyncio.Future[Any], value: Any) -> None:
    """Resolve ``future`` unless done (on the loop, from a MAVSDK callback)."""
    if not future.done():
        future.set_result(value)
