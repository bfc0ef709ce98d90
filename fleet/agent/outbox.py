"""What a drone sends at once, in what order: protocol messages first, answers with one trajectory joined.

A plan proposed answers every drone that waited for it. The proposal goes to every drone anyway, so
the answers that carry it ride in it (:class:`Proposed`): one message for both, as for a decision
and the answers with the trajectory it names (:class:`Decided`). Other
answers that share a trajectory (a round with no plan) go as one put on the fleet's ``answers`` key
instead of one per drone (:class:`Answers`), and with drones sharing a session (``--shared-session``)
one delivery per host. Drones that did not wait get it too (one decode each): it is the plan's
announcement, and no other goes out.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TypeVar

from drona_gcs.motion import Trajectory
from drona_gcs.stack.drone import DroneAction
from drona_gcs.stack.mail import GoTo
from drona_gcs.stack.messages import CurrentTraj, PlanDecision, PlanProposal, TaskId
from drona_gcs.stack.protocol import Broadcast, Send, StartExecuting
from drona_gcs.workspace import Cell


@dataclass(frozen=True)
class Answers:
    """Several ``Send(CurrentTraj)`` with one trajectory, sent as one message on the fleet's
    ``answers`` key (each drone answered takes its own)."""

    trajectory: Trajectory
    replies: dict[str, TaskId]  #: drone answered -> the request it answers
    holds: tuple[Cell, ...] = ()


@dataclass(frozen=True)
class Decided:
    """A ``Broadcast(PlanDecision)`` that also answers the drones in ``replies`` (each to its request) with
    the trajectory it names, as the ``Send(CurrentTraj)`` it stands for would."""

    decision: PlanDecision
    replies: dict[str, TaskId]
    holds: tuple[Cell, ...] = ()


@dataclass(frozen=True)
class Proposed:
    """A ``Broadcast(PlanProposal)`` that also answers the drones in ``replies`` (each to its request) with
    ``current`` and the proposal, as the ``Send(CurrentTraj)`` it stands for would."""

    proposal: PlanProposal
    replies: dict[str, TaskId]
    current: Trajectory
    holds: tuple[Cell, ...] = ()


_M = TypeVar("_M", PlanDecision, PlanProposal)

#: Answers with one trajectory to at least this many drones go as one message to every drone.
COALESCE_FROM = 2

#: what an answer says: a trajectory, cells held besides, and the plan proposed with it
_Said = tuple[Trajectory, tuple[Cell, ...], PlanProposal | None]


def coalesced(actions: Sequence[DroneAction]) -> list[DroneAction | Answers | Decided | Proposed]:
    """``actions`` with the answers that carry the proposal joined into it (:class:`Proposed`), those
    that share the decision's trajectory joined into it (:class:`Decided`), and the others that share a
    trajectory joined into one :class:`Answers` in the place of the first of them (a drone answered
    twice, to two requests, keeps the second apart)."""
    groups: dict[_Said, dict[str, TaskId]] = {}
    for action in actions:
        if isinstance(action, Send) and isinstance(action.message, CurrentTraj):
            said = action.message.trajectory, action.message.holds, action.message.proposal
            groups.setdefault(said, {}).setdefault(action.to, action.message.in_reply_to)
    decision = _broadcast(actions, PlanDecision)
    proposal = _broadcast(actions, PlanProposal)
    with_decision = next((said for said in groups if decision is not None and said[2] is None
                          and said[0] == decision.trajectory), None)
    with_proposal = next((said for said in groups if proposal is not None and said[2] == proposal), None)
    carried = {said for said in (with_decision, with_proposal) if said is not None}
    if not carried and all(len(replies) < COALESCE_FROM for replies in groups.values()):
        return list(actions)  # mostly: one answer, or none
    out: list[DroneAction | Answers | Decided | Proposed] = []
    joined: set[_Said] = set()
    for action in actions:
        carrier = _carrier(action, groups, carried)
        if carrier is not None:
            out.append(carrier)
            continue
        if isinstance(action, Send) and isinstance(action.message, CurrentTraj):
            said = action.message.trajectory, action.message.holds, action.message.proposal
            replies = groups[said]
            if replies[action.to] != action.message.in_reply_to:
                out.append(action)
            elif said in carried:
                continue
            elif len(replies) >= COALESCE_FROM and said[2] is None:
                if said not in joined:
                    joined.add(said)
                    out.append(Answers(said[0], replies, said[1]))
            else:
                out.append(action)
            continue
        out.append(action)
    return out


def _broadcast(actions: Sequence[DroneAction], kind: type[_M]) -> _M | None:
    return next((a.message for a in actions if isinstance(a, Broadcast) and isinstance(a.message, kind)), None)


def _carrier(action: DroneAction, groups: dict[_Said, dict[str, TaskId]],
             carried: set[_Said]) -> Decided | Proposed | None:
    """The decision or proposal ``action`` broadcasts, with the answers it carries (if any)."""
    if not isinstance(action, Broadcast):
        return None
    message = action.message
    for said in carried:
        if isinstance(message, PlanDecision) and said[2] is None and said[0] == message.trajectory:
            return Decided(message, groups[said], said[1])
        if isinstance(message, PlanProposal) and said[2] == message:
            return Proposed(message, groups[said], said[0], said[1])
    return None


def urgency(action: DroneAction) -> int:
    """Protocol messages (and the task's arrival time, which comes before its request), then a new
    plan's bookkeeping, then the rest; a stable sort keeps the order within each."""
    if isinstance(action, (GoTo, Send, Broadcast)):
        return 0
    return 1 if isinstance(action, StartExecuting) else 2
