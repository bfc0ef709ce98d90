"""What travels over Zenoh: versioned, validated JSON messages.

Every payload is one :class:`Envelope`: the format version ``v``, the
``sender`` and its clock time ``sent_at`` (seconds since the Unix epoch on the
sender's clock), and one ``body`` tagged by ``kind``. A payload that is not
valid JSON, has another version, names a kind we do not know, or carries a
field that is missing, mistyped or unknown raises :class:`WireError`; the
receiving side logs it and drops it (a foreign or malformed message is never
fatal).

The bodies, by key (see :mod:`fleet.transport.keys`):

* ``proto/<drone>``: ``req_traj`` and ``cur_traj``, Protocol 1's two messages.
* ``proto/all``: a ``req_traj`` to everyone.
* ``answers``: ``cur_traj_to``, one trajectory answering the requests of
  several drones at once (a new plan, to every drone that waited for it),
  which each drone named in ``replies`` takes as its ``cur_traj`` and the
  others ignore.
* ``plan/<drone>``: ``plan``, a drone's new trajectory once planned.
* ``state/<drone>``: ``state``, what a drone publishes at every step boundary
  and answers queries with (cell, trajectory, battery, task, queue, health).
* ``held/<drone>``: ``held``, the mail a drone holds, when it changes (and
  on query): what its heir takes over if it leaves.
* ``mail/assign/<drone>``: a query whose payload is a ``mail`` order; the
  drone replies ``mail_ack`` (accepted, or refused with the reason).
* ``mail/cancel/<drone>``: a query with a ``mail_cancel``; ``mail_ack``
  accepted if the mail was still waiting (it is dropped), refused if under way.
* ``mail/status/<mail id>``: ``mail_status`` reports as a mail moves.
* ``clock/<drone>``: a query with a ``clock_ping``; the reply is a
  ``clock_pong`` with the peer's clock (offset estimation).
"""

from __future__ import annotations

import enum
import functools
from collections.abc import Mapping
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from drona_gcs.errors import DronaError
from drona_gcs.motion import Trajectory
from drona_gcs.stack.messages import CurrentTraj, Message, ReqForCurrentTraj, TaskId

#: 2: a Zenoh message may carry several envelopes, one per line (fleet.transport.node);
#: 3: ``cur_traj_to``, one answer to several drones.
VERSION = 3

CellList = Annotated[list[int], Field(min_length=3, max_length=3)]


class WireError(DronaError):
    """A payload that is not a valid message of this version."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)


class WireTaskId(_Strict):
    stamp: int
    drone: str
    seq: int

    @classmethod
    def of(cls, task_id: TaskId) -> WireTaskId:
        return cls(stamp=task_id.stamp, drone=task_id.drone, seq=task_id.seq)

    def core(self) -> TaskId:
        return TaskId(self.stamp, self.drone, self.seq)


class WireTrajectory(_Strict):
    start_step: int
    cells: Annotated[list[CellList], Field(min_length=1)]

    @classmethod
    def of(cls, trajectory: Trajectory) -> WireTrajectory:
        """Remembered for the last few trajectories: a drone answers every request of a round, and
        publishes its state, with the same one. Shared, so never to be changed in place."""
        return _wire_trajectory(trajectory)

    def core(self) -> Trajectory:
        # Each cell is three ints (validated): tuple() of it is a Cell, at C speed.
        return Trajectory(self.start_step, tuple(map(tuple, self.cells)))  # type: ignore[arg-type]


@functools.lru_cache(maxsize=256)
def _wire_trajectory(trajectory: Trajectory) -> WireTrajectory:
    return WireTrajectory(start_step=trajectory.start_step, cells=[list(c) for c in trajectory.cells])


# ------------------------------------------------------------- protocol
class ReqTraj(_Strict):
    kind: Literal["req_traj"] = "req_traj"
    task_id: WireTaskId


class CurTraj(_Strict):
    kind: Literal["cur_traj"] = "cur_traj"
    in_reply_to: WireTaskId
    trajectory: WireTrajectory


class CurTrajTo(_Strict):
    """One trajectory answering several drones' requests: ``replies`` maps each drone to its request."""

    kind: Literal["cur_traj_to"] = "cur_traj_to"
    replies: Annotated[dict[str, WireTaskId], Field(min_length=1)]
    trajectory: WireTrajectory


class PlanAnnounce(_Strict):
    """A drone's new plan, to everyone, once made (peers outside the round learn where it goes)."""

    kind: Literal["plan"] = "plan"
    trajectory: WireTrajectory


# ---------------------------------------------------------------- state
class Health(_Strict):
    ok: bool = True
    alarms: list[str] = Field(default_factory=list)


class TaskView(_Strict):
    goal: CellList
    purpose: str
    mail_id: str | None = None


class MailView(_Strict):
    """A mail a drone holds: queued, current (flying to its pickup) or on board."""

    id: str
    pickup: CellList
    dropoff: CellList
    priority: int
    stage: Literal["queued", "current", "carrying"]


class DroneState(_Strict):
    kind: Literal["state"] = "state"
    drone: str
    step: int
    cell: CellList  #: where the stack holds the drone (its executor's cell)
    actual: CellList | None = None  #: where telemetry puts the vehicle
    position: tuple[float, float, float] | None = None  #: lat, lon, alt_m (AMSL)
    battery_pct: float | None = None
    mode: str  #: the protocol's state
    phase: str  #: the task planner's phase
    landed: bool
    task: TaskView | None = None
    trajectory: WireTrajectory | None = None
    mail: list[MailView] = Field(default_factory=list)
    health: Health = Field(default_factory=Health)
    clock_offset_s: dict[str, float] = Field(default_factory=dict)  #: measured offset of each peer's clock
    plans: int = 0  #: plans made so far
    messages_sent: int = 0  #: protocol messages sent so far
    coordination_ms: float | None = None  #: the last plan's: task arrival to plan scheduled


class HeldMail(_Strict):
    """The mail a drone holds, published when it changes: a drone's heir takes it over if it leaves."""

    kind: Literal["held"] = "held"
    drone: str
    mail: list[MailView]


# ----------------------------------------------------------------- mail
class MailOrder(_Strict):
    kind: Literal["mail"] = "mail"
    id: Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.:-]+$")]
    pickup: CellList
    dropoff: CellList
    priority: Annotated[int, Field(ge=0, le=9)]
    note: str | None = None


class MailCancel(_Strict):
    kind: Literal["mail_cancel"] = "mail_cancel"
    id: str


class MailAck(_Strict):
    kind: Literal["mail_ack"] = "mail_ack"
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
    FAILED = "failed"  #: lost (with a drone that left while carrying it)
    REASSIGNED = "reassigned"  #: a drone took over the mail of one that left
    CANCELLED = "cancelled"  #: dropped from the queue on request


class MailStatusReport(_Strict):
    kind: Literal["mail_status"] = "mail_status"
    id: str
    drone: str
    status: MailStatus
    step: int
    reason: str = ""


# ---------------------------------------------------------------- clock
class ClockPing(_Strict):
    kind: Literal["clock_ping"] = "clock_ping"


class ClockPong(_Strict):
    kind: Literal["clock_pong"] = "clock_pong"


Body = Annotated[
    ReqTraj | CurTraj | CurTrajTo | PlanAnnounce | DroneState | HeldMail | MailOrder | MailCancel | MailAck
    | MailStatusReport | ClockPing | ClockPong,
    Field(discriminator="kind"),
]


class Envelope(_Strict):
    v: Literal[3] = VERSION
    sender: Annotated[str, Field(min_length=1)]
    sent_at: float
    body: Body


def encode(sender: str, sent_at: float, body: Body) -> bytes:
    return Envelope(sender=sender, sent_at=sent_at, body=body).model_dump_json().encode()


@functools.lru_cache(maxsize=256)
def decode(payload: bytes) -> Envelope:
    """The envelope in ``payload``; :class:`WireError` naming what is wrong otherwise.

    Remembered for the last few payloads: a message to everyone reaches every drone of a
    process as the same bytes (one Zenoh subscriber per process), and validating it once is
    enough. The drones then share one envelope: it is frozen, and its lists (cells, mail)
    must not be changed in place either.
    """
    try:
        return Envelope.model_validate_json(payload)
    except ValidationError as exc:
        problems = "; ".join(f"{'.'.join(map(str, e['loc'])) or 'payload'}: {e['msg']}" for e in exc.errors()[:3])
        raise WireError(f"malformed message: {problems}") from exc


# ------------------------------------------------------ core <-> wire
def from_core(message: Message) -> ReqTraj | CurTraj:
    if isinstance(message, ReqForCurrentTraj):
        return ReqTraj(task_id=WireTaskId.of(message.task_id))
    return CurTraj(in_reply_to=WireTaskId.of(message.in_reply_to), trajectory=WireTrajectory.of(message.trajectory))


def answers(trajectory: Trajectory, replies: Mapping[str, TaskId]) -> CurTrajTo:
    """One ``cur_traj_to`` for several ``CurrentTraj`` with the same trajectory: ``replies`` maps
    each drone answered to the request it answers."""
    return CurTrajTo(replies={drone: WireTaskId.of(task) for drone, task in replies.items()},
                     trajectory=WireTrajectory.of(trajectory))


def to_core(envelope: Envelope, me: str) -> Message | None:
    """The protocol message for drone ``me`` in ``envelope`` (the sender is the envelope's); None
    for a ``cur_traj_to`` that answers others only."""
    body = envelope.body
    if isinstance(body, ReqTraj):
        return ReqForCurrentTraj(body.task_id.core(), envelope.sender)
    if isinstance(body, CurTraj):
        request = body.in_reply_to
    elif isinstance(body, CurTrajTo):
        found = body.replies.get(me)
        if found is None:
            return None
        request = found
    else:
        raise WireError(f"{body.kind} is not a protocol message")
    try:
        return CurrentTraj(envelope.sender, body.trajectory.core(), request.core())
    except DronaError as exc:
        raise WireError(f"{body.kind} from {envelope.sender!r}: {exc}") from exc
