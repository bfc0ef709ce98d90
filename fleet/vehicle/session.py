"""One vehicle's MAVLink session, without I/O: what both links know from the vehicle's own messages.

The links decode the wire (pymavlink, MAVSDK) and hand the session :data:`Inbound` messages with
the time they came (``now``); the session keeps the vehicle's system id, its HEARTBEAT state
(autopilot, mode, armed), the ACKs and the STATUSTEXTs, and answers what a link asks: whether a
message is the vehicle's, whether the vehicle fell silent, whether an acknowledged command is
confirmed (:meth:`MavlinkSession.verdict`), and why it was refused. No socket, thread, clock or
task lives here: the links await, the session only decides (skybrush-server's split).

Whether the link can carry commands is a :class:`LinkState`, changed only as
:data:`LINK_TRANSITIONS` says.
"""

from __future__ import annotations

import collections
import enum
from dataclasses import dataclass

from drona_gcs.errors import VehicleCommandRejected, VehicleError
from drona_gcs.stack.transitions import lookup
from fleet.vehicle.link import Autopilot
from fleet.vehicle.modes import ModeDoubt, mode_name
from fleet.vehicle.policy import CONFIRM_HEARTBEATS, Expectation, Result, explains_refusal

AUTOPILOT_COMPONENT = 1  #: MAV_COMP_ID_AUTOPILOT1
#: MAV_AUTOPILOT -> ours; MAV_AUTOPILOT_INVALID (8) is a ground station's or a camera's HEARTBEAT.
AUTOPILOTS = {3: Autopilot.ARDUPILOT, 12: Autopilot.PX4}
MAV_AUTOPILOT_INVALID, MAV_TYPE_GCS = 8, 6
SAFETY_ARMED = 128  #: MAV_MODE_FLAG_SAFETY_ARMED


@dataclass(frozen=True)
class Heartbeat:
    autopilot: Autopilot | None  #: None: not said (the link knows it another way)
    custom_mode: int
    armed: bool

    @classmethod
    def decode(cls, autopilot: int | None, custom_mode: int, base_mode: int) -> Heartbeat:
        """From HEARTBEAT's fields (``autopilot`` None: not read from it)."""
        kind = None if autopilot is None else AUTOPILOTS.get(autopilot, Autopilot.OTHER)
        return cls(kind, custom_mode, bool(base_mode & SAFETY_ARMED))


@dataclass(frozen=True)
class CommandAck:
    command: int
    result: int


@dataclass(frozen=True)
class StatusText:
    severity: int
    text: str


Inbound = Heartbeat | CommandAck | StatusText


@dataclass(frozen=True)
class Ack:
    """A command's last COMMAND_ACK: when, its MAV_RESULT, and the HEARTBEATs heard by then."""

    at: float
    result: int
    heartbeats: int


class Verdict(enum.Enum):
    PENDING = "pending"  #: not enough HEARTBEATs since the ACK to tell
    CONFIRMED = "confirmed"  #: a HEARTBEAT after the ACK shows the expected effect
    REFUSED = "refused"  #: acknowledged, yet CONFIRM_HEARTBEATS HEARTBEATs later still not done


class LinkState(enum.Enum):
    ALIVE = "alive"  #: the vehicle speaks (or has not yet had a whole timeout to)
    SILENT = "silent"  #: no HEARTBEAT for heartbeat_timeout: the next one ends the silence
    DEAD = "dead"  #: closed, or the stream is gone: until it is opened again


class LinkEvent(enum.Enum):
    HEARTBEAT = "heartbeat"  #: the vehicle's HEARTBEAT came
    SILENCE = "silence"  #: no HEARTBEAT for heartbeat_timeout (:meth:`MavlinkSession.watch`)
    LOST = "lost"  #: the link was closed, or its stream is gone
    REOPENED = "reopened"  #: the lost stream is open again


#: Every change of a link's state: LINK_TRANSITIONS[state][event] -> the state it leads to. A HEARTBEAT
#: does not reopen a dead link, and a silent or dead one is not told of a silence again.
LINK_TRANSITIONS: dict[LinkState, dict[LinkEvent, LinkState]] = {
    LinkState.ALIVE: {LinkEvent.HEARTBEAT: LinkState.ALIVE, LinkEvent.SILENCE: LinkState.SILENT,
                      LinkEvent.LOST: LinkState.DEAD},
    LinkState.SILENT: {LinkEvent.HEARTBEAT: LinkState.ALIVE, LinkEvent.LOST: LinkState.DEAD},
    LinkState.DEAD: {LinkEvent.HEARTBEAT: LinkState.DEAD, LinkEvent.LOST: LinkState.DEAD,
                     LinkEvent.REOPENED: LinkState.ALIVE},
}


def autopilot_heartbeat(autopilot: int, vehicle_type: int) -> bool:
    """A HEARTBEAT an autopilot sends (a ground station's says MAV_TYPE_GCS; a camera's, no autopilot)."""
    return autopilot != MAV_AUTOPILOT_INVALID and vehicle_type != MAV_TYPE_GCS


class MavlinkSession:
    """A vehicle as its messages describe it; ``where`` names the link in errors."""

    def __init__(self, where: str, heartbeat_timeout: float, target_system: int | None = None) -> None:
        self.where, self.heartbeat_timeout = where, heartbeat_timeout
        self.sysid = target_system  #: the vehicle's, fixed by its first HEARTBEAT (it must match if given)
        self.locked = False  #: sysid is fixed
        self.autopilot: Autopilot | None = None
        self.custom_mode: int | None = None
        self.armed = False
        self.heartbeats = 0
        self.heartbeat_at: float | None = None
        self.mode_doubt = ModeDoubt()
        self.acks: dict[int, Ack] = {}  #: command -> its last ACK
        self.texts: collections.deque[tuple[float, int, str]] = collections.deque(maxlen=32)
        self._state = LinkState.ALIVE
        self._error: VehicleError | None = None  #: why the link is silent or dead

    # ------------------------------------------------------------ inbound
    def accepts(self, system: int, component: int, heartbeat: bool) -> bool:
        """Whether a message from ``(system, component)`` is the vehicle's; the first autopilot HEARTBEAT
        (``heartbeat``: one of :func:`autopilot_heartbeat`) from a matching system fixes the system id."""
        if not self.locked and heartbeat and component == AUTOPILOT_COMPONENT and self.sysid in (None, system):
            self.sysid, self.locked = system, True
        return self.locked and (system, component) == (self.sysid, AUTOPILOT_COMPONENT)

    def receive(self, message: Inbound, now: float) -> bool:
        """Take the vehicle's ``message``; True for a HEARTBEAT that ends a silence (ask for the streams again)."""
        if isinstance(message, Heartbeat):
            return self._on_heartbeat(message, now)
        if isinstance(message, CommandAck):
            self.acks[message.command] = Ack(now, message.result, self.heartbeats)
        else:
            self.texts.append((now, message.severity, message.text))
        return False

    def _on_heartbeat(self, heartbeat: Heartbeat, now: float) -> bool:
        after_silence = self._state is LinkState.SILENT
        self.autopilot = heartbeat.autopilot or self.autopilot
        self.custom_mode, self.armed = heartbeat.custom_mode, heartbeat.armed
        self.heartbeats += 1
        self.heartbeat_at = now
        self._enter(LinkEvent.HEARTBEAT)
        return after_silence

    # ------------------------------------------------------------ liveness
    @property
    def state(self) -> LinkState:
        """Changed only by :meth:`_enter`, as :data:`LINK_TRANSITIONS` allows."""
        return self._state

    @property
    def dead(self) -> bool:
        """Closed, or the stream is gone (until it is opened again)."""
        return self._state is LinkState.DEAD

    def _enter(self, event: LinkEvent, error: VehicleError | None = None) -> None:
        """The one place the link's state changes: to where :data:`LINK_TRANSITIONS` says ``event`` leads;
        ``error`` says why, if it leads to a silent or dead link that was not already dead."""
        target = lookup(LINK_TRANSITIONS, f"vehicle link {self.where}", self._state, event)
        if target is LinkState.ALIVE:
            self._error = None
        elif self._state is not LinkState.DEAD:
            self._error = error
        self._state = target

    def watch(self, now: float) -> VehicleError | None:
        """The error to fail every wait with, if the vehicle has just been silent for too long."""
        if self.heartbeat_at is None or self._state is not LinkState.ALIVE \
                or now - self.heartbeat_at <= self.heartbeat_timeout:
            return None
        return VehicleError(f"vehicle {self.sysid} on {self.where}: no HEARTBEAT for "
                            f"{now - self.heartbeat_at:.1f} s (timeout {self.heartbeat_timeout} s)")

    def fail(self, error: VehicleError, final: bool = False) -> None:
        """``final``: the link is closed or its stream gone; otherwise the vehicle is silent (from :meth:`watch`)."""
        self._enter(LinkEvent.LOST if final else LinkEvent.SILENCE, error)

    def reopened(self, now: float) -> None:
        """The stream is open again: alive, and the vehicle has a whole timeout to speak."""
        self._enter(LinkEvent.REOPENED)
        self.heartbeat_at = now

    def problem(self) -> str | None:
        return None if self._error is None else str(self._error)

    def check_alive(self) -> None:
        if self._error is not None:
            raise self._error

    # ------------------------------------------------------------ state
    @property
    def mode(self) -> str | None:
        return mode_name(self.autopilot, self.custom_mode)

    def in_mode(self, mode: str) -> bool:
        """In ``mode`` for sure: no mode change is in doubt (see :class:`~fleet.vehicle.modes.ModeDoubt`)."""
        return self.mode == mode and not self.mode_doubt.in_doubt

    def prearm_text(self) -> str:
        """The autopilot's last "PreArm: ..." text, which says what fails."""
        return next((text for _, _, text in reversed(self.texts) if text.startswith("PreArm")), "")

    def serious_since(self, since: float) -> list[str]:
        """The STATUSTEXTs since ``since`` that may explain a refusal, oldest first."""
        return [text for at, severity, text in self.texts if at >= since and explains_refusal(severity)]

    def ack_since(self, command: int, since: float) -> Ack | None:
        ack = self.acks.get(command)
        return ack if ack is not None and ack.at >= since else None

    # ------------------------------------------------------------ confirmation
    def verdict(self, expect: Expectation, seen: int, at_once: bool = False) -> Verdict:
        """Whether the HEARTBEATs after an ACK (``seen``: HEARTBEATs heard by then) confirm ``expect``:
        from the first one after it (``at_once``: already from the last one before it), until
        CONFIRM_HEARTBEATS have come."""
        if self.heartbeats < seen + (0 if at_once else 1):
            return Verdict.PENDING
        if expect.met(self.armed, self.mode):
            return Verdict.CONFIRMED
        return Verdict.REFUSED if self.heartbeats >= seen + CONFIRM_HEARTBEATS else Verdict.PENDING

    def refusal(self, expect: Expectation, since: float) -> VehicleCommandRejected:
        """An acknowledged command the vehicle did not carry out, with what it said since ``since``."""
        texts = "; ".join(self.serious_since(since))
        reason = f"acknowledged, but the vehicle {expect.failure(self.mode)}" + (f" ({texts})" if texts else "")
        return VehicleCommandRejected(expect.label, int(Result.ACCEPTED), reason)
