"""What a drone sends at once, in what order: protocol messages first, answers with one trajectory joined.

A new plan answers every drone that waited for it: when many coordinate at once (a fleet given mail
together), one put on the fleet's ``answers`` key instead of one per drone, and with drones sharing a
session (``--shared-session``) one delivery per host. Drones that did not wait get it too (one decode
each): it is the plan's announcement, and no other goes out.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from drona_gcs.motion import Trajectory
from drona_gcs.stack.drone import DroneAction
from drona_gcs.stack.mail import GoTo
from drona_gcs.stack.messages import CurrentTraj, TaskId
from drona_gcs.stack.protocol import Broadcast, Send, StartExecuting
from drona_gcs.workspace import Cell


@dataclass(frozen=True)
class Answers:
    """Several ``Send(CurrentTraj)`` with one trajectory, sent as one message on the fleet's
    ``answers`` key (each drone answered takes its own)."""

    trajectory: Trajectory
    replies: dict[str, TaskId]  #: drone answered -> the request it answers
    holds: tuple[Cell, ...] = ()


#: Answers with one trajectory to at least this many drones go as one message to every drone.
COALESCE_FROM = 2


def coalesced(actions: Sequence[DroneAction]) -> list[DroneAction | Answers]:
    """``actions`` with the answers that share a trajectory joined into one :class:`Answers`, in
    the place of the first of them (a drone answered twice, to two requests, keeps the second apart)."""
    groups: dict[tuple[Trajectory, tuple[Cell, ...]], dict[str, TaskId]] = {}
    for action in actions:
        if isinstance(action, Send) and isinstance(action.message, CurrentTraj):
            said = action.message.trajectory, action.message.holds
            groups.setdefault(said, {}).setdefault(action.to, action.message.in_reply_to)
    if all(len(replies) < COALESCE_FROM for replies in groups.values()):
        return list(actions)  # mostly: one answer, or none
    out: list[DroneAction | Answers] = []
    joined: set[tuple[Trajectory, tuple[Cell, ...]]] = set()
    for action in actions:
        if isinstance(action, Send) and isinstance(action.message, CurrentTraj):
            said = action.message.trajectory, action.message.holds
            replies = groups[said]
            if len(replies) >= COALESCE_FROM and replies[action.to] == action.message.in_reply_to:
                if said not in joined:
                    joined.add(said)
                    out.append(Answers(*said[:1], replies, said[1]))
                continue
        out.append(action)
    return out


def urgency(action: DroneAction) -> int:
    """Protocol messages (and the task's arrival time, which comes before its request), then a new
    plan's bookkeeping, then the rest; a stable sort keeps the order within each."""
    if isinstance(action, (GoTo, Send, Broadcast)):
        return 0
    return 1 if isinstance(action, StartExecuting) else 2
