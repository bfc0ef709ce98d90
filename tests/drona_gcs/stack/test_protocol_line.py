"""The line moves on as a drone proposes: the drones that waited for its plan are answered with what it
flies now and its proposal, and plan against both; a drone confirming acks only plans clear of its own.
"""

from __future__ import annotations

import pytest

from drona_gcs.motion import Trajectory
from drona_gcs.stack.messages import (
    CurrentTraj,
    PlanAck,
    PlanDecision,
    PlanProposal,
    PlanRefusal,
    ReqForCurrentTraj,
    Task,
    TaskId,
)
from drona_gcs.stack.protocol import Broadcast, CoordinationProtocol, NewTask, NextStep, Send, State, TaskFailed
from tests.drona_gcs.stack.protocol_helpers import (
    GOAL,
    ID_A,
    ID_B_HIGH,
    ID_B_LOW,
    ID_B_NEXT,
    B,
    confirmed,
    location_of,
    machine,
    started,
    state_of,
    traj,
)

B_PLAN = traj(2, (4, 4), (4, 3), (4, 2))  # b leaves B at step 3 and rests at (4, 2)


def proposing_a() -> tuple[CoordinationProtocol, Trajectory]:
    """a planned row 0 to GOAL (at (2, 0) at step 4) and waits for b's and c's acks."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    proto.handle(CurrentTraj("b", location_of("b"), ID_A), 0)
    [broadcast] = proto.handle(CurrentTraj("c", location_of("c"), ID_A), 0)
    assert isinstance(broadcast, Broadcast) and isinstance(broadcast.message, PlanProposal)
    assert broadcast.message.trajectory.at(4) == (2, 0, 0)
    return proto, broadcast.message.trajectory


def test_a_drone_confirming_acks_a_plan_clear_of_its_own_and_refuses_one_across_it() -> None:
    """Whichever it flies, what it flies now or its proposal, an acked plan keeps clear of it."""
    proto, _ = proposing_a()
    across = PlanProposal("b", ID_B_LOW, traj(4, (2, 0), (2, 1)), ("a", "c"))  # (2, 0) at step 4, as a's plan
    assert proto.handle(across, 0) == [Send("b", PlanRefusal("a", ID_B_LOW))]
    clear = PlanProposal("b", ID_B_NEXT, traj(4, (4, 4), (3, 4)), ("a", "c"))
    assert proto.handle(clear, 0) == [Send("b", PlanAck("a", ID_B_NEXT, location_of("a")))]
    assert state_of(proto) is State.CONFIRMING


def waiting_for_b(goal: tuple[int, int, int]) -> CoordinationProtocol:
    """a coordinates a task to ``goal``, ranking below b's (which b coordinates), c answered: a waits for b."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, goal)), 0)
    assert proto.handle(ReqForCurrentTraj(ID_B_HIGH, "b", location_of("b"), ("a", "c")), 0) == []
    assert proto.handle(CurrentTraj("c", location_of("c"), ID_A), 0) == []
    return proto


def pledge(trajectory: Trajectory = B_PLAN) -> CurrentTraj:
    """b's answer to a, as b proposes: where it is, and its proposal."""
    return CurrentTraj("b", location_of("b"), ID_A, (), PlanProposal("b", ID_B_HIGH, trajectory, ("a", "c")))


def test_a_drone_answered_as_its_predecessor_proposes_plans_against_both_at_once() -> None:
    proto = waiting_for_b(GOAL)
    actions = proto.handle(pledge(), 0)
    assert state_of(proto) is State.CONFIRMING  # planned, before b's plan was decided
    action = started(confirmed(proto, actions))
    assert action.psi["b"] == location_of("b") and action.psi["b?"] == B_PLAN  # b may fly either


@pytest.mark.parametrize("flown", [True, False])
def test_with_no_plan_clear_of_both_a_drone_waits_for_the_decision_as_its_answer(flown: bool) -> None:
    """a's goal is where b is: while b may stay there, no plan reaches it. b's decision says which holds."""
    proto = waiting_for_b(B)
    assert proto.handle(pledge(), 0) == []
    assert state_of(proto) is State.COORDINATING and "b" not in proto.received
    flies = B_PLAN if flown else location_of("b")
    actions = proto.handle(PlanDecision("b", ID_B_HIGH, flies, flown=flown), 1)
    if flown:
        action = started(confirmed(proto, actions))
        assert action.psi["b"] == B_PLAN and action.trajectory.last == B
    else:  # b stays on a's goal: the task fails, and is tried again
        assert [type(a) for a in actions] == [TaskFailed] and state_of(proto) is State.WAIT_FOR_TASK


def test_an_answer_after_its_senders_decision_is_not_taken_for_what_it_flies() -> None:
    """Messages reorder: b's decision came first, and says what b flies; the answer's "where I am" is old."""
    proto = waiting_for_b(GOAL)
    assert proto.handle(PlanDecision("b", ID_B_HIGH, B_PLAN, flown=True), 0) == []
    action = started(confirmed(proto, proto.handle(pledge(), 0)))
    assert action.psi["b"] == B_PLAN and "b?" not in action.psi
    assert proto.known["b"] == B_PLAN


def test_a_decision_not_waited_for_answers_nothing() -> None:
    """Only the decision on the proposal that came with the answer stands for that answer (an older
    one, late, says what b flew before)."""
    proto = waiting_for_b(B)
    assert proto.handle(pledge(), 0) == []
    older = TaskId(ID_B_HIGH.stamp - 1, "b", 0)
    assert proto.handle(PlanDecision("b", older, location_of("b"), flown=True), 0) == []
    assert state_of(proto) is State.COORDINATING and "b" not in proto.received


def test_a_wait_for_a_decision_that_was_lost_ends_with_the_next_answer() -> None:
    """Found in review: b's decision lost, a asked again, and b's answer (no proposal now: its round is
    over) was dropped again for the same proposal, for good. One wait per proposal: the task fails."""
    proto = waiting_for_b(B)
    assert proto.handle(pledge(), 0) == []
    asked = proto.handle(NextStep(), 4)  # the round asks b again
    assert [a.to for a in asked if isinstance(a, Send)] == ["b"]
    actions = proto.handle(CurrentTraj("b", location_of("b"), ID_A), 4)
    assert [type(a) for a in actions] == [TaskFailed] and state_of(proto) is State.WAIT_FOR_TASK


def test_a_new_round_of_the_drone_waited_on_ends_the_wait() -> None:
    """b's decision lost, b tries again (ranking below a now): its request is its answer, and says what
    it flies; the proposal a waited on is over."""
    proto = waiting_for_b(B)
    assert proto.handle(pledge(), 0) == []
    actions = proto.handle(ReqForCurrentTraj(ID_B_NEXT, "b", location_of("b", 2), ("a", "c")), 2)
    assert TaskFailed in [type(a) for a in actions] and state_of(proto) is State.WAIT_FOR_TASK


def test_a_decision_not_to_fly_says_what_its_sender_flies() -> None:
    """Its decision (not flown) came before its answer: what it flies is what the decision says, not
    what I knew of it before."""
    proto = waiting_for_b(GOAL)
    there = Trajectory.stationary((3, 3, 0), 0)  # b is there now (a plan of it I never heard of)
    proto.handle(PlanDecision("b", ID_B_HIGH, there, flown=False), 0)
    action = started(confirmed(proto, proto.handle(pledge(), 0)))
    assert action.psi["b"].cells == ((3, 3, 0),)
