"""The coordination protocol's confirming state: a plan is flown once every member holds it.
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
    Task,
    TaskId,
)
from drona_gcs.stack.protocol import (
    Broadcast,
    CoordinationProtocol,
    Event,
    NewTask,
    NextStep,
    PeerDown,
    PeerJoined,
    PeerLeft,
    Send,
    State,
    TaskFailed,
    VehicleLost,
)
from tests.drona_gcs.stack.protocol_helpers import (
    GOAL,
    ID_A,
    ID_B_HIGH,
    ID_B_LOW,
    ID_B_NEXT,
    ID_C_LOW,
    A,
    B,
    C,
    confirmed,
    location_of,
    machine,
    request,
    started,
    state_of,
    traj,
)


# ============================================== a plan is flown once every member holds it
def confirming(lead_steps: int = 2) -> tuple[CoordinationProtocol, PlanProposal]:
    """a planned (b and c answered, c waits for a's plan, and is answered as a proposes it: with where a
    is, and the proposal), and waits for b's and c's acks."""
    proto = machine(lead_steps=lead_steps)
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    proto.handle(request(ID_C_LOW, "c"), 0)
    [broadcast, answer] = proto.handle(CurrentTraj("b", location_of("b"), ID_A), 0)
    assert isinstance(broadcast, Broadcast) and isinstance(broadcast.message, PlanProposal)
    assert answer == Send("c", CurrentTraj("a", location_of("a"), ID_C_LOW, (), broadcast.message))
    assert proto.state is State.CONFIRMING and proto.current_trajectory(0) == Trajectory.stationary(A, 0)
    return proto, broadcast.message


def test_a_plan_no_member_held_by_the_boundary_before_its_start_is_dropped() -> None:
    """Found by the tester's partitions: b flew a plan that a, cut off before b announced it, did not
    know, and planned into b's cell. A plan some member may not hold is never flown."""
    proto, _ = confirming()
    assert proto.handle(PlanAck("b", ID_A, location_of("b")), 0) == []  # c's is missing
    assert proto.handle(NextStep(), 0) == []  # the boundary to step 1: still in time for step 2
    actions = proto.handle(NextStep(), 1)
    stay = Trajectory.stationary(A, 1)
    assert actions == [Broadcast(PlanDecision("a", ID_A, stay, flown=False)),
                       TaskFailed(Task(ID_A, GOAL), "not every peer held my plan in time")]
    assert proto.state is State.WAIT_FOR_TASK and proto.trajectory is None
    assert proto.handle(PlanAck("c", ID_A, location_of("c")), 1) == []  # too late


def test_a_request_while_confirming_is_answered_once_decided() -> None:
    proto, proposal = confirming()
    assert proto.handle(request(ID_B_HIGH, "b"), 0) == []  # even a higher priority waits (a lead at most)
    proto.handle(PlanAck("b", ID_A, location_of("b")), 0)
    actions = proto.handle(PlanAck("c", ID_A, location_of("c")), 0)
    assert {a.to for a in actions if isinstance(a, Send)} == {"b"}  # c was answered as a proposed
    assert all(not isinstance(a.message, PlanRefusal) and a.message.trajectory == proposal.trajectory
               for a in actions if isinstance(a, Send))


@pytest.mark.parametrize("news", [PeerLeft("b"), PeerDown("b", (2, 2, 0)), VehicleLost(0, A), PeerJoined("d", C)],
                         ids=lambda e: type(e).__name__)
def test_news_of_the_fleet_while_confirming_drops_the_plan(news: Event) -> None:
    """The plan avoided b's timed answer; gone, b may hold any cell of it for good."""
    proto, _ = confirming()
    actions = proto.handle(news, 0)
    assert [type(a) for a in actions[:1]] == [Broadcast] and any(isinstance(a, TaskFailed) for a in actions)
    assert proto.state is State.WAIT_FOR_TASK and proto.proposed is None


def test_a_peer_holds_a_proposal_until_decided_and_for_good_if_its_sender_leaves_first() -> None:
    proto = machine()
    b_plan = traj(3, (4, 4), (3, 4), (2, 4))
    proposal = PlanProposal("b", ID_B_LOW, b_plan)
    assert proto.handle(proposal, 1) == [Send("b", PlanAck("a", ID_B_LOW, location_of("a", 1)))]
    task = Task(ID_A, GOAL)
    proto.handle(NewTask(task), 1)
    proto.handle(CurrentTraj("c", location_of("c"), ID_A), 1)
    action = started(confirmed(proto, proto.handle(CurrentTraj("b", location_of("b"), ID_A), 1)))
    assert action.psi["b?"] == b_plan and action.psi["b"] == location_of("b")  # either may be flown
    proto.handle(PeerLeft("b"), 2)  # undecided: b may fly it, or stay
    held = {t.last for t in proto.ghost_obstacles().values()}
    assert {B, (3, 4, 0), (2, 4, 0)} <= held


def test_a_decision_ends_the_hold_on_a_proposal() -> None:
    proto = machine()
    b_plan = traj(3, (4, 4), (3, 4), (2, 4))
    proto.handle(PlanProposal("b", ID_B_LOW, b_plan), 1)
    proto.handle(PlanDecision("b", ID_B_LOW, b_plan, flown=True), 2)
    assert proto.proposals == {} and proto.known["b"] == b_plan
    late = PlanProposal("b", ID_B_LOW, b_plan)  # a duplicate, after the decision
    assert proto.handle(late, 2) == [] and proto.proposals == {}
    proto.handle(PlanProposal("b", ID_B_NEXT, traj(9, (2, 4), (1, 4))), 9)
    proto.handle(PlanDecision("b", ID_B_NEXT, b_plan, flown=False), 9)
    assert proto.proposals == {} and proto.known["b"] == b_plan


def test_a_proposal_across_what_i_fly_is_not_acked() -> None:
    """Found by the tester's partitions: a plan made while a was held as gone avoided where a was last
    known; a flies elsewhere now. Its ack would let that plan fly into a: a holds it, and refuses it."""
    proto = machine()
    a_plan = started(confirmed(proto, proto.handle(NewTask(Task(ID_A, GOAL)), 0)
                               + proto.handle(CurrentTraj("b", location_of("b"), ID_A), 0)
                               + proto.handle(CurrentTraj("c", location_of("c"), ID_A), 0))).trajectory
    across = PlanProposal("b", ID_B_NEXT, Trajectory(a_plan.end_step, ((3, 1, 0), GOAL)), ("c",))
    refused = [Send("b", PlanRefusal("a", ID_B_NEXT))]  # b held none gone that a knows of: no cells
    assert proto.handle(across, 1) == refused and proto.proposals["b"] == across  # held all the same
    clear = PlanProposal("b", TaskId(10, "b", 3), Trajectory(a_plan.end_step, (B, (3, 4, 0))), ("a", "c"))
    assert proto.handle(clear, 1) == [Send("b", PlanAck("a", clear.task_id, a_plan))]


def test_a_proposal_across_a_drone_its_sender_held_as_gone_is_not_acked() -> None:
    """Views apart: b planned with c gone (where b last knew it); I know where c flies now, and b's plan
    crosses it. Two majorities overlap in a drone that holds both: it acks neither into the other, and
    names where c may be for good, which b then holds too."""
    proto = machine()
    c_plan = traj(2, (0, 4), (1, 4), (2, 4))
    proto.handle(PlanDecision("c", ID_C_LOW, c_plan, flown=True), 1)
    into_c = PlanProposal("b", ID_B_NEXT, traj(3, (4, 4), (3, 4), (2, 4)), ("a",))
    assert proto.handle(into_c, 1) == [Send("b", PlanRefusal("a", ID_B_NEXT, (("c", c_plan.cells),)))]
    asked_c = PlanProposal("b", TaskId(10, "b", 3), traj(3, (4, 4), (3, 4), (2, 4)), ("a", "c"))
    assert proto.handle(asked_c, 1) == [Send("b", PlanAck("a", asked_c.task_id, location_of("a", 1)))]


def test_a_proposal_far_along_the_fleets_clock_is_checked_from_its_start() -> None:
    """Found over real processes: an agent not yet stepping (its step 0) checked a proposal from step 0 to
    the fleet's step, millions of steps on, and answered nothing for seconds."""
    proto = machine()
    far = 10**9
    proposal = PlanProposal("b", ID_B_LOW, Trajectory(far, (B, (3, 4, 0))), ("a", "c"))
    assert proto.handle(proposal, 0) == [Send("b", PlanAck("a", ID_B_LOW, location_of("a")))]


def test_an_ack_that_says_the_member_holds_my_way_drops_my_plan() -> None:
    """Found in review: a member whose clock is off checked my plan on its own steps, which said nothing,
    and acked. Its ack says what it flies and holds: a plan across that is not flown."""
    proto, proposal = confirming()
    held = tuple(proposal.trajectory.cells[1:3])
    actions = proto.handle(PlanAck("b", ID_A, location_of("b"), held), 0)
    assert [type(a) for a in actions] == [Broadcast, TaskFailed] and proto.state is State.WAIT_FOR_TASK
    assert isinstance(actions[-1], TaskFailed) and actions[-1].reason == "b flies or holds across it"


def test_a_refusal_naming_where_a_gone_drone_may_be_is_held_and_the_next_plan_keeps_clear() -> None:
    """Found in the suite: b, frozen while c died, held more of c's way than a did, and silently refused
    each plan a proposed across it until a's mail was given up. Now b says where it holds c: a drops the
    plan at once, holds those cells too, and plans around them; c back, they are free again."""
    proto = machine()
    proto.handle(PeerLeft("c"), 0)
    actions = proto.handle(NewTask(Task(ID_A, GOAL)), 0) + proto.handle(CurrentTraj("b", location_of("b"), ID_A), 0)
    proposal = next(a.message for a in actions if isinstance(a, Broadcast) and isinstance(a.message, PlanProposal))
    assert (2, 0, 0) in proposal.trajectory.cells and proto.state is State.CONFIRMING
    dropped = proto.handle(PlanRefusal("b", proposal.task_id, (("c", ((2, 0, 0), (2, 1, 0))),)), 1)
    assert state_of(proto) is State.WAIT_FOR_TASK and any(isinstance(a, TaskFailed) for a in dropped)
    assert {"c!0", "c!1"} <= set(proto.ghost_obstacles())
    again = TaskId(9, "a", 2)
    actions = proto.handle(NewTask(Task(again, GOAL)), 2) + proto.handle(CurrentTraj("b", location_of("b"), again), 2)
    retry = next(a.message for a in actions if isinstance(a, Broadcast) and isinstance(a.message, PlanProposal))
    assert not {(2, 0, 0), (2, 1, 0)} & set(retry.trajectory.cells) and retry.trajectory.last == GOAL
    proto.handle(PeerJoined("c", C), 3)
    assert {"c!0", "c!1"} <= set(proto.ghost_obstacles())  # until c says where it is
    proto.heard("c", Trajectory.stationary(C, 3), 0)
    assert not any(name.startswith("c!") for name in proto.ghost_obstacles())
