"""A task's plan proposed at once, made against what the drone knows (no round asks first); a round asks
only if the fleet does not hold it as it is."""

from __future__ import annotations

import random

import pytest

from drona_gcs.motion import Trajectory
from drona_gcs.safety import check_fleet, check_pair
from drona_gcs.stack.messages import (
    CurrentTraj,
    PlanAck,
    PlanDecision,
    PlanProposal,
    PlanRefusal,
    ReqForCurrentTraj,
    Task,
)
from drona_gcs.stack.protocol import (
    Action,
    Broadcast,
    CoordinationProtocol,
    NewTask,
    PeerJoined,
    PeerLeft,
    Send,
    State,
    TaskFailed,
)
from tests.drona_gcs.stack.cluster import ProtocolCluster
from tests.drona_gcs.stack.protocol_helpers import (
    GOAL,
    ID_A,
    ID_B_HIGH,
    ID_B_LOW,
    ID_C_LOW,
    machine,
    request,
    started,
    state_of,
    traj,
)
from tests.drona_gcs.stack.test_protocol_cluster import CLUSTER_GOALS, CLUSTER_STARTS, CROSSING, ORDERS, made_against

ACROSS = traj(0, (3, 1), (3, 0), (3, 0), (3, 0), (3, 0), (3, 0))  #: b on a's way to GOAL, from step 1 on


def broadcasts(actions: list[Action], kind: type) -> list[object]:
    return [a.message for a in actions if isinstance(a, Broadcast) and isinstance(a.message, kind)]


def proposed_at_once() -> tuple[CoordinationProtocol, PlanProposal]:
    """a (peers b and c, both known where they start) is given a task and proposes at once."""
    proto = machine(at_once=True)
    actions = proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    [proposal] = broadcasts(actions, PlanProposal)
    assert isinstance(proposal, PlanProposal)
    return proto, proposal


def test_a_task_is_proposed_at_once_against_what_is_known_and_flown_once_every_member_holds_it() -> None:
    proto = machine(at_once=True)
    actions = proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    assert broadcasts(actions, ReqForCurrentTraj) == []  # nobody asked
    [proposal] = broadcasts(actions, PlanProposal)
    assert isinstance(proposal, PlanProposal) and proposal.direct and proposal.task_id == ID_A
    assert state_of(proto) is State.CONFIRMING
    assert proto.handle(PlanAck("b", ID_A, proto.known["b"], direct=True), 0) == []
    flown = started(proto.handle(PlanAck("c", ID_A, proto.known["c"], direct=True), 0))
    assert flown.trajectory == proposal.trajectory
    assert flown.psi["b"] == proto.known["b"] and flown.psi["c"] == proto.known["c"]


def test_asking_first_a_task_starts_with_a_round() -> None:
    proto = machine(at_once=False)
    actions = proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    assert broadcasts(actions, PlanProposal) == [] and len(broadcasts(actions, ReqForCurrentTraj)) == 1


def test_an_ack_saying_the_member_flies_across_a_direct_plan_has_a_round_ask_with_the_same_task() -> None:
    proto, proposal = proposed_at_once()
    assert proposal.trajectory.at(5) == (3, 0, 0)
    actions = proto.handle(PlanAck("b", ID_A, ACROSS, direct=True), 0)
    assert not any(isinstance(a, TaskFailed) for a in actions)
    [asked] = broadcasts(actions, ReqForCurrentTraj)
    assert isinstance(asked, ReqForCurrentTraj) and asked.task_id == ID_A
    assert state_of(proto) is State.COORDINATING
    # What the direct proposal still gets counts for nothing now: a late refusal drops no round.
    assert proto.handle(PlanRefusal("c", ID_A, direct=True), 0) == []
    proto.handle(CurrentTraj("b", ACROSS, ID_A), 0)
    actions = proto.handle(CurrentTraj("c", proto.known["c"], ID_A), 0)
    [round_proposal] = broadcasts(actions, PlanProposal)
    assert isinstance(round_proposal, PlanProposal) and not round_proposal.direct
    assert round_proposal.trajectory.at(5) != (3, 0, 0)
    # Acks of the direct proposal (the same task) are not acks of the round's.
    assert proto.handle(PlanAck("b", ID_A, ACROSS, direct=True), 0) == []
    assert proto.handle(PlanAck("c", ID_A, proto.known["c"], direct=True), 0) == []
    assert proto.handle(PlanAck("b", ID_A, ACROSS), 0) == []
    assert started(proto.handle(PlanAck("c", ID_A, proto.known["c"]), 0)).trajectory == round_proposal.trajectory


def test_a_refused_direct_plan_is_asked_for_and_a_round_with_no_plan_decides_it() -> None:
    proto, _ = proposed_at_once()
    assert broadcasts(proto.handle(PlanRefusal("c", ID_A, direct=True), 0), ReqForCurrentTraj)
    # b answers that it rests on the goal for good: no plan, and the proposal peers hold is decided.
    proto.handle(CurrentTraj("b", Trajectory.stationary(GOAL, 0), ID_A), 0)
    actions = proto.handle(CurrentTraj("c", proto.known["c"], ID_A), 0)
    [decision] = broadcasts(actions, PlanDecision)
    assert isinstance(decision, PlanDecision) and decision.task_id == ID_A and not decision.flown
    assert [type(a) for a in actions][-1] is TaskFailed and state_of(proto) is State.WAIT_FOR_TASK


def test_a_request_held_while_a_direct_plan_waits_is_the_answer_of_the_round_that_follows() -> None:
    """c's request (behind a in line) came while a's direct plan waited: it waits for a's plan, and what it
    carries is c's answer. Held for the decision instead, each would have waited for the other."""
    proto, _ = proposed_at_once()
    assert proto.handle(request(ID_C_LOW, "c"), 0) == []
    proto.handle(PlanRefusal("b", ID_A, direct=True), 0)
    assert "c" in proto.received and "c" in proto.pending
    actions = proto.handle(CurrentTraj("b", proto.known["b"], ID_A), 0)
    [round_proposal] = broadcasts(actions, PlanProposal)
    assert isinstance(round_proposal, PlanProposal)
    [answer] = [a for a in actions if isinstance(a, Send) and a.to == "c"]
    assert isinstance(answer.message, CurrentTraj) and answer.message.proposal == round_proposal


@pytest.mark.parametrize("theirs, gives_way", [(ID_B_HIGH, True), (ID_B_LOW, False)])
def test_a_direct_plan_gives_way_to_one_ahead_in_line_that_meets_it(theirs: object, gives_way: bool) -> None:
    """Two drones that proposed at once across each other would each refuse the other's: the one behind
    in line acks the other's and asks instead; the one ahead refuses."""
    proto, mine = proposed_at_once()
    crossing = PlanProposal("b", theirs, traj(2, (4, 1), (4, 0), (3, 0), (2, 0)), ("a", "c"), direct=True)  # type: ignore[arg-type]
    assert check_pair(mine.trajectory, crossing.trajectory, 0)  # it meets a's plan (head on), not where a is
    actions = proto.handle(crossing, 0)
    sent = [a.message for a in actions if isinstance(a, Send) and a.to == "b"]
    if gives_way:
        assert [type(m) for m in sent] == [PlanAck] and broadcasts(actions, ReqForCurrentTraj)
        assert state_of(proto) is State.COORDINATING
    else:
        assert [type(m) for m in sent] == [PlanRefusal] and state_of(proto) is State.CONFIRMING


def test_a_peer_holds_a_rounds_proposal_over_its_tasks_direct_one_come_late() -> None:
    peer = machine(me="b", at_once=True)
    round_plan = PlanProposal("a", ID_A, traj(2, (0, 0), (1, 0)), ("b", "c"))
    direct_plan = PlanProposal("a", ID_A, traj(2, (0, 0), (0, 1)), ("b", "c"), direct=True)
    peer.handle(round_plan, 0)
    peer.handle(direct_plan, 0)
    assert peer.proposals["a"] == round_plan


def test_an_answer_older_than_the_plan_its_sender_decided_since_is_not_planned_with() -> None:
    """b answered where it rested, then flew a direct plan (decided before the answer came, messages
    reorder): a's round holds that plan, not the rest."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    flown = traj(3, (4, 4), (4, 3), (4, 2))
    proto.handle(PlanDecision("b", ID_B_LOW, flown, flown=True), 0)
    proto.handle(CurrentTraj("b", Trajectory.stationary((4, 4, 0), 0), ID_A), 0)
    assert proto.received["b"] == flown


@pytest.mark.parametrize("order", ORDERS)
@pytest.mark.parametrize("drones", [("a", "b"), ("a", "c"), ("a", "b", "c")], ids="+".join)
def test_tasks_given_at_once_and_proposed_at_once_all_start_safely(drones: tuple[str, ...], order: str | int) -> None:
    cluster = ProtocolCluster(CROSSING, {d: CLUSTER_STARTS[d] for d in drones}, at_once=True)
    for drone in drones:
        cluster.start_task(drone, CLUSTER_GOALS[drone])
    cluster.deliver_all(random.Random(order) if isinstance(order, int) else order)
    assert sorted(s.drone for s in cluster.started) == sorted(drones), "every drone starts exactly once"
    assert cluster.failed == []
    flown = {s.drone: s.action.trajectory for s in cluster.started}
    assert check_fleet(cluster.workspace, flown, cluster.delta) == []
    for i, one in enumerate(cluster.started):  # of every two plans, one was made (or checked) against the other
        for other in cluster.started[i + 1:]:
            assert made_against(one, other) or made_against(other, one)


def test_a_plan_held_while_mine_waits_is_what_mine_avoided_when_either_is_direct() -> None:
    """Neither waited for the other: mine was checked clear of it when I acked it, which is what it avoided."""
    proto, _ = proposed_at_once()
    theirs = PlanProposal("b", ID_B_LOW, traj(3, (4, 4), (4, 3)), ("a", "c"), direct=True)
    [ack] = proto.handle(theirs, 0)
    assert isinstance(ack, Send) and isinstance(ack.message, PlanAck)
    proto.handle(PlanAck("b", ID_A, proto.known["b"], direct=True), 0)
    flown = started(proto.handle(PlanAck("c", ID_A, proto.known["c"], direct=True), 0))
    assert flown.psi["b?"] == theirs.trajectory


def test_a_peer_holds_a_direct_proposal_no_more_once_its_sender_asks_for_that_task() -> None:
    """Its sender flies a direct proposal only while confirming it: asking instead, it never will. Held on,
    a sender gone right after would have the proposal's cells held for good (the integration test
    test_an_agent_killed_mid_coordination saw its pickup walled off)."""
    peer = machine(me="b", at_once=True)
    peer.handle(PlanProposal("a", ID_A, traj(2, (0, 0), (1, 0)), ("b", "c"), direct=True), 0)
    assert "a" in peer.proposals
    peer.handle(request(ID_A, "a"), 0)
    assert "a" not in peer.proposals


def test_a_direct_proposal_come_after_its_senders_request_for_that_task_is_not_held() -> None:
    """Messages reorder: held then, a sender whose vehicle came down before its round planned would have had
    the proposal's goal held for good (found by the tester, sweep 30714: a charger walled off)."""
    peer = machine(me="b", at_once=True)
    peer.handle(request(ID_A, "a"), 0)
    assert peer.handle(PlanProposal("a", ID_A, traj(2, (0, 0), (1, 0)), ("b", "c"), direct=True), 0) == []
    assert "a" not in peer.proposals


def test_an_answer_from_a_peer_back_since_its_plan_was_decided_is_planned_with() -> None:
    """b decided a plan starting late, then left (its agent crashed) and came back where it stood: its
    answer is news, however early it starts (found by the tester, sweep 30721, config 549460)."""
    proto = machine()
    decided = traj(11, (4, 4), (4, 3), (4, 2))
    proto.handle(PlanDecision("b", ID_B_LOW, decided, flown=True), 0)
    proto.handle(PeerLeft("b", 1), 2)
    proto.handle(PeerJoined("b", (4, 2, 0), decided), 3)  # as it was last heard of
    proto.handle(NewTask(Task(ID_A, GOAL)), 3)
    back = Trajectory.stationary((4, 4, 0), 4)
    proto.handle(CurrentTraj("b", back, ID_A), 4)
    assert proto.received["b"] == back
