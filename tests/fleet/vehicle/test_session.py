"""The sans-I/O MAVLink session (fleet.vehicle.session): decoded messages and ``now`` in, decisions out."""

from __future__ import annotations

import pytest

from drona_gcs.errors import ProtocolViolation, VehicleCommandRejected, VehicleError
from fleet.vehicle.link import Autopilot
from fleet.vehicle.policy import CONFIRM_HEARTBEATS, Command, arming, landing, switching
from fleet.vehicle.session import (
    CommandAck,
    Heartbeat,
    LinkState,
    MavlinkSession,
    StatusText,
    Verdict,
    autopilot_heartbeat,
)

ARDUPILOTMEGA, PX4, INVALID = 3, 12, 8  #: MAV_AUTOPILOT
QUAD, GCS = 2, 6  #: MAV_TYPE
STABILIZE, GUIDED, LAND = 0, 4, 9  #: ArduCopter's custom modes
ARMED = 128 | 1


def heartbeat(custom_mode: int = STABILIZE, armed: bool = False, autopilot: int = ARDUPILOTMEGA) -> Heartbeat:
    return Heartbeat.decode(autopilot, custom_mode, ARMED if armed else 1)


def session_at(now: float = 10.0, **heartbeat_fields: object) -> MavlinkSession:
    """A session that has heard one ArduCopter HEARTBEAT at ``now``."""
    session = MavlinkSession("tcp://127.0.0.1:5760", heartbeat_timeout=3.0)
    assert session.accepts(1, 1, heartbeat=True)
    session.receive(heartbeat(**heartbeat_fields), now)  # type: ignore[arg-type]
    return session


def test_the_first_autopilot_heartbeat_fixes_whose_messages_count() -> None:
    session = MavlinkSession("udpin://0.0.0.0:14550", 3.0)
    assert not session.accepts(1, 1, heartbeat=False), "no HEARTBEAT yet: nobody is the vehicle"
    assert not session.accepts(1, 191, heartbeat=True), "a companion's component is not the autopilot"
    assert session.accepts(7, 1, heartbeat=True) and session.sysid == 7
    assert session.accepts(7, 1, heartbeat=False)
    assert not session.accepts(8, 1, heartbeat=True), "a second autopilot is someone else's vehicle"
    assert not session.accepts(7, 100, heartbeat=False)


def test_a_target_system_given_must_match() -> None:
    session = MavlinkSession("udpin://0.0.0.0:14550", 3.0, target_system=2)
    assert not session.accepts(1, 1, heartbeat=True)
    assert session.accepts(2, 1, heartbeat=True) and session.locked


def test_only_an_autopilots_heartbeat_is_the_vehicles() -> None:
    assert autopilot_heartbeat(ARDUPILOTMEGA, QUAD)
    assert not autopilot_heartbeat(ARDUPILOTMEGA, GCS), "a ground station's"
    assert not autopilot_heartbeat(INVALID, QUAD), "a camera's: no autopilot"


def test_a_heartbeat_says_autopilot_mode_and_armed_state() -> None:
    session = session_at(5.0, custom_mode=GUIDED, armed=True)
    assert (session.autopilot, session.mode, session.armed) == (Autopilot.ARDUPILOT, "GUIDED", True)
    assert (session.heartbeats, session.heartbeat_at) == (1, 5.0)
    session.receive(Heartbeat.decode(None, LAND, 1), 6.0)  # MAVSDK: the autopilot is known otherwise
    assert (session.autopilot, session.mode, session.armed) == (Autopilot.ARDUPILOT, "LAND", False)
    assert Heartbeat.decode(PX4, 6 << 16, 0).autopilot is Autopilot.PX4
    assert Heartbeat.decode(99, 0, 0).autopilot is Autopilot.OTHER


def test_a_command_is_confirmed_only_by_a_heartbeat_after_its_ack() -> None:
    session = session_at()
    session.receive(CommandAck(Command.COMPONENT_ARM_DISARM, 0), 10.1)
    seen = session.acks[Command.COMPONENT_ARM_DISARM].heartbeats
    assert session.verdict(arming(True), seen) is Verdict.PENDING
    session.receive(heartbeat(armed=True), 11.0)
    assert session.verdict(arming(True), seen) is Verdict.CONFIRMED


def test_at_once_the_last_heartbeat_before_the_answer_may_confirm() -> None:
    """MAVSDK's answer and HEARTBEATs come on different threads: the state may already show it."""
    session = session_at()
    assert session.verdict(arming(False), session.heartbeats, at_once=True) is Verdict.CONFIRMED
    assert session.verdict(arming(False), session.heartbeats) is Verdict.PENDING


def test_one_heartbeat_with_the_old_state_is_forgiven_the_next_is_a_refusal() -> None:
    """PX4 may send one more HEARTBEAT with the old mode after its ACK; ArduCopter that ACKs a mode
    it does not take (before its position estimate) stays in STABILIZE."""
    session = session_at()
    seen = session.heartbeats
    session.receive(heartbeat(), 11.0)
    assert session.verdict(switching("GUIDED"), seen) is Verdict.PENDING
    session.receive(heartbeat(), 12.0)
    assert CONFIRM_HEARTBEATS == 2
    assert session.verdict(switching("GUIDED"), seen) is Verdict.REFUSED
    late = session_at()
    late.receive(heartbeat(), 11.0)
    late.receive(heartbeat(custom_mode=GUIDED), 12.0)
    assert late.verdict(switching("GUIDED"), 1) is Verdict.CONFIRMED


def test_a_refusal_gives_the_serious_texts_since_the_command() -> None:
    session = session_at()
    session.receive(StatusText(4, "PreArm: old news"), 9.0)
    session.receive(StatusText(6, "an info text"), 10.5)
    session.receive(StatusText(3, "Arm: Need Position Estimate"), 10.6)
    session.receive(StatusText(4, "PreArm: Gyros inconsistent"), 10.7)
    refused = session.refusal(switching("GUIDED"), since=10.0)
    assert isinstance(refused, VehicleCommandRejected) and refused.result == 0
    assert refused.command == "DO_SET_MODE GUIDED"
    assert refused.reason == ("acknowledged, but the vehicle stayed in STABILIZE "
                              "(Arm: Need Position Estimate; PreArm: Gyros inconsistent)")
    assert session.serious_since(10.65) == ["PreArm: Gyros inconsistent"]
    assert session.prearm_text() == "PreArm: Gyros inconsistent"
    assert session.refusal(arming(True), 20.0).reason == "acknowledged, but the vehicle is still disarmed"


def test_an_ack_counts_since_a_time_only_if_it_came_after() -> None:
    session = session_at()
    session.receive(CommandAck(Command.NAV_LAND, 4), 10.2)
    ack = session.ack_since(Command.NAV_LAND, 10.0)
    assert ack is not None and (ack.result, ack.heartbeats) == (4, 1)
    assert session.ack_since(Command.NAV_LAND, 10.3) is None
    assert session.ack_since(Command.NAV_TAKEOFF, 0.0) is None


def test_a_silent_vehicle_is_told_once_and_its_next_heartbeat_ends_the_silence() -> None:
    session = session_at(10.0)
    assert session.watch(13.0) is None, "within the timeout"
    silence = session.watch(13.5)
    assert silence is not None and "no HEARTBEAT for 3.5 s (timeout 3.0 s)" in str(silence)
    assert "vehicle 1 on tcp://127.0.0.1:5760" in str(silence)
    session.fail(silence)
    assert session.watch(14.0) is None, "already silent: told once"
    with pytest.raises(VehicleError, match="no HEARTBEAT"):
        session.check_alive()
    assert session.receive(heartbeat(), 14.5), "the silence is over: ask for the streams again"
    assert session.problem() is None and not session.receive(heartbeat(), 15.0)


def test_a_closed_or_lost_link_stays_dead_until_opened_again() -> None:
    session = session_at(10.0)
    session.fail(VehicleError("link closed"), final=True)
    session.fail(VehicleError("something later"), final=True)
    assert session.problem() == "link closed"
    assert session.watch(100.0) is None, "a dead link is not silent on top"
    session.receive(heartbeat(), 11.0)
    assert session.problem() == "link closed", "a HEARTBEAT does not reopen a stream"
    session.reopened(50.0)
    assert session.problem() is None and session.heartbeat_at == 50.0
    assert session.watch(53.0) is None, "a whole timeout to speak"


def test_the_link_state_changes_only_as_its_table_says() -> None:
    session = session_at(10.0)
    states = [(session.state, session.dead)]
    refusal = r"vehicle link tcp://127\.0\.0\.1:5760: 'reopened' in state alive cannot lead anywhere"
    with pytest.raises(ProtocolViolation, match=refusal):
        session.reopened(11.0)
    assert session.state is LinkState.ALIVE and session.heartbeat_at == 10.0, "an illegal event changes nothing"
    silence = session.watch(13.5)
    assert silence is not None
    session.fail(silence)
    states.append((session.state, session.dead))
    with pytest.raises(ProtocolViolation, match="'silence' in state silent cannot"):
        session.fail(VehicleError("silent again"))
    assert session.problem() == str(silence)
    session.fail(VehicleError("link closed"), final=True)
    states.append((session.state, session.dead))
    assert session.problem() == "link closed"
    with pytest.raises(ProtocolViolation, match="'silence' in state dead cannot"):
        session.fail(VehicleError("silent while dead"))
    session.reopened(50.0)
    states.append((session.state, session.dead))
    assert states == [(LinkState.ALIVE, False), (LinkState.SILENT, False), (LinkState.DEAD, True),
                      (LinkState.ALIVE, False)]


def test_a_mode_in_doubt_is_not_trusted() -> None:
    session = session_at(custom_mode=GUIDED)
    assert session.in_mode("GUIDED")
    session.mode_doubt.in_doubt = True  # a LAND given up before its confirmation
    assert not session.in_mode("GUIDED")
    assert landing(Autopilot.ARDUPILOT).met(False, "LAND") and not landing(Autopilot.ARDUPILOT).met(True, "GUIDED")
