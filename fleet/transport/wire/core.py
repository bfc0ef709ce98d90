"""Protocol 1's messages between the core (:mod:`drona_gcs.stack.messages`) and the wire."""

from __future__ import annotations

from collections.abc import Mapping

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
from fleet.transport.wire.base import Holds, WireError, WireTaskId, WireTrajectory
from fleet.transport.wire.envelope import Envelope
from fleet.transport.wire.protocol import Ack, CurTraj, CurTrajTo, Decide, Propose, Refuse, ReqTraj

ProtocolBody = ReqTraj | CurTraj | Propose | Ack | Refuse | Decide


def from_core(message: Message) -> ProtocolBody:
    if isinstance(message, ReqForCurrentTraj):
        return ReqTraj(task_id=WireTaskId.of(message.task_id), trajectory=WireTrajectory.of(message.trajectory),
                       asked=message.asked, holds=message.holds, clear=message.clear)
    if isinstance(message, PlanProposal):
        return proposing(message, {})
    if isinstance(message, PlanAck):
        return Ack(task_id=WireTaskId.of(message.task_id), trajectory=WireTrajectory.of(message.trajectory),
                   holds=message.holds, direct=message.direct)
    if isinstance(message, PlanRefusal):
        return Refuse(task_id=WireTaskId.of(message.task_id), gone=dict(message.gone), direct=message.direct)
    if isinstance(message, PlanDecision):
        return Decide(task_id=WireTaskId.of(message.task_id), trajectory=WireTrajectory.of(message.trajectory),
                      flown=message.flown)
    if message.proposal is not None:  # it rides in the proposal (see proposing)
        return proposing(message.proposal, {message.in_reply_to.drone: message.in_reply_to}, message.trajectory,
                         message.holds)
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


def proposing(proposal: PlanProposal, replies: Mapping[str, TaskId], current: Trajectory | None = None,
              holds: Holds = ()) -> Propose:
    """A ``propose`` that also answers the drones in ``replies`` with ``current`` and the proposal."""
    return Propose(task_id=WireTaskId.of(proposal.task_id), trajectory=WireTrajectory.of(proposal.trajectory),
                   members=proposal.members, replies={drone: WireTaskId.of(task) for drone, task in replies.items()},
                   current=None if current is None else WireTrajectory.of(current), holds=holds,
                   direct=proposal.direct)


def answer_in(envelope: Envelope, me: str) -> CurrentTraj | None:
    """The answer to drone ``me``'s request that a ``cur_traj_to``, ``decide`` or ``propose`` carries, if any."""
    body = envelope.body
    if not isinstance(body, (CurTrajTo, Decide, Propose)):
        return None
    found = body.replies.get(me)
    if found is None:
        return None
    if isinstance(body, Propose):
        return _proposed_answer(envelope.sender, body, found)
    return _answer(envelope.sender, body, found)


def _proposed_answer(sender: str, body: Propose, request: WireTaskId) -> CurrentTraj:
    if body.current is None:
        raise WireError(f"propose from {sender!r} answers requests but says nothing of what it flies now")
    try:
        proposal = PlanProposal(sender, made_by(sender, body), body.trajectory.core(), body.members)
        return CurrentTraj(sender, body.current.core(), request.core(), body.holds, proposal)
    except DronaError as exc:
        raise WireError(f"propose from {sender!r}: {exc}") from exc


def _answer(sender: str, body: CurTraj | CurTrajTo | Decide, request: WireTaskId) -> CurrentTraj:
    try:
        return CurrentTraj(sender, body.trajectory.core(), request.core(), body.holds)
    except DronaError as exc:
        raise WireError(f"{body.kind} from {sender!r}: {exc}") from exc


def made_by(sender: str, body: ReqTraj | Propose | Decide) -> TaskId:
    """The task id of ``sender``'s request, proposal or decision: one of its own tasks. A task id naming
    another drone would stand in that drone's place in the line, and a forged one could jump it."""
    if body.task_id.drone != sender:
        raise WireError(f"{body.kind} from {sender!r} names task {body.task_id.core()} of drone "
                        f"{body.task_id.drone!r}: a drone coordinates its own tasks only")
    return body.task_id.core()


def to_core(envelope: Envelope, me: str) -> Message | None:
    """The protocol message for drone ``me`` in ``envelope`` (the sender is the envelope's); None
    for a ``cur_traj_to`` that answers others only."""
    body, sender = envelope.body, envelope.sender
    if isinstance(body, ReqTraj):
        return ReqForCurrentTraj(made_by(sender, body), sender, body.trajectory.core(), body.asked, body.holds,
                                 body.clear)
    if isinstance(body, Propose):
        return PlanProposal(sender, made_by(sender, body), body.trajectory.core(), body.members, body.direct)
    if isinstance(body, Ack):
        return PlanAck(sender, body.task_id.core(), body.trajectory.core(), body.holds, body.direct)
    if isinstance(body, Refuse):
        return PlanRefusal(sender, body.task_id.core(), tuple(sorted(body.gone.items())), body.direct)
    if isinstance(body, Decide):
        return PlanDecision(sender, made_by(sender, body), body.trajectory.core(), body.flown)
    if isinstance(body, CurTraj):
        return _answer(sender, body, body.in_reply_to)
    if isinstance(body, CurTrajTo):
        return answer_in(envelope, me)
    raise WireError(f"{body.kind} is not a protocol message")
