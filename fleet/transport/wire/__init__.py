"""What travels over Zenoh: versioned JSON messages, validated by msgspec.

Every payload is one :class:`Envelope`: the format version ``v``, the
``sender`` and its clock time ``sent_at`` (seconds since the Unix epoch on the
sender's clock), and one ``body`` tagged by ``kind``. A payload that is not
valid JSON, has another version, names a kind we do not know, or carries a
field that is missing, mistyped or unknown raises :class:`WireError`; the
receiving side logs it and drops it (a foreign or malformed message is never
fatal).

The bodies, by key (see :mod:`fleet.transport.keys`):

* ``proto/<sender>/<drone>``: ``req_traj`` and ``cur_traj``, Protocol 1's two messages (``<sender>``
  may be a host: then each frame is from one of its drones)
  (``req_traj`` carries the requester's trajectory: see :mod:`drona_gcs.stack.protocol`).
* ``proto/<sender>/all``: a ``req_traj`` to everyone; ``propose``, a plan made (and the answer, in
  ``replies``, to the drones that waited for it), and ``decide``, whether it is flown
  (``proto/<sender>/<drone>``: ``ack``, the drone holds the proposal).
* ``answers/<sender>``: ``cur_traj_to``, one trajectory answering the requests of
  several drones at once (a new plan, to every drone that waited for it),
  which each drone named in ``replies`` takes as its ``cur_traj`` and the
  others ignore.
* ``plan/<drone>``: ``plan``, a drone's vehicle down, or its plan cut short.
* ``state/<drone>``: ``state``, what a drone publishes at every step boundary
  and answers queries with (cell, trajectory, battery, task, queue, health).
* ``held/<drone>``: ``held``, the mail a drone holds, when it changes (and
  on query): what its heir takes over if it leaves.
* ``mail/assign/<drone>``: a query whose payload is a ``mail`` order; the
  drone replies ``mail_ack`` (accepted, or refused with the reason).
* ``mail/cancel/<drone>``: a query with a ``mail_cancel``; ``mail_ack``
  accepted if the mail was still waiting (it is dropped), refused if under way.
* ``mail/status/<drone>/<mail id>``: ``mail_status`` reports as a mail its drone holds moves.

A receiver takes a message only from the peer that may write its key (:meth:`FleetKeys.writer`,
enforced by the fleet's access control) and only within :class:`PeerBounds`.
* ``clock/<drone>``: a query with a ``clock_ping``; the reply is a
  ``clock_pong`` with the peer's clock (offset estimation).
* ``command/<drone>``: a query with an operator's ``command`` (only the service may ask); the
  reply is a ``command_ack``.

The messages, one module each group: :mod:`~fleet.transport.wire.protocol` (between drones),
:mod:`~fleet.transport.wire.state` (what a drone publishes), :mod:`~fleet.transport.wire.queries`
(mail, clock, commands); :mod:`~fleet.transport.wire.envelope` encodes and decodes them and
:mod:`~fleet.transport.wire.core` turns Protocol 1's into the core's and back. Every name is importable
from here.
"""

from fleet.transport.wire.base import (
    VERSION,
    CellList,
    CellTuples,
    Holds,
    MailId,
    Priority,
    WireBody,
    WireError,
    WireStruct,
    WireTaskId,
    WireTrajectory,
)
from fleet.transport.wire.core import ProtocolBody, answer_in, answering, answers, from_core, proposing, to_core
from fleet.transport.wire.envelope import (
    STAMP_AHEAD_STEPS,
    Body,
    Envelope,
    PeerBounds,
    checked,
    decode,
    decode_as,
    encode,
    to_json,
)
from fleet.transport.wire.protocol import Ack, CurTraj, CurTrajTo, Decide, PlanAnnounce, Propose, Refuse, ReqTraj
from fleet.transport.wire.queries import (
    ClockPing,
    ClockPong,
    CommandAck,
    CommandAction,
    FleetCommand,
    MailAck,
    MailCancel,
    MailClear,
    MailOrder,
    MailStatus,
    MailStatusReport,
)
from fleet.transport.wire.state import DroneState, Health, HeldMail, MailView, TaskView, VehicleView

__all__ = [
    "STAMP_AHEAD_STEPS", "VERSION", "Ack", "Body", "CellList", "CellTuples", "ClockPing", "ClockPong", "CommandAck",
    "CommandAction", "CurTraj", "CurTrajTo", "Decide", "DroneState", "Envelope", "FleetCommand", "Health", "HeldMail",
    "Holds", "MailAck", "MailCancel", "MailClear", "MailId", "MailOrder", "MailStatus", "MailStatusReport",
    "MailView", "PeerBounds", "PlanAnnounce", "Priority", "Propose", "ProtocolBody", "Refuse", "ReqTraj",
    "TaskView", "VehicleView", "WireBody", "WireError", "WireStruct", "WireTaskId", "WireTrajectory", "answer_in",
    "answering", "answers", "checked", "decode", "decode_as", "encode", "from_core", "proposing", "to_core", "to_json",
]
