"""The mission protocol of the fake vehicle, which flies no missions: every list is empty but ArduPilot's home.

As the real autopilots answer a ground station that downloads (MAVProxy's ``wp list``, QGroundControl
on connecting):

* ArduPilot (MissionItemProtocol.cpp, AP_Mission): the mission's count is 1, item 0 being home
  (MAV_CMD_NAV_WAYPOINT in MAV_FRAME_GLOBAL at home's latitude, longitude and altitude AMSL; all 0
  until home is set with the position estimate); fence and rally count 0. A request beyond the count
  is answered MISSION_ACK MAV_MISSION_INVALID_SEQUENCE (MISSION_REQUEST_INT first repeats the
  MISSION_COUNT, "to educate the GCS"). MISSION_REQUEST, the legacy request, gets a MISSION_ITEM.
* PX4 (mavlink_mission.cpp, v1.15): every count is 0, and a request then finds no transfer under
  way, which PX4 ignores without a word.

A mission type neither knows is answered MAV_MISSION_UNSUPPORTED. Uploads: an empty one (MISSION_COUNT
0, or MISSION_CLEAR_ALL) is accepted, since the lists are empty already; any other is refused with
MAV_MISSION_UNSUPPORTED, as the fake flies no missions. A ground station's MISSION_ACK needs no answer.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fleet.sim import telemetry
from fleet.sim.mav import ENC, Message, mavlink2, source
from fleet.sim.personality import ARDUPILOT

if TYPE_CHECKING:
    from fleet.sim.model import VehicleModel

MISSION: int = mavlink2.MAV_MISSION_TYPE_MISSION
FENCE: int = mavlink2.MAV_MISSION_TYPE_FENCE
RALLY: int = mavlink2.MAV_MISSION_TYPE_RALLY
INVALID_SEQUENCE: int = mavlink2.MAV_MISSION_INVALID_SEQUENCE
UNSUPPORTED: int = mavlink2.MAV_MISSION_UNSUPPORTED
ACCEPTED: int = mavlink2.MAV_MISSION_ACCEPTED


def count(m: VehicleModel, mission_type: int) -> int | None:
    """How many items a list holds (None: no such list)."""
    if mission_type not in (MISSION, FENCE, RALLY):
        return None
    return 1 if m.personality is ARDUPILOT and mission_type == MISSION else 0


def on_request_list(m: VehicleModel, msg: Message, now: float) -> list[Message]:
    n = count(m, msg.mission_type)
    if n is None:
        return [telemetry.mission_ack(UNSUPPORTED, msg.mission_type, source(msg))]
    return [ENC.mission_count_encode(*source(msg), n, msg.mission_type)]


def on_request_item(m: VehicleModel, msg: Message, now: float) -> list[Message]:
    """MISSION_REQUEST_INT or MISSION_REQUEST: the item, or why not."""
    if m.personality is not ARDUPILOT:
        return []  # PX4: no transfer under way (every list is empty), ignored silently
    n = count(m, msg.mission_type)
    if n is None:
        return [telemetry.mission_ack(UNSUPPORTED, msg.mission_type, source(msg))]
    legacy = msg.get_type() == "MISSION_REQUEST"
    if msg.seq >= n:
        educate = [] if legacy else [ENC.mission_count_encode(*source(msg), n, msg.mission_type)]
        return [*educate, telemetry.mission_ack(INVALID_SEQUENCE, msg.mission_type, source(msg))]
    return [home_item(m, now, source(msg), legacy)]


def home_item(m: VehicleModel, now: float, target: tuple[int, int], legacy: bool = False) -> Message:
    """ArduPilot's mission item 0: home, at 0 degrees and 0 m until home is set."""
    h = m.home_global if m.ready(now) else None
    lat, lon, alt = (h.lat, h.lon, h.alt_m) if h is not None else (0.0, 0.0, 0.0)
    frame, command = mavlink2.MAV_FRAME_GLOBAL, mavlink2.MAV_CMD_NAV_WAYPOINT
    if legacy:
        return ENC.mission_item_encode(*target, 0, frame, command, 0, 1, 0, 0, 0, 0, lat, lon, alt, MISSION)
    return ENC.mission_item_int_encode(*target, 0, frame, command, 0, 1, 0, 0, 0, 0, round(lat * 1e7),
                                       round(lon * 1e7), alt, MISSION)


def on_upload(m: VehicleModel, msg: Message, now: float) -> list[Message]:
    """MISSION_COUNT from the ground station (an upload), or MISSION_CLEAR_ALL."""
    if count(m, msg.mission_type) is None and msg.mission_type != mavlink2.MAV_MISSION_TYPE_ALL:
        return [telemetry.mission_ack(UNSUPPORTED, msg.mission_type, source(msg))]
    empty = msg.get_type() == "MISSION_CLEAR_ALL" or msg.count == 0
    return [telemetry.mission_ack(ACCEPTED if empty else UNSUPPORTED, msg.mission_type, source(msg))]
