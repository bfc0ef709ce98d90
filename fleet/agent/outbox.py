"""What a drone sends at once, in what order: protocol messages first, answers with one trajectory joined.

A new plan answers every drone that waited for it. Its decision goes to every drone anyway, so the
answers with the trajectory it names ride in it (:class:`Decided`): one message for both. Other
answers that share a trajectory (a round with no plan) go as one put on the fleet's ``answers`` key
instead of one per drone (:class:`Answers`), and with drones sharing a session (``--shared-session``)
one delivery per host. Drones that did not wait get it too (one decode each): it is the plan's
announcement, and no other goes out.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from drona_gcs.motion import Trajectory
from drona_gcs.stack.drone import DroneAction
from drona_gcs.stack.mail import GoTo
from drona_gcs.stack.messages import CurrentTraj, PlanDecision, TaskId
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


#: Answers with one trajectory to at least this many drones go as one message to every drone.
COALESCE_FROM = 2

_Said = tuple[Trajectory, tuple[Cell, ...]]  #: what an answer says: a trajectory, and cells held besides


def coalesced(actions: Sequence[DroneAction]) -> list[DroneAction | Answers | Decided]:
    """``actions`` with the answers that share the decision's trajectory joined into it (:class:`Decided`),
    and the others that share a trajectory joined into one :class:`Answers` in the place of the first of
    them (a drone answered twice, to two requests, keeps the second apart)."""
    groups: dict[_Said, dict[str, TaskId]] = {}
    for action in actions:
        if isinstance(action, Send) and isinstance(action.message, CurrentTraj):
            said = action.message.trajectory, action.message.holds
            groups.setdefault(said, {}).setdefault(action.to, action.message.in_reply_to)
    decision = next((a.message for a in actions
                     if isinstance(a, Broadcast) and isinstance(a.message, PlanDecision)), None)
    carried = next((said for said in groups if decision is not None and said[0] == decision.trajectory), None)
    if carried is None and all(len(replies) < COALESCE_FROM for replies in groups.values()):
        return list(actions)  # mostly: one answer, or none
    out: list[DroneAction | Answers | Decided] = []
    joined: set[_Said] = set()
    for action in actions:
        if isinstance(action, Broadcast) and action.message is decision and carried is not None:
            assert decision is not None
            out.append(Decided(decision, groups[carried], carried[1]))
            continue
        if isinstance(action, Send) and isinstance(action.message, CurrentTraj):
            said = action.message.trajectory, action.message.holds
            replies = groups[said]
            if replies[action.to] != action.message.in_reply_to:
                out.append(action)
            elif said == carried:
                continue
            elif len(replies) >= COALESCE_FROM:
                if said not in joined:
                    joined.add(said)
                    out.append(Answers(*said[:1], replies, said[1]))
            else:
                out.append(action)
            continue
        out.append(action)
    return out


def urgency(action: DroneAction) -> int:
    """Protocol messages (and the task's arrival time, which comes before its request), then a new
    plan's bookkeeping, then the rest; a stable sort keeps the order within each."""
    if isinstance(action, (GoTo, Send, Broadcast)):
        return 0
    return 1 if isinstance(action, StartExecuting) else 2
