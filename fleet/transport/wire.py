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
* ``proto/<sender>/all``: a ``req_traj`` to everyone; ``propose``, a plan made, and ``decide``, whether
  it is flown (``proto/<sender>/<drone>``: ``ack``, the drone holds the proposal).
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
"""

from __future__ import annotations

import enum
import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Annotated, Any, Final, Literal, TypeVar

import msgspec

from drona_gcs.errors import DronaError
from drona_gcs.motion import Trajectory
from drona_gcs.stack.messages import (
    CurrentTraj,
    Message,
    PlanAck,
    PlanDecision,
    PlanProposal,
    PlanRefusal,
    ReqForCurrentTraj,
    TaskId,
)

#: 2: a Zenoh message may carry several envelopes, one per line (fleet.transport.node);
#: 3: ``cur_traj_to``, one answer to several drones;
#: 4: ``req_traj`` carries the requester's trajectory (its answer to the drones before it in line);
#: 5: protocol messages carry ``holds``, the cells a drone whose vehicle is lost holds besides its trajectory;
#: 6: ``req_traj`` carries ``asked``, the peers its round waits for, and ``clear``, a way the requester
#: asks resting drones to leave; task ids carry the ``epoch`` (incarnation) of the agent that made them;
#: ``plan`` says ``grounded`` when a vehicle came down by itself;
#: 7: keys name their writer (``proto/<sender>/<to>``, ``answers/<sender>``, ``mail/status/<drone>/<mail>``).
#: 8: ``plan`` says ``braked``;
#: 9: ``propose``, ``ack`` and ``decide``: a plan is flown once every member holds it; ``plan`` says ``lost``.
#: 10: ``held`` lists mail handed back that no peer holds yet, and a status says ``handed_back``; ``refuse``.
#: 11: ``mail_clear``, the service's clearance to take a mail on board.
#: 13: a host's drones send to one drone on ``proto/<host>/<to>``, several messages in one.
VERSION: Final = 13

CellList = Annotated[list[int], msgspec.Meta(min_length=3, max_length=3)]
#: A mail id is a Zenoh key chunk (mail/status/<id>); \Z, not $: "$" would let a final newline through.
MailId = Annotated[str, msgspec.Meta(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.:-]+\Z")]
Priority = Annotated[int, msgspec.Meta(ge=0, le=9)]
#: A trajectory's cells are tuples as they come off the wire: a core Trajectory takes them as they are.
CellTuples = Annotated[tuple[tuple[int, int, int], ...], msgspec.Meta(min_length=1)]
Holds = tuple[tuple[int, int, int], ...]


class WireError(DronaError):
    """A payload that is not a valid message of this version."""


class _Strict(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Every wire type: immutable, built by keyword, and no field it does not know (msgspec validates on
    decoding, strictly: no "12" for 12; a message built here is checked with :func:`checked`)."""


class _Body(_Strict, frozen=True, kw_only=True, tag_field="kind"):
    """An envelope's body, told apart by its ``kind``."""

    @property
    def kind(self) -> str:
        return str(type(self).__struct_config__.tag)


class WireTaskId(_Strict, frozen=True, kw_only=True):
    stamp: int
    drone: str
    seq: int
    epoch: int = 0  #: the incarnation of the agent that made it

    @classmethod
    def of(cls, task_id: TaskId) -> WireTaskId:
        return cls(stamp=task_id.stamp, drone=task_id.drone, seq=task_id.seq, epoch=task_id.epoch)

    def core(self) -> TaskId:
        return TaskId(self.stamp, self.drone, self.seq, self.epoch)


class WireTrajectory(_Strict, frozen=True, kw_only=True):
    start_step: int
    cells: CellTuples

    @classmethod
    def of(cls, trajectory: Trajectory) -> WireTrajectory:
        return cls(start_step=trajectory.start_step, cells=trajectory.cells)

    def core(self) -> Trajectory:
        return Trajectory(self.start_step, self.cells)


# ------------------------------------------------------------- protocol
class ReqTraj(_Body, frozen=True, kw_only=True, tag="req_traj"):
    task_id: WireTaskId
    trajectory: WireTrajectory  #: the requester's, which a drone before it in line takes as its answer
    asked: tuple[str, ...]  #: the peers its round waits for
    holds: Holds = ()  #: cells its lost vehicle may be in, besides the trajectory
    clear: Holds = ()  #: a way to its goal that drones resting on it are asked to leave


class CurTraj(_Body, frozen=True, kw_only=True, tag="cur_traj"):
    in_reply_to: WireTaskId
    trajectory: WireTrajectory
    holds: Holds = ()


class CurTrajTo(_Body, frozen=True, kw_only=True, tag="cur_traj_to"):
    """One trajectory answering several drones' requests: ``replies`` maps each drone to its request."""

    replies: Annotated[dict[str, WireTaskId], msgspec.Meta(min_length=1)]
    trajectory: WireTrajectory
    holds: Holds = ()


class Propose(_Body, frozen=True, kw_only=True, tag="propose"):
    """A plan made, flown once every member holds it (acknowledged with ``ack``)."""

    task_id: WireTaskId
    trajectory: WireTrajectory
    members: tuple[str, ...]  #: the drones that must hold it


class Ack(_Body, frozen=True, kw_only=True, tag="ack"):
    task_id: WireTaskId  #: the proposal held
    trajectory: WireTrajectory  #: what the sender flies
    holds: Holds = ()  #: cells its lost vehicle may be in, besides the trajectory


class Refuse(_Body, frozen=True, kw_only=True, tag="refuse"):
    """A proposal the sender will not hold; ``gone``: for each drone the proposer held as gone, every cell
    the sender holds it may be in for good."""

    task_id: WireTaskId
    gone: dict[str, Holds] = {}


class Decide(_Body, frozen=True, kw_only=True, tag="decide"):
    """What the proposer flies from now: the proposal (``flown``), or what it flew before. It answers
    too, as ``cur_traj_to`` does, the drones in ``replies`` (each to its request), whose rounds waited
    for it: one message for both, since every drone gets the decision anyway."""

    task_id: WireTaskId
    trajectory: WireTrajectory
    flown: bool
    replies: dict[str, WireTaskId] = {}
    holds: Holds = ()  #: of the answers: cells the sender's lost vehicle may be in


class PlanAnnounce(_Body, frozen=True, kw_only=True, tag="plan"):
    """A drone's new plan, to everyone, once made (peers outside the round learn where it goes);
    ``grounded``: its vehicle came down by itself, and stays at the trajectory's end for good;
    ``braked``: it cut the plan it flies short, and holds at the trajectory's end until its next plan;
    ``lost``: its vehicle is lost, and may be in any of ``holds`` for good (none: it is back)."""

    trajectory: WireTrajectory
    grounded: bool = False
    braked: bool = False
    lost: bool = False
    holds: Holds = ()


# ---------------------------------------------------------------- state
class Health(_Strict, frozen=True, kw_only=True):
    ok: bool = True
    alarms: list[str] = msgspec.field(default_factory=list)


class TaskView(_Strict, frozen=True, kw_only=True):
    goal: CellList
    purpose: str
    mail_id: str | None = None


class MailView(_Strict, frozen=True, kw_only=True):
    """A mail a drone holds: queued, current (flying to its pickup) or on board; or one it handed back
    that no peer has taken over yet (with no service, its heir adopts it)."""

    id: MailId  #: a departed peer's mail is taken over from these: checked as an order is
    pickup: CellList
    dropoff: CellList
    priority: Priority
    stage: Literal["queued", "current", "carrying", "handed_back"]


class VehicleView(_Strict, frozen=True, kw_only=True):
    """What the vehicle itself last reported, and whether it can fly plans."""

    status: Literal["ready", "waiting_for_position", "not_ready", "lost"]
    reason: str = ""  #: what keeps it from flying plans
    mode: str | None = None
    armed: bool = False
    landed: str = "undefined"  #: MAV_LANDED_STATE, lower case: on_ground, takeoff, in_air, landing
    height_m: float | None = None  #: above home
    gps_fix: int = 0  #: GPS_FIX_TYPE: 3 is a 3D fix
    satellites: int = 0
    battery_v: float | None = None


class DroneState(_Body, frozen=True, kw_only=True, tag="state"):
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
    mail: list[MailView] = msgspec.field(default_factory=list)
    health: Health = msgspec.field(default_factory=Health)
    clock_offset_s: dict[str, float] = msgspec.field(default_factory=dict)  #: measured offset of each peer's clock
    plans: int = 0  #: plans made so far
    messages_sent: int = 0  #: protocol messages sent so far
    coordination_ms: float | None = None  #: the last plan's: task arrival to plan scheduled
    command: str | None = None  #: the operator's command in force: pause, recall or land (None: none)
    vehicle: VehicleView | None = None


class HeldMail(_Body, frozen=True, kw_only=True, tag="held"):
    """The mail a drone holds, published when it changes: a drone's heir takes it over if it leaves."""

    drone: str
    mail: list[MailView]


# ----------------------------------------------------------------- mail
class MailOrder(_Body, frozen=True, kw_only=True, tag="mail"):
    id: MailId
    pickup: CellList
    dropoff: CellList
    priority: Priority
    note: str | None = None


class MailCancel(_Body, frozen=True, kw_only=True, tag="mail_cancel"):
    id: str


class MailClear(_Body, frozen=True, kw_only=True, tag="mail_clear"):
    """The service holds the mail as the drone's from now: it may take it on board."""

    id: str


class MailAck(_Body, frozen=True, kw_only=True, tag="mail_ack"):
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


class MailStatusReport(_Body, frozen=True, kw_only=True, tag="mail_status"):
    id: str
    drone: str
    status: MailStatus
    step: int
    reason: str = ""


# ---------------------------------------------------------------- clock
class ClockPing(_Body, frozen=True, kw_only=True, tag="clock_ping"):
    pass


class ClockPong(_Body, frozen=True, kw_only=True, tag="clock_pong"):
    pass


class CommandAction(enum.Enum):
    PAUSE = "pause"  #: start no mail; legs under way and mail on board are flown; then park
    RESUME = "resume"  #: undo every command below
    RECALL = "recall"  #: as pause, and hand back every mail not on board
    LAND = "land"  #: as recall, and stop where the drone is (through the protocol), until resumed
    RELEASE = "release"  #: the drone ``about``, gone, is out of the air for good: hold none of its cells


class FleetCommand(_Body, frozen=True, kw_only=True, tag="command"):
    """An operator's command, from the service (``command/<drone>``); the reply is a ``command_ack``."""

    action: CommandAction
    by: Annotated[str, msgspec.Meta(max_length=200)]  #: who asked, for the drone's log
    about: Annotated[str, msgspec.Meta(max_length=64)] | None = None  #: the drone a release is about


class CommandAck(_Body, frozen=True, kw_only=True, tag="command_ack"):
    drone: str
    action: CommandAction
    accepted: bool
    reason: str = ""


Body = (ReqTraj | CurTraj | CurTrajTo | Propose | Ack | Refuse | Decide | PlanAnnounce | DroneState | HeldMail
        | MailOrder | MailCancel | MailClear | MailAck | MailStatusReport | ClockPing | ClockPong | FleetCommand
        | CommandAck)


class Envelope(_Strict, frozen=True, kw_only=True):
    v: Literal[13] = VERSION
    sender: Annotated[str, msgspec.Meta(min_length=1)]
    sent_at: float
    body: Body


_ENCODER = msgspec.json.Encoder()
_DECODER = msgspec.json.Decoder(Envelope)


#: How far ahead of the receiver's step a task id's stamp may be. Stamps follow the sender's step (a hybrid
#: clock: a burst of ids in one step runs a few ahead); a stamp far beyond would drag every clock it reaches.
STAMP_AHEAD_STEPS: Final = 1000


@dataclass(frozen=True)
class PeerBounds:
    """What a peer's protocol message or plan may carry in this workspace: cells inside it,
    trajectories no plan here can outgrow (a plan and the one it was spliced onto, each at most
    L_max long: twice that again for margin), task ids not far ahead of our clock."""

    size: tuple[int, int, int]
    max_cells: int

    @classmethod
    def of(cls, size: tuple[int, int, int], plan_length_limit: int) -> PeerBounds:
        return cls(size, 4 * (plan_length_limit + 1))

    def check(self, body: Body, now: int) -> None:
        """:class:`WireError` naming what is out of bounds."""
        trajectory = getattr(body, "trajectory", None)
        if isinstance(trajectory, WireTrajectory):
            if len(trajectory.cells) > self.max_cells:
                raise WireError(f"a trajectory of {len(trajectory.cells)} cells: no plan here has more than "
                                f"{self.max_cells}")
            self._inside(trajectory.cells)
        self._inside((*getattr(body, "holds", ()), *getattr(body, "clear", ())))
        if isinstance(body, Refuse):
            for drone, cells in body.gone.items():
                if len(cells) > self.max_cells:
                    raise WireError(f"{len(cells)} cells held for {drone!r}: no plan here has more than "
                                    f"{self.max_cells}")
                self._inside(cells)
        for task_id in _task_ids(body):
            if task_id.stamp > now + STAMP_AHEAD_STEPS:
                raise WireError(f"task id stamp {task_id.stamp} is {task_id.stamp - now} steps ahead of this "
                                f"clock (at most {STAMP_AHEAD_STEPS})")

    def _inside(self, cells: Sequence[tuple[int, int, int]]) -> None:
        width, depth, height = self.size
        for cell in cells:
            x, y, z = cell
            if not (0 <= x < width and 0 <= y < depth and 0 <= z < height):
                raise WireError(f"cell {list(cell)} is outside the {'x'.join(map(str, self.size))} workspace")


def _task_ids(body: Body) -> list[WireTaskId]:
    if isinstance(body, Decide):
        return [body.task_id, *body.replies.values()]
    if isinstance(body, (ReqTraj, Propose, Ack, Refuse)):
        return [body.task_id]
    if isinstance(body, CurTraj):
        return [body.in_reply_to]
    if isinstance(body, CurTrajTo):
        return list(body.replies.values())
    return []


def encode(sender: str, sent_at: float, body: Body) -> bytes:
    return _ENCODER.encode(Envelope(sender=sender, sent_at=sent_at, body=body))


@functools.lru_cache(maxsize=256)
def decode(payload: bytes) -> Envelope:
    """The envelope in ``payload``; :class:`WireError` naming what is wrong otherwise.

    Remembered for the last few payloads: a message to everyone reaches every drone of a
    process as the same bytes (one Zenoh subscriber per process), and validating it once is
    enough. The drones then share one envelope: it is frozen, and its lists (cells, mail)
    must not be changed in place either.
    """
    try:
        return _DECODER.decode(payload)
    except msgspec.DecodeError as exc:  # its ValidationError too: msgspec names the field ("at `$.body.id`")
        raise WireError(f"malformed message: {exc}") from exc
    except UnicodeDecodeError as exc:  # msgspec lets a string that is not UTF-8 through as this
        raise WireError(f"malformed message: not UTF-8: {exc.reason} at byte {exc.start}") from exc


T = TypeVar("T", bound=_Strict)


def decode_as(payload: bytes, kind: type[T], what: str) -> T:
    """The body of ``payload``, which must be a ``kind`` (``what``, in the error); :class:`WireError`
    naming what is wrong otherwise."""
    body = decode(payload).body
    if not isinstance(body, kind):
        raise WireError(f"expected {what}, got {body.kind}")
    return body


def checked(kind: type[T], /, **fields: Any) -> T:
    """A message built from ``fields`` and validated as if it had come over the wire (building one by
    hand checks nothing); :class:`WireError` naming what is wrong (a mail order typed by an operator)."""
    try:
        return msgspec.convert(fields, kind)
    except msgspec.ValidationError as exc:
        raise WireError(f"{exc}") from exc


def to_json(message: _Strict) -> dict[str, Any]:
    """``message`` as plain JSON values (a body without its ``kind``)."""
    record: dict[str, Any] = msgspec.to_builtins(message)
    record.pop("kind", None)
    return record


# ------------------------------------------------------ core <-> wire
ProtocolBody = ReqTraj | CurTraj | Propose | Ack | Refuse | Decide


def from_core(message: Message) -> ProtocolBody:
    if isinstance(message, ReqForCurrentTraj):
        return ReqTraj(task_id=WireTaskId.of(message.task_id), trajectory=WireTrajectory.of(message.trajectory),
                       asked=message.asked, holds=message.holds, clear=message.clear)
    if isinstance(message, PlanProposal):
        return Propose(task_id=WireTaskId.of(message.task_id), trajectory=WireTrajectory.of(message.trajectory),
                       members=message.members)
    if isinstance(message, PlanAck):
        return Ack(task_id=WireTaskId.of(message.task_id), trajectory=WireTrajectory.of(message.trajectory),
                   holds=message.holds)
    if isinstance(message, PlanRefusal):
        return Refuse(task_id=WireTaskId.of(message.task_id), gone=dict(message.gone))
    if isinstance(message, PlanDecision):
        return Decide(task_id=WireTaskId.of(message.task_id), trajectory=WireTrajectory.of(message.trajectory),
                      flown=message.flown)
    return CurTraj(in_reply_to=WireTaskId.of(message.in_reply_to), trajectory=WireTrajectory.of(message.trajectory),
                   holds=message.holds)


def answers(trajectory: Trajectory, replies: Mapping[str, TaskId], holds: Holds = ()) -> CurTrajTo:
    """One ``cur_traj_to`` for several ``CurrentTraj`` with the same trajectory and holds: ``replies``
    maps each drone answered to the request it answers."""
    return CurTrajTo(replies={drone: WireTaskId.of(task) for drone, task in replies.items()},
                     trajectory=WireTrajectory.of(trajectory), holds=holds)


def answering(decision: PlanDecision, replies: Mapping[str, TaskId], holds: Holds = ()) -> Decide:
    """A ``decide`` that also answers the drones in ``replies`` with the trajectory it names."""
    return Decide(task_id=WireTaskId.of(decision.task_id), trajectory=WireTrajectory.of(decision.trajectory),
                  flown=decision.flown, replies={drone: WireTaskId.of(task) for drone, task in replies.items()},
                  holds=holds)


def answer_in(envelope: Envelope, me: str) -> CurrentTraj | None:
    """The answer to drone ``me``'s request that a ``cur_traj_to`` or ``decide`` carries, if any."""
    body = envelope.body
    if not isinstance(body, (CurTrajTo, Decide)):
        return None
    found = body.replies.get(me)
    return None if found is None else _answer(envelope.sender, body, found)


def _answer(sender: str, body: CurTraj | CurTrajTo | Decide, request: WireTaskId) -> CurrentTraj:
    try:
        return CurrentTraj(sender, body.trajectory.core(), request.core(), body.holds)
    except DronaError as exc:
        raise WireError(f"{body.kind} from {sender!r}: {exc}") from exc


def to_core(envelope: Envelope, me: str) -> Message | None:
    """The protocol message for drone ``me`` in ``envelope`` (the sender is the envelope's); None
    for a ``cur_traj_to`` that answers others only."""
    body = envelope.body
    if isinstance(body, ReqTraj):
        return ReqForCurrentTraj(body.task_id.core(), envelope.sender, body.trajectory.core(), body.asked,
                                 body.holds, body.clear)
    if isinstance(body, Propose):
        return PlanProposal(envelope.sender, body.task_id.core(), body.trajectory.core(), body.members)
    if isinstance(body, Ack):
        return PlanAck(envelope.sender, body.task_id.core(), body.trajectory.core(), body.holds)
    if isinstance(body, Refuse):
        return PlanRefusal(envelope.sender, body.task_id.core(), tuple(sorted(body.gone.items())))
    if isinstance(body, Decide):
        return PlanDecision(envelope.sender, body.task_id.core(), body.trajectory.core(), body.flown)
    if isinstance(body, CurTraj):
        return _answer(envelope.sender, body, body.in_reply_to)
    if isinstance(body, CurTrajTo):
        return answer_in(envelope, me)
    raise WireError(f"{body.kind} is not a protocol message")

