"""Protocol 1's messages between drones (``proto/...``, ``answers/...``), and a plan announced to
everyone (``plan/<drone>``)."""

from __future__ import annotations

from typing import Annotated

import msgspec

from fleet.transport.wire.base import Holds, WireBody, WireTaskId, WireTrajectory


class ReqTraj(WireBody, frozen=True, kw_only=True, tag="req_traj"):
    task_id: WireTaskId
    trajectory: WireTrajectory  #: the requester's, which a drone before it in line takes as its answer
    asked: tuple[str, ...]  #: the peers its round waits for
    holds: Holds = ()  #: cells its lost vehicle may be in, besides the trajectory
    clear: Holds = ()  #: a way to its goal that drones resting on it are asked to leave


class CurTraj(WireBody, frozen=True, kw_only=True, tag="cur_traj"):
    in_reply_to: WireTaskId
    trajectory: WireTrajectory
    holds: Holds = ()


class CurTrajTo(WireBody, frozen=True, kw_only=True, tag="cur_traj_to"):
    """One trajectory answering several drones' requests: ``replies`` maps each drone to its request."""

    replies: Annotated[dict[str, WireTaskId], msgspec.Meta(min_length=1)]
    trajectory: WireTrajectory
    holds: Holds = ()


class Propose(WireBody, frozen=True, kw_only=True, tag="propose"):
    """A plan made, flown once every member holds it (acknowledged with ``ack``). It answers too the
    drones in ``replies`` (each to its request), whose rounds waited for it: with ``current``, what the
    sender flies unless this plan is flown, and the plan itself, which they hold besides."""

    task_id: WireTaskId
    trajectory: WireTrajectory
    members: tuple[str, ...]  #: the drones that must hold it
    replies: dict[str, WireTaskId] = msgspec.field(default_factory=dict)
    current: WireTrajectory | None = None  #: of the answers (there are replies: required)
    holds: Holds = ()  #: of the answers: cells the sender's lost vehicle may be in
    direct: bool = False  #: made before any round of its task (see the protocol's theory of operation)


class Ack(WireBody, frozen=True, kw_only=True, tag="ack"):
    task_id: WireTaskId  #: the proposal held
    trajectory: WireTrajectory  #: what the sender flies
    holds: Holds = ()  #: cells its lost vehicle may be in, besides the trajectory
    direct: bool = False  #: the proposal held is its task's direct one


class Refuse(WireBody, frozen=True, kw_only=True, tag="refuse"):
    """A proposal the sender will not hold; ``gone``: for each drone the proposer held as gone, every cell
    the sender holds it may be in for good."""

    task_id: WireTaskId
    gone: dict[str, Holds] = msgspec.field(default_factory=dict)
    direct: bool = False  #: the proposal refused is its task's direct one


class Decide(WireBody, frozen=True, kw_only=True, tag="decide"):
    """What the proposer flies from now: the proposal (``flown``), or what it flew before. It answers
    too, as ``cur_traj_to`` does, the drones in ``replies`` (each to its request), whose rounds waited
    for it: one message for both, since every drone gets the decision anyway."""

    task_id: WireTaskId
    trajectory: WireTrajectory
    flown: bool
    replies: dict[str, WireTaskId] = msgspec.field(default_factory=dict)
    holds: Holds = ()  #: of the answers: cells the sender's lost vehicle may be in


class PlanAnnounce(WireBody, frozen=True, kw_only=True, tag="plan"):
    """A drone's new plan, to everyone, once made (peers outside the round learn where it goes);
    ``grounded``: its vehicle came down by itself, and stays at the trajectory's end for good;
    ``braked``: it cut the plan it flies short, and holds at the trajectory's end until its next plan;
    ``lost``: its vehicle may be in any of ``holds`` for good: lost, late beyond lambda, or its clock
    off (none: it is back, on time); ``for_now``: late or its clock off, not lost."""

    trajectory: WireTrajectory
    grounded: bool = False
    braked: bool = False
    lost: bool = False
    holds: Holds = ()
    for_now: bool = False
    holds_seq: tuple[int, int] = (0, 0)  #: which of the drone's holds these are: an older one, come late, is dropped
