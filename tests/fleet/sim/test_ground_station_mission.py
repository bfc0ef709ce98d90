"""The fake vehicle towards a real ground station: the mission protocol, the geofence bits in
SYS_STATUS and MAVLink FTP refused (the sans-I/O model).
"""

from __future__ import annotations

import pytest

from fleet.sim.ftp import ACK, HEADER, NAK
from fleet.sim.personality import ARDUPILOT, PX4, Personality
from fleet.sim.telemetry import sys_status
from tests.fleet.sim.ground_station_helpers import BOTH, ML, answers, param_set, vehicle
from tests.fleet.sim.vehicle_helpers import GCS


# ------------------------------------------------------------------ missions
@BOTH
def test_mission_counts_are_ardupilots_home_or_nothing(personality: Personality) -> None:
    model = vehicle(personality)
    counts = {}
    for kind in (ML.MAV_MISSION_TYPE_MISSION, ML.MAV_MISSION_TYPE_FENCE, ML.MAV_MISSION_TYPE_RALLY):
        (reply,) = answers(model, GCS.mission_request_list_encode(1, 1, kind))
        assert (reply.get_type(), reply.mission_type, reply.target_system, reply.target_component) == \
            ("MISSION_COUNT", kind, 255, 190)
        counts[kind] = reply.count
    assert list(counts.values()) == ([1, 0, 0] if personality is ARDUPILOT else [0, 0, 0])
    (unknown,) = answers(model, GCS.mission_request_list_encode(1, 1, 7))
    assert (unknown.get_type(), unknown.type) == ("MISSION_ACK", ML.MAV_MISSION_UNSUPPORTED)


def test_arducopters_mission_item_0_is_home() -> None:
    model = vehicle(ARDUPILOT)
    (item,) = answers(model, GCS.mission_request_int_encode(1, 1, 0, ML.MAV_MISSION_TYPE_MISSION))
    home = model.home_global
    assert (item.get_type(), item.seq, item.command, item.frame, item.autocontinue, item.mission_type) == \
        ("MISSION_ITEM_INT", 0, ML.MAV_CMD_NAV_WAYPOINT, ML.MAV_FRAME_GLOBAL, 1, 0)
    assert (item.x, item.y, item.z) == (round(home.lat * 1e7), round(home.lon * 1e7), pytest.approx(home.alt_m))
    (legacy,) = answers(model, GCS.mission_request_encode(1, 1, 0, ML.MAV_MISSION_TYPE_MISSION))
    assert (legacy.get_type(), legacy.x, legacy.y) == ("MISSION_ITEM", pytest.approx(home.lat), pytest.approx(home.lon))
    booting = vehicle(ARDUPILOT, ready_after_s=30.0)  # home is set with the position estimate
    (early,) = answers(booting, GCS.mission_request_int_encode(1, 1, 0, ML.MAV_MISSION_TYPE_MISSION))
    assert (early.x, early.y, early.z) == (0, 0, 0.0)


@BOTH
def test_a_mission_request_out_of_range(personality: Personality) -> None:
    model = vehicle(personality)
    (count,) = answers(model, GCS.mission_request_list_encode(1, 1, ML.MAV_MISSION_TYPE_MISSION))  # as a GCS does
    assert count.count == (1 if personality is ARDUPILOT else 0)
    beyond = answers(model, GCS.mission_request_int_encode(1, 1, count.count, ML.MAV_MISSION_TYPE_MISSION))
    fence = answers(model, GCS.mission_request_int_encode(1, 1, 0, ML.MAV_MISSION_TYPE_FENCE))
    legacy = answers(model, GCS.mission_request_encode(1, 1, 5, ML.MAV_MISSION_TYPE_MISSION))
    if personality is PX4:  # no transfer under way: PX4 ignores the request without a word
        assert beyond == fence == legacy == []
        return
    # ArduPilot repeats the count ("to educate the GCS"), then refuses; the legacy request only refuses.
    assert [(m.get_type(), getattr(m, "count", None)) for m in beyond] == [("MISSION_COUNT", 1), ("MISSION_ACK", None)]
    for refused, kind in ((beyond[-1], 0), (fence[-1], 1), (legacy[-1], 0)):
        assert (refused.type, refused.mission_type) == (ML.MAV_MISSION_INVALID_SEQUENCE, kind)
    assert len(legacy) == 1


@BOTH
def test_uploads_but_empty_ones_are_refused_and_a_mission_ack_needs_no_answer(personality: Personality) -> None:
    model = vehicle(personality)
    (upload,) = answers(model, GCS.mission_count_encode(1, 1, 3, ML.MAV_MISSION_TYPE_MISSION))
    (empty,) = answers(model, GCS.mission_count_encode(1, 1, 0, ML.MAV_MISSION_TYPE_FENCE))
    (clear,) = answers(model, GCS.mission_clear_all_encode(1, 1, ML.MAV_MISSION_TYPE_ALL))
    assert [(m.type, m.mission_type) for m in (upload, empty, clear)] == [
        (ML.MAV_MISSION_UNSUPPORTED, 0), (ML.MAV_MISSION_ACCEPTED, 1), (ML.MAV_MISSION_ACCEPTED, 255)]
    assert not answers(model, GCS.mission_ack_encode(1, 1, ML.MAV_MISSION_ACCEPTED, 0))
    assert "MISSION_ACK" not in model.unhandled


# ------------------------------------------------------------------ SYS_STATUS and FTP
def test_arducopters_geofence_is_present_healthy_and_enabled_by_fence_enable() -> None:
    copter = vehicle(ARDUPILOT)
    fence = ML.MAV_SYS_STATUS_GEOFENCE
    status = sys_status(copter, 1.0)
    assert status.onboard_control_sensors_present & status.onboard_control_sensors_health & fence
    assert not status.onboard_control_sensors_enabled & fence  # FENCE_ENABLE 0
    param_set(copter, "FENCE_ENABLE", 1)
    assert sys_status(copter, 1.0).onboard_control_sensors_enabled & fence
    px4 = sys_status(vehicle(PX4), 1.0)  # PX4's SYS_STATUS has no geofence bits
    assert not (px4.onboard_control_sensors_present | px4.onboard_control_sensors_health) & fence


@BOTH
def test_ftp_requests_are_refused_at_once_so_a_ground_station_falls_back(personality: Personality) -> None:
    model = vehicle(personality)
    name = b"@PARAM/param.pck"
    open_ro = HEADER.pack(7, 0, 4, len(name), 0, 0, 0, 0) + name  # OpenFileRO, seq 7
    (nak,) = answers(model, GCS.file_transfer_protocol_encode(0, 1, 1, open_ro.ljust(251, b"\0")))
    assert (nak.target_system, nak.target_component) == (255, 190)
    seq, _, opcode, size, req_opcode = HEADER.unpack_from(bytes(nak.payload))[:5]
    assert (seq, opcode, size, req_opcode, nak.payload[HEADER.size]) == (8, NAK, 1, 4, 10)  # ERR_FileNotFound
    terminate = HEADER.pack(9, 0, 1, 0, 0, 0, 0, 0)
    (ack,) = answers(model, GCS.file_transfer_protocol_encode(0, 1, 1, terminate.ljust(251, b"\0")))
    assert HEADER.unpack_from(bytes(ack.payload))[2] == ACK
