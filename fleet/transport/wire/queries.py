"""The queries a drone answers: mail orders, cancellations and clearances (``mail/...``) and their
progress, clock pings (``clock/<drone>``) and an operator's commands (``command/<drone>``)."""

from __future__ import annotations

import enum
from typing import Annotated

import msgspec

from fleet.transport.wire.base import CellList, MailId, Priority, WireBody


class MailOrder(WireBody, frozen=True, kw_only=True, tag="mail"):
    id: MailId
    pickup: CellList
    dropoff: CellList
    priority: Priority
    note: str | None = None


class MailCancel(WireBody, frozen=True, kw_only=True, tag="mail_cancel"):
    id: str


class MailClear(WireBody, frozen=True, kw_only=True, tag="mail_clear"):
    """The service holds the mail as the drone's from now: it may take it on board."""

    id: str


class MailAck(WireBody, frozen=True, kw_only=True, tag="mail_ack"):
    id: str
    drone: str
    accepted: bool
    reason: str = ""


class MailStatus(enum.Enum):
    ACCEPTED = "accepted"
    STARTED = "started"
    PICKED_UP = "picked_up"
    DELIVERED = "delivered"
    REJECTED = "rejected"  #: the drone cannot fly it (handed back)
    HANDED_BACK = "handed_back"  #: the drone cannot fly it now; with no service, a peer takes it over
    FAILED = "failed"  #: lost (with a drone that left while carrying it)
    REASSIGNED = "reassigned"  #: a drone took over the mail of one that left
    CANCELLED = "cancelled"  #: dropped from the queue on request


class MailStatusReport(WireBody, frozen=True, kw_only=True, tag="mail_status"):
    id: str
    drone: str
    status: MailStatus
    step: int
    reason: str = ""


# ---------------------------------------------------------- clock, command
class ClockPing(WireBody, frozen=True, kw_only=True, tag="clock_ping"):
    pass


class ClockPong(WireBody, frozen=True, kw_only=True, tag="clock_pong"):
    pass


class CommandAction(enum.Enum):
    PAUSE = "pause"  #: start no mail; legs under way and mail on board are flown; then park
    RESUME = "resume"  #: undo every command below
    RECALL = "recall"  #: as pause, and hand back every mail not on board
    LAND = "land"  #: as recall, and stop where the drone is (through the protocol), until resumed
    RELEASE = "release"  #: the drone ``about``, gone, is out of the air for good: hold none of its cells


class FleetCommand(WireBody, frozen=True, kw_only=True, tag="command"):
    """An operator's command, from the service (``command/<drone>``); the reply is a ``command_ack``."""

    action: CommandAction
    by: Annotated[str, msgspec.Meta(max_length=200)]  #: who asked, for the drone's log
    about: Annotated[str, msgspec.Meta(max_length=64)] | None = None  #: the drone a release is about


class CommandAck(WireBody, frozen=True, kw_only=True, tag="command_ack"):
    drone: str
    action: CommandAction
    accepted: bool
    reason: str = ""
