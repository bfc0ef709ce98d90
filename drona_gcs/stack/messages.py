"""Task ids and the messages drones exchange: frozen dataclasses that validate themselves.

**Task ids** are globally unique and totally ordered without a central
counter: ``(stamp, tick, drone, seq)`` where ``stamp`` and ``tick`` come from
the drone's hybrid logical clock (:class:`HybridClock`), ``drone`` breaks ties
between drones and ``seq`` between tasks of one drone. The original DRONA used
a process-global counter, which only works when every robot runs in one process.
A lower id is a higher priority (the paper's rule).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Final

from drona_gcs.errors import ProtocolViolation
from drona_gcs.motion import Trajectory
from drona_gcs.workspace import Cell

#: The most ids of one stamp: past it a clock moves its stamp on a step instead (only a forged id comes near).
TICK_LIMIT: Final = 2**32


@functools.total_ordering
@dataclass(frozen=True)
class TaskId:
    stamp: int  #: the largest physical step its maker had seen
    drone: str
    seq: int
    #: the incarnation of the drone's agent that made it (a restart counts afresh): see :meth:`newer_than`
    epoch: int = 0
    tick: int = 0  #: orders ids of one stamp: past every id its maker had seen with that stamp

    def __lt__(self, other: object) -> bool:
        if not isinstance(other, TaskId):
            return NotImplemented
        return self._rank() < other._rank()

    def _rank(self) -> tuple[int, int, str, int, int]:
        return self.stamp, self.tick, self.drone, self.seq, self.epoch

    def newer_than(self, other: TaskId) -> bool:
        """Made after ``other`` by the same drone: by a later incarnation, or later in the same one. Stamps
        alone cannot tell: a restarted agent's clock may be behind the stamps its old one had seen."""
        return (self.epoch, self.seq) > (other.epoch, other.seq)

    def __str__(self) -> str:
        tick = f"+{self.tick}" if self.tick else ""
        return f"{self.stamp}{tick}.{self.drone}.{self.seq}"


class HybridClock:
    """A hybrid logical clock (Kulkarni et al., 2014): ``stamp`` is the largest physical step seen, here
    or in a peer's id, so it never runs ahead of the fleet's clocks; ``tick`` counts ids made since it
    last moved, so every id outranks every id seen before it (causal order)."""

    def __init__(self, drone: str, epoch: int = 0) -> None:
        self.drone = drone
        self.epoch = epoch  #: this agent's incarnation: larger at each restart
        self.stamp = 0
        self.tick = 0
        self.seq = 0

    def observe(self, seen: TaskId) -> None:
        self.stamp, self.tick = max((self.stamp, self.tick), (seen.stamp, seen.tick))

    def next_id(self, physical: int) -> TaskId:
        if physical > self.stamp:
            self.stamp, self.tick = physical, 0
        elif self.tick < TICK_LIMIT:
            self.tick += 1
        else:
            self.stamp, self.tick = self.stamp + 1, 0
        self.seq += 1
        return TaskId(self.stamp, self.drone, self.seq, self.epoch, self.tick)


@dataclass(frozen=True)
class Task:
    """A motion task (the paper's atomic task): reach ``goal``.

    ``flight_steps`` is what the battery affords for it; a drone that hovers
    while it coordinates (``hovering_since`` the step it began) pays those
    steps from the same budget. The protocol caps the plan's length with what
    is left when it plans.
    """

    id: TaskId
    goal: Cell
    flight_steps: int | None = None
    hovering_since: int | None = None
    #: a way to the goal whose resting drones are asked to make way (an earlier try found no plan)
    clear: tuple[Cell, ...] = ()
    #: a rest that stops short of a held cell must start by this step (later, it parts after the cell)
    start_by: int | None = None

    def max_length(self, start_step: int) -> int | None:
        if self.flight_steps is None:
            return None
        hovered = start_step - self.hovering_since if self.hovering_since is not None else 0
        return self.flight_steps - hovered


@dataclass(frozen=True)
class ReqForCurrentTraj:
    """Protocol 1: ``sender`` coordinates task ``task_id`` and asks for everyone's trajectory.

    ``trajectory`` is our addition: the sender's current trajectory, which a drone before it in
    line takes as its answer (see :mod:`drona_gcs.stack.protocol`); so are ``asked``, ``holds`` and
    ``clear``: the cells of a way to the sender's goal, which drones resting on them are asked to
    leave (see :mod:`drona_gcs.stack.drone`).
    """

    task_id: TaskId
    sender: str
    trajectory: Trajectory
    #: the peers this round waits for (its members): a drone not named takes nothing from it as an answer
    asked: tuple[str, ...]
    #: cells the sender's vehicle may be in for good, its trajectory aside (its vehicle is lost)
    holds: tuple[Cell, ...] = ()
    clear: tuple[Cell, ...] = ()  #: the way the sender asks resting drones to leave


@dataclass(frozen=True)
class CurrentTraj:
    """Protocol 1: ``sender``'s current trajectory, answering request ``in_reply_to``.

    ``in_reply_to`` is our addition: a reply to an older request (delayed or
    duplicated on the network) is recognised and dropped, never planned with. So are
    ``holds``: cells the sender's vehicle may be in for good, besides its trajectory (lost);
    and ``proposal``: the sender's plan, not decided as it answers, which it may fly instead.
    """

    sender: str
    trajectory: Trajectory
    in_reply_to: TaskId
    holds: tuple[Cell, ...] = ()
    proposal: PlanProposal | None = None

    def __post_init__(self) -> None:
        if not self.trajectory.cells:
            raise ProtocolViolation(f"CurrentTraj from {self.sender!r} carries no cells")


@dataclass(frozen=True)
class PlanProposal:
    """Our addition: ``sender`` planned ``trajectory`` for task ``task_id``, and flies it only once every
    member holds it (:class:`PlanAck`); until its :class:`PlanDecision`, a peer holds it as well as what
    it knew the sender to fly (see :mod:`drona_gcs.stack.protocol`)."""

    sender: str
    task_id: TaskId
    trajectory: Trajectory
    #: the members that must hold it: the plan avoided the others as gone, where it last knew them
    members: tuple[str, ...] = ()
    #: made against what the sender knew, before any round (a task has at most one, and a round's after it)
    direct: bool = False


@dataclass(frozen=True)
class PlanAck:
    """``sender`` holds the proposal of task ``task_id``, and flies ``trajectory`` (its vehicle, lost, may
    be in ``holds`` too): the proposal is flown only if it keeps clear of that, whatever it avoided."""

    sender: str
    task_id: TaskId
    trajectory: Trajectory
    holds: tuple[Cell, ...] = ()
    direct: bool = False  #: of the task's direct proposal (not its round's)


@dataclass(frozen=True)
class PlanRefusal:
    """``sender`` will not hold the proposal of task ``task_id``: it comes too close to what ``sender``
    flies or holds, or enters cells where a drone the proposer holds as gone may be for good, as
    ``sender`` knows it (``gone``: each such drone with those cells, which the proposer holds from now)."""

    sender: str
    task_id: TaskId
    gone: tuple[tuple[str, tuple[Cell, ...]], ...] = ()
    direct: bool = False  #: of the task's direct proposal (not its round's)


@dataclass(frozen=True)
class PlanDecision:
    """``sender`` flies ``trajectory`` from now: its proposal of task ``task_id`` if ``flown``, else the
    trajectory it flew before (the proposal is dropped)."""

    sender: str
    task_id: TaskId
    trajectory: Trajectory
    flown: bool


Message = ReqForCurrentTraj | CurrentTraj | PlanProposal | PlanAck | PlanRefusal | PlanDecision


def task_of(message: Message) -> TaskId:
    """The task id a message names (the request it answers, for a reply): its stamp is a clock reading."""
    return message.in_reply_to if isinstance(message, CurrentTraj) else message.task_id
