"""The coordination protocol (paper Protocol 1) as a sans-I/O state machine.

Unit tests feed one drone's machine events by hand on an open 5 x 5 x 1 grid
(the unit tests use delta 0, so the shortest plan is the Manhattan path);
the cluster tests join two or three machines through
:class:`tests.drona_gcs.stack.cluster.ProtocolCluster` and check, under several message
orders, that everyone starts, plans against what its peers had committed,
and that the flown trajectories are safe by the independent checker.
"""

from __future__ import annotations

import itertools
import random
from collections.abc import Mapping

import pytest

from drona_gcs.errors import ProblemError, ProtocolViolation
from drona_gcs.motion import Trajectory
from drona_gcs.planner import SafePlanner
from drona_gcs.safety import check_fleet, check_trajectory
from drona_gcs.stack.messages import (
    CurrentTraj,
    HybridClock,
    PlanAck,
    PlanDecision,
    PlanProposal,
    PlanRefusal,
    ReqForCurrentTraj,
    Task,
    TaskId,
)
from drona_gcs.stack.protocol import (
    ASK_AGAIN_STEPS,
    TRANSITIONS,
    Action,
    Braked,
    Broadcast,
    ClockBound,
    CoordinationProtocol,
    Event,
    Grounded,
    Holding,
    NewTask,
    NextStep,
    PeerAnnounced,
    PeerBraked,
    PeerDown,
    PeerJoined,
    PeerLeft,
    PeerLost,
    PlanCompleted,
    Present,
    Released,
    Relocated,
    Reroute,
    RerouteFailed,
    Send,
    StartExecuting,
    State,
    TaskFailed,
    Threatened,
    VehicleDown,
    VehicleLost,
)
from drona_gcs.workspace import Cell, Workspace
from tests.drona_gcs.stack.cluster import ProtocolCluster

OPEN = Workspace.build(size=(5, 5, 1))
A, B, C = (0, 0, 0), (4, 4, 0), (0, 4, 0)
STARTS = {"a": A, "b": B, "c": C}
GOAL = (4, 0, 0)  # 4 steps from A, free of every start

# the ids a, b and c use; a lower id is a higher priority
ID_A, ID_B_HIGH, ID_B_LOW, ID_C_LOW = TaskId(5, "a", 1), TaskId(3, "b", 1), TaskId(7, "b", 1), TaskId(8, "c", 1)


def traj(start_step: int, *cells: tuple[int, int]) -> Trajectory:
    return Trajectory(start_step, tuple((x, y, 0) for x, y in cells))


def manhattan(a: Cell, b: Cell) -> int:
    return sum(abs(p - q) for p, q in zip(a, b, strict=True))


def machine(peers: Mapping[str, Cell] | None = None, me: str = "a", lead_steps: int = 2,
            workspace: Workspace = OPEN) -> CoordinationProtocol:
    """Drone ``me`` with ``peers`` (default a, b and c); the peer map includes ``me``."""
    peers = dict(STARTS if peers is None else peers)
    return CoordinationProtocol(me, peers[me], peers, SafePlanner(workspace, 0).plan, lead_steps)


def started(actions: list[Action]) -> StartExecuting:
    found = [a for a in actions if isinstance(a, StartExecuting)]
    assert len(found) == 1, actions
    return found[0]


def state_of(proto: CoordinationProtocol) -> State:
    """The state now: read anew after an event (mypy keeps the state an earlier check found)."""
    return proto.state


def confirmed(proto: CoordinationProtocol, actions: list[Action]) -> list[Action]:
    """``actions``, then what each member's ack of the plan they propose brings: the fleet holds it."""
    out = list(actions)
    for action in actions:
        if isinstance(action, Broadcast) and isinstance(action.message, PlanProposal):
            for member in sorted(proto.members):
                flies = proto.received.get(member, proto.known[member])
                out += proto.handle(PlanAck(member, action.message.task_id, flies), 0)
    return out


def location_of(drone: str, now: int = 0) -> Trajectory:
    return Trajectory.stationary(STARTS[drone], now)


def others(sender: str) -> tuple[str, ...]:
    """Whom ``sender``'s round waits for: every other drone of STARTS."""
    return tuple(d for d in sorted(STARTS) if d != sender)


def request(task_id: TaskId, sender: str, now: int = 0) -> ReqForCurrentTraj:
    """``sender``'s request, carrying where it rests (its location since ``now``)."""
    return ReqForCurrentTraj(task_id, sender, location_of(sender, now), others(sender))


# =========================================================== the state table
EVENT_TYPES: tuple[type, ...] = (NewTask, PlanCompleted, PeerLeft, PeerJoined, ReqForCurrentTraj, CurrentTraj,
                                 VehicleLost, Relocated, Reroute, VehicleDown, PeerDown, PeerBraked, PeerAnnounced,
                                 Released, NextStep, PlanProposal, PlanAck, PlanRefusal, PlanDecision, ClockBound,
                                 PeerLost)
#: What Protocol 1 takes in each state (paper section 3.1); the rest is a protocol violation. A vehicle
#: found again is not placed while a round is under way (its request carried where it was). Only a
#: drone flying a plan plans its rest anew (Reroute), and that round ends when the plan does.
REJECTED = {(State.COORDINATING, NewTask), (State.EXECUTING, NewTask), (State.REROUTING, NewTask),
            (State.WAIT_FOR_TASK, PlanCompleted), (State.COORDINATING, PlanCompleted),
            (State.COORDINATING, Relocated), (State.REROUTING, Relocated),
            (State.WAIT_FOR_TASK, Reroute), (State.COORDINATING, Reroute), (State.REROUTING, Reroute),
            (State.CONFIRMING, NewTask), (State.CONFIRMING, Relocated), (State.CONFIRMING, Reroute)}


def in_state(state: State) -> CoordinationProtocol:
    """Drone a (peer b) in ``state``, its task ``ID_A`` when it has one."""
    proto = machine({"a": A, "b": B})
    if state is not State.WAIT_FOR_TASK:
        proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    if state is State.CONFIRMING:
        proto.handle(CurrentTraj("b", location_of("b"), ID_A), 0)
    if state in (State.EXECUTING, State.REROUTING):
        started(confirmed(proto, proto.handle(CurrentTraj("b", location_of("b"), ID_A), 0)))
    if state is State.REROUTING:
        proto.handle(Reroute(Task(TaskId(6, "a", 2), GOAL)), 0)
    assert proto.state is state
    return proto


def sample(event_type: type) -> Event:
    samples: dict[type, Event] = {
        NewTask: NewTask(Task(TaskId(9, "a", 2), (2, 2, 0))),
        PlanCompleted: PlanCompleted(),
        PeerLeft: PeerLeft("b"),
        PeerJoined: PeerJoined("c", C),
        ReqForCurrentTraj: request(ID_B_LOW, "b"),
        CurrentTraj: CurrentTraj("b", location_of("b"), ID_A),
        VehicleLost: VehicleLost(1, A),
        Relocated: Relocated((1, 0, 0)),
        Reroute: Reroute(Task(TaskId(9, "a", 2), GOAL)),
        VehicleDown: VehicleDown((1, 0, 0)),
        PeerDown: PeerDown("b", (3, 3, 0)),
        NextStep: NextStep(),
        PeerBraked: PeerBraked("b", Trajectory(0, (B, B))),
        PeerAnnounced: PeerAnnounced("b", Trajectory(0, (B, B))),
        Released: Released("b"),  # in_state's peer, once it left (see test_every_state_event_pair)
        PlanProposal: PlanProposal("b", ID_B_LOW, Trajectory(3, (B, B))),
        PlanAck: PlanAck("b", ID_A, location_of("b")),
        PlanRefusal: PlanRefusal("b", ID_A, (("c", ((3, 3, 0),)),)),
        PlanDecision: PlanDecision("b", ID_B_LOW, Trajectory(3, (B, B)), flown=True),
        ClockBound: ClockBound(mine_off=False, outliers=frozenset({"b"})),
        PeerLost: PeerLost("b", ((3, 3, 0),)),
    }
    return samples[event_type]


def test_the_transition_table_is_the_papers() -> None:
    table = {(state, event) for state, row in TRANSITIONS.items() for event in row}
    everything = set(itertools.product(State, EVENT_TYPES))
    assert table == everything - REJECTED


@pytest.mark.parametrize("event_type", EVENT_TYPES, ids=lambda t: t.__name__)
@pytest.mark.parametrize("state", list(State), ids=lambda s: s.name)
def test_every_state_event_pair(state: State, event_type: type) -> None:
    proto = in_state(state)
    event = sample(event_type)
    if event_type is Released:
        proto.handle(PeerLeft("b"), 1)
    if (state, event_type) in REJECTED:
        with pytest.raises(ProtocolViolation) as info:
            proto.handle(event, 1)
        assert state.value in str(info.value)
        assert event_type.__name__ in str(info.value)
        assert proto.state is state  # a refused event changes nothing
    else:
        assert isinstance(proto.handle(event, 1), list)


# ====================================================== answering requests
def test_an_idle_drone_answers_with_its_location() -> None:
    proto = machine()
    actions = proto.handle(request(ID_B_LOW, "b"), 3)
    assert actions == [Send("b", CurrentTraj("a", Trajectory.stationary(A, 3), ID_B_LOW))]
    assert proto.state is State.WAIT_FOR_TASK


def test_a_drone_ignores_its_own_broadcast_request() -> None:
    proto = machine()
    assert proto.handle(request(ID_A, "a"), 0) == []
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    assert proto.handle(request(ID_A, "a"), 0) == []


def test_an_executing_drone_answers_with_its_trajectory_then_idle_with_the_finished_plan() -> None:
    proto = machine({"a": A})
    plan = started(confirmed(proto, proto.handle(NewTask(Task(ID_A, GOAL)), 0))).trajectory
    assert proto.state is State.EXECUTING
    # b, unknown so far, is alive: told what a flies, then answered
    assert proto.handle(request(ID_B_LOW, "b"), 1) == [Present("b", plan, False),
                                                       Send("b", CurrentTraj("a", plan, ID_B_LOW))]
    proto.handle(PlanCompleted(), plan.end_step)
    assert (proto.state, proto.location) == (State.WAIT_FOR_TASK, GOAL)
    # idle after a plan: the plan itself, which ends at the location and forever stays there
    told, reply = proto.handle(request(ID_C_LOW, "c"), 20)
    assert isinstance(told, Present) and isinstance(reply, Send) and isinstance(reply.message, CurrentTraj)
    assert reply.message.trajectory.at(20) == GOAL and reply.message.in_reply_to == ID_C_LOW


# ================================================================ new task
def test_new_task_broadcasts_a_request_with_its_id_and_where_it_is() -> None:
    proto = machine()
    task = Task(ID_A, GOAL)
    assert proto.handle(NewTask(task), 3) == [Broadcast(request(ID_A, "a", 3))]
    assert (proto.state, proto.task) == (State.COORDINATING, task)
    proto.handle(CurrentTraj("b", location_of("b"), ID_A), 3)
    plan = started(confirmed(proto, proto.handle(CurrentTraj("c", location_of("c"), ID_A), 3))).trajectory
    proto.handle(PlanCompleted(), plan.end_step)
    # idle after a plan, where it is is that plan (see current_trajectory)
    later = TaskId(20, "a", 2)
    assert proto.handle(NewTask(Task(later, A)), 30) == [Broadcast(ReqForCurrentTraj(later, "a", plan, others("a")))]


@pytest.mark.parametrize(("now", "lead"), [(0, 1), (5, 2), (7, 3)])
def test_with_no_peers_it_plans_at_once_lead_steps_ahead(now: int, lead: int) -> None:
    proto = machine({"a": A}, lead_steps=lead)
    task = Task(ID_A, GOAL)
    actions = proto.handle(NewTask(task), now)
    assert actions[0] == Broadcast(ReqForCurrentTraj(ID_A, "a", location_of("a", now), ()))
    action = started(actions)
    plan = action.trajectory
    assert action.task == task and action.psi == {}
    assert plan.start_step == now + lead
    assert (plan.first, plan.last) == (A, GOAL)
    assert len(plan.cells) - 1 == manhattan(A, GOAL)  # the open grid's shortest path
    assert proto.state is State.EXECUTING and proto.trajectory == plan


def test_it_plans_once_every_peer_answered_against_their_answers() -> None:
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    # b is about to cross a's shortest way along y = 0
    crossing = traj(1, (1, 2), (1, 1), (1, 0), (1, 1), (1, 2))
    assert proto.handle(CurrentTraj("b", crossing, ID_A), 0) == []
    action = started(confirmed(proto, proto.handle(CurrentTraj("c", location_of("c"), ID_A), 0)))
    assert action.psi == {"b": crossing, "c": location_of("c")}
    assert check_trajectory(OPEN, action.trajectory, action.psi, 0, goal=GOAL) == []


# ===================================================== requests while coordinating
def test_a_higher_priority_request_drops_its_old_reply_and_is_asked_again() -> None:
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    assert proto.handle(CurrentTraj("b", location_of("b"), ID_A), 0) == []  # b was idle
    # b got a task of higher priority (a lower id): it plans first, so its answer is stale. My
    # request again is my answer: b holds it until it has planned, and takes my location from it.
    actions = proto.handle(request(ID_B_HIGH, "b"), 1)
    assert actions == [Send("b", request(ID_A, "a", 1))]
    assert "b" not in proto.received and "b" not in proto.pending
    # c answering no longer completes the round: b's answer was dropped
    assert proto.handle(CurrentTraj("c", location_of("c"), ID_A), 1) == []
    assert proto.state is State.COORDINATING
    b_plan = traj(2, (4, 4), (4, 3), (4, 2), (3, 2))
    action = started(confirmed(proto, proto.handle(CurrentTraj("b", b_plan, ID_A), 2)))
    assert action.psi["b"] == b_plan


def test_a_higher_priority_that_has_not_answered_is_neither_answered_nor_asked_again() -> None:
    """Two drones given tasks at once: b, ranked first, holds my request until it has planned, and
    takes my location from it. Answering or asking it again would only cost a message (one per
    pair of drones coordinating together)."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    assert proto.handle(request(ID_B_HIGH, "b"), 0) == []
    assert proto.handle(CurrentTraj("c", location_of("c"), ID_A), 0) == []  # still waiting for b
    b_plan = traj(2, (4, 4), (4, 3), (4, 2), (3, 2))
    action = started(confirmed(proto, proto.handle(CurrentTraj("b", b_plan, ID_A), 1)))
    assert action.psi["b"] == b_plan


def test_a_requester_that_is_no_member_is_alive_and_a_member_again() -> None:
    """c was gone when my request went out and came back (or was seen gone while it lived on): its
    request proves it alive. It is a member again and gets my request, not an answer: answered at
    once, it planned with my location while I planned without it (found by the tester's crash and
    restart of an agent)."""
    proto = machine()
    proto.handle(PeerLeft("c"), 0)
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    first, second = TaskId(2, "c", 1), TaskId(3, "c", 2)
    told = Present("c", Trajectory.stationary(A, 1), False)
    assert proto.handle(request(first, "c"), 1) == [told, Send("c", request(ID_A, "a", 1))]
    assert "c" in proto.members and "c" in proto.ghosts  # held where it may be until it says where it is
    assert proto.handle(PeerJoined("c", C), 1) == [told]  # its return, noticed late: told again
    assert proto.handle(request(second, "c"), 1) == []
    assert proto.state is State.COORDINATING  # waiting for b, and for c's plan
    proto.handle(PeerLeft("b"), 1)
    assert proto.handle(request(ID_B_HIGH, "b"), 1) == [Present("b", Trajectory.stationary(A, 1), False),
                                                        Send("b", request(ID_A, "a", 1))]
    assert proto.state is State.COORDINATING and proto.members == {"b", "c"}


def test_a_lower_priority_request_is_its_answer_and_waits_for_my_new_trajectory() -> None:
    proto = machine({"a": A, "b": B, "c": C})
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    c_way = traj(0, (0, 4), (1, 4))  # c's last plan, which it flew and rests at the end of
    assert proto.handle(request(ID_B_LOW, "b"), 0) == []
    assert proto.pending == {"b": ID_B_LOW} and proto.received == {"b": location_of("b")}
    proposal = proto.handle(ReqForCurrentTraj(ID_C_LOW, "c", c_way, others("c")), 1)
    [broadcast] = proposal
    assert isinstance(broadcast, Broadcast) and isinstance(broadcast.message, PlanProposal)
    plan = broadcast.message.trajectory  # flown once b and c hold it
    assert proto.state is State.CONFIRMING and proto.handle(PlanAck("b", ID_A, location_of("b")), 1) == []
    actions = proto.handle(PlanAck("c", ID_A, c_way), 1)
    assert started(actions).psi == {"b": location_of("b"), "c": c_way} and started(actions).trajectory == plan
    # it starts executing, tells every peer, then unblocks the waiting peers
    assert actions[:2] == [started(actions), Broadcast(PlanDecision("a", ID_A, plan, flown=True))]
    assert set(actions[2:]) == {Send("b", CurrentTraj("a", plan, ID_B_LOW)),
                                Send("c", CurrentTraj("a", plan, ID_C_LOW))}
    assert proto.pending == {}


def test_a_lower_priority_request_from_a_departed_drone_makes_it_a_member_and_is_its_answer() -> None:
    """Its request proves it alive: a member again, asked, and its request is its answer."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    proto.handle(PeerLeft("c"), 0)
    assert proto.handle(request(ID_C_LOW, "c"), 0) == [Present("c", Trajectory.stationary(A, 0), False),
                                                       Send("c", request(ID_A, "a", 0))]
    assert proto.pending == {"c": ID_C_LOW} and "c" in proto.members
    assert proto.received["c"] == request(ID_C_LOW, "c").trajectory


# ============================================ late requests of rounds that are over
ID_B_NEXT = TaskId(9, "b", 2)  # b's next task, after ID_B_HIGH or ID_B_LOW: a drone's ids only grow
B_PLAN = traj(1, (4, 4), (4, 3), (4, 2))  # what b flew since its first request, and rests at the end of


def test_a_late_request_of_a_round_that_is_over_is_not_taken_for_a_higher_priority() -> None:
    """The deadlock of the issue tracker: b's request from its round that is over (ranking above mine)
    came after its request for the next one (ranking below). Taken as current, I dropped b's answer and
    asked it again, while b took my request as my answer: both waited for good."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 2)
    assert proto.handle(ReqForCurrentTraj(ID_B_NEXT, "b", B_PLAN, others("b")), 2) == []  # b waits for my plan
    assert proto.handle(request(ID_B_HIGH, "b"), 2) == []  # late: neither asked again nor answered
    assert proto.pending == {"b": ID_B_NEXT} and proto.received == {"b": B_PLAN}
    actions = confirmed(proto, proto.handle(CurrentTraj("c", location_of("c", 2), ID_A), 2))
    action = started(actions)
    assert action.psi["b"] == B_PLAN
    assert Send("b", CurrentTraj("a", action.trajectory, ID_B_NEXT)) in actions


def test_a_late_request_of_a_round_that_is_over_replaces_neither_the_answer_nor_the_id_to_answer() -> None:
    """Ranking below mine too, it would put where b was before its last plan in Psi, and have my plan
    answer a request b no longer waits on (b ignores that answer and waits for good)."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 2)
    proto.handle(ReqForCurrentTraj(ID_B_NEXT, "b", B_PLAN, others("b")), 2)
    assert proto.handle(request(ID_B_LOW, "b"), 2) == []  # carrying b at B, before it flew B_PLAN
    assert proto.pending == {"b": ID_B_NEXT} and proto.received == {"b": B_PLAN}
    actions = confirmed(proto, proto.handle(CurrentTraj("c", location_of("c", 2), ID_A), 2))
    action = started(actions)
    assert action.psi["b"] == B_PLAN
    assert [a.message for a in actions if isinstance(a, Send) and a.to == "b"] == [
        CurrentTraj("a", action.trajectory, ID_B_NEXT)]


def test_the_newest_request_is_remembered_across_states_and_rounds() -> None:
    """Idle, I answered b's newest request; its late older one gets no answer (b would ignore it), and
    coordinating later it is not taken for a higher priority's after b answered me (nor asked again)."""
    proto = machine()
    assert len(proto.handle(ReqForCurrentTraj(ID_B_NEXT, "b", B_PLAN, others("b")), 1)) == 1
    assert proto.handle(request(ID_B_LOW, "b"), 1) == []
    mine = TaskId(10, "a", 1)  # my clock saw b's stamp: b's newest task ranks above mine
    proto.handle(NewTask(Task(mine, GOAL)), 2)
    assert proto.handle(CurrentTraj("b", B_PLAN, mine), 2) == []
    assert proto.handle(request(ID_B_HIGH, "b"), 2) == []
    action = started(confirmed(proto, proto.handle(CurrentTraj("c", location_of("c", 2), mine), 2)))
    assert action.psi["b"] == B_PLAN
    assert proto.handle(request(ID_B_LOW, "b"), 3) == []  # executing: still late


def test_a_drone_that_rejoins_has_its_ids_count_afresh() -> None:
    """It may have restarted, and its hybrid clock with it: its requests rank by its new ids."""
    proto = machine()
    proto.handle(ReqForCurrentTraj(ID_B_NEXT, "b", B_PLAN, others("b")), 1)
    proto.handle(PeerLeft("b"), 2)
    proto.handle(PeerJoined("b", (4, 2, 0)), 3)
    restarted = TaskId(4, "b", 1)
    assert proto.handle(request(restarted, "b"), 4) == [
        Send("b", CurrentTraj("a", Trajectory.stationary(A, 4), restarted))]


def test_a_restarted_drones_request_is_current_before_its_join_is_seen() -> None:
    """Found by the systematic tester with a crash: the new agent's first request came before its
    join, with a lower stamp than its old agent's last one (its clock counts afresh). Dropped as late,
    the new agent waited for my answer for good. Its epoch says it is newer."""
    proto = machine()
    proto.handle(ReqForCurrentTraj(ID_B_NEXT, "b", B_PLAN, others("b")), 1)
    proto.handle(PeerLeft("b"), 2)
    restarted = TaskId(4, "b", 1, epoch=1)
    actions = proto.handle(request(restarted, "b"), 4)
    assert Send("b", CurrentTraj("a", Trajectory.stationary(A, 4), restarted)) in actions
    assert proto.handle(request(ID_B_LOW, "b"), 5) == []  # its old agent's: late


def test_a_request_that_does_not_wait_for_me_is_not_my_answer() -> None:
    """Found by the systematic tester with a crash and restart: b saw me leave and plans without me,
    so what its request carries may change before I plan. Taken as its answer, I planned with b's
    old location while b flew a new plan. I ask b instead (it admits me and answers)."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    without_me = ReqForCurrentTraj(ID_B_LOW, "b", location_of("b"), ("c",))
    assert proto.handle(without_me, 0) == [Send("b", request(ID_A, "a", 0))]
    assert "b" not in proto.received and proto.pending == {}
    proto.handle(CurrentTraj("c", location_of("c"), ID_A), 0)
    assert proto.state is State.COORDINATING  # still waits for b's own answer
    b_plan = traj(1, (4, 4), (4, 3))
    assert started(confirmed(proto, proto.handle(CurrentTraj("b", b_plan, ID_A), 1))).psi["b"] == b_plan


# ================================================= stale, duplicate and foreign replies
def test_a_reply_to_an_older_request_is_ignored() -> None:
    proto = machine({"a": A, "b": B})
    old = TaskId(1, "a", 0)
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    stale = traj(0, (4, 4), (4, 3), (4, 2), (4, 1), (4, 0))  # an old plan of b, ending on a's goal
    assert proto.handle(CurrentTraj("b", stale, old), 0) == []
    assert proto.state is State.COORDINATING and proto.received == {}
    action = started(confirmed(proto, proto.handle(CurrentTraj("b", location_of("b"), ID_A), 0)))
    assert action.psi == {"b": location_of("b")}


def test_a_reply_from_a_stranger_is_ignored() -> None:
    proto = machine({"a": A, "b": B})
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    assert proto.handle(CurrentTraj("z", Trajectory.stationary((2, 2, 0), 0), ID_A), 0) == []
    assert proto.state is State.COORDINATING


def test_a_duplicated_reply_is_harmless() -> None:
    reply_b = CurrentTraj("b", traj(1, (1, 2), (1, 1), (1, 0), (1, 1)), ID_A)
    reply_c = CurrentTraj("c", location_of("c"), ID_A)
    once, twice = machine(), machine()
    for proto in (once, twice):
        proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    once.handle(reply_b, 0)
    assert twice.handle(reply_b, 0) == [] and twice.handle(reply_b, 0) == []
    assert started(confirmed(twice, twice.handle(reply_c, 0))) == started(confirmed(once, once.handle(reply_c, 0)))
    assert twice.handle(reply_c, 0) == []  # late duplicate while executing
    assert twice.state is State.EXECUTING


# ========================================================== membership changes
def test_a_peer_leaving_is_no_longer_waited_for_but_its_whole_plan_stays_an_obstacle() -> None:
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    b_plan = traj(1, (4, 4), (4, 3), (4, 2), (4, 1))  # b answered, then lost its link
    proto.handle(CurrentTraj("b", b_plan, ID_A), 0)
    assert proto.handle(PeerLeft("b"), 1) == []  # still waiting for c
    action = started(confirmed(proto, proto.handle(CurrentTraj("c", location_of("c"), ID_A), 1)))
    # b may have stopped anywhere along its plan: each of its cells is held for good.
    held = {name: Trajectory.stationary(cell, 1) for name, cell in
            (("b#0", (4, 4, 0)), ("b#1", (4, 3, 0)), ("b#2", (4, 2, 0)), ("b", (4, 1, 0)))}
    assert action.psi == {**held, "c": location_of("c")}
    assert not set(action.trajectory.cells) & set(b_plan.cells)
    assert action.trajectory.last == GOAL
    assert check_trajectory(OPEN, action.trajectory, action.psi, 0) == []


def test_a_peer_leaving_long_after_its_plan_holds_only_where_it_ended() -> None:
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    b_plan = traj(1, (4, 4), (4, 3), (4, 2), (4, 1))  # done by step 4
    proto.handle(CurrentTraj("b", b_plan, ID_A), 0)
    assert proto.handle(PeerLeft("b"), 30) == []
    action = started(confirmed(proto, proto.handle(CurrentTraj("c", location_of("c"), ID_A), 30)))
    assert action.psi["b"].cells == ((4, 1, 0),)  # resting there, for good
    assert not any(name.startswith("b#") for name in action.psi)  # the cells it flew through are free again


def test_a_plan_heard_outside_a_round_is_where_a_departed_peer_may_have_stopped() -> None:
    proto = machine()
    b_plan = traj(10, (4, 4), (4, 3), (4, 2), (4, 1))
    proto.handle(PeerLeft("c"), 0)
    proto.heard("b", b_plan)  # b announced it while this drone was idle
    proto.heard("b", traj(2, (0, 0)))  # an older announcement, late: ignored
    proto.handle(PeerLeft("b", silent_since=11), 20)  # noticed at step 20, a lease after it went quiet
    proto.handle(NewTask(Task(ID_A, GOAL)), 20)
    held = {t.cells[0] for name, t in proto.ghost_obstacles().items() if name.startswith("b")}
    assert held == {(4, 4, 0), (4, 3, 0), (4, 2, 0), (4, 1, 0)}  # from step 11 - lead on: all of it


def test_a_drone_resting_where_a_departed_peer_flew_through_can_still_leave() -> None:
    """Seen in a fleet test: b flew through (2, 0); a came to rest there after it; b died and was
    noticed a lease later, so its whole plan was held for good, a's own cell included: a found
    no plan ever again. Had b stopped there, they would have met: a's cell is spared, the others not."""
    peers = {"a": (2, 0, 0), "b": (3, 1, 0), "c": C}
    proto = machine(peers)
    b_plan = traj(1, (3, 1), (2, 1), (2, 0), (1, 0), (1, 1))  # through a's cell at step 3, done by step 5
    proto.heard("b", b_plan)
    proto.handle(PeerLeft("b", silent_since=0), 6)  # b's rest of plan: all of it
    proto.handle(NewTask(Task(ID_A, GOAL)), 6)
    action = started(confirmed(proto, proto.handle(CurrentTraj("c", location_of("c", 6), ID_A), 6)))
    held = {t.cells[0] for name, t in action.psi.items() if name.startswith("b")}
    assert held == {(3, 1, 0), (2, 1, 0), (1, 0, 0), (1, 1, 0)}  # all of b's plan but a's own cell
    assert action.trajectory.cells[0] == (2, 0, 0) and action.trajectory.last == GOAL
    assert not set(action.trajectory.cells[1:]) & held
    assert check_trajectory(OPEN, action.trajectory, action.psi, action.trajectory.start_step) == []


def test_the_last_awaited_peer_leaving_lets_it_plan_with_its_last_known_trajectory() -> None:
    proto = machine({**STARTS, "d": (2, 4, 0)})
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    proto.handle(CurrentTraj("d", Trajectory.stationary((2, 4, 0), 0), ID_A), 0)
    proto.handle(request(ID_C_LOW, "c"), 0)  # c waits for a's plan, its request its answer ...
    proto.handle(PeerLeft("c"), 1)  # ... then leaves
    actions = confirmed(proto, proto.handle(PeerLeft("b"), 1))  # b leaves before answering
    action = started(actions)
    # where they were last known, for good
    assert {p: action.psi[p] for p in "bc"} == {"b": Trajectory.stationary(B, 0), "c": Trajectory.stationary(C, 0)}
    assert not any(isinstance(a, Send) for a in actions)  # a departed drone is not answered
    assert proto.handle(PeerLeft("c"), 1) == []  # leaving twice changes nothing


@pytest.mark.parametrize(("fleet", "in_touch", "plans"), [
    ("abc", "a", False), ("abc", "ab", True), ("abc", "bc", True),
    ("ab", "a", True), ("ab", "b", False),  # half the fleet: the side with its first drone
    ("abcd", "ab", True), ("abcd", "cd", False), ("abcd", "abc", True),
])
def test_a_drone_plans_only_in_touch_with_most_of_the_fleet(fleet: str, in_touch: str, plans: bool) -> None:
    """Both sides of a partition see the other leave: were both to plan, each around where it last knew
    the other, they could plan into one cell. Only a majority (half, with the first drone) plans on."""
    cells = {d: (i, 4, 0) for i, d in enumerate(fleet)}
    me = in_touch[0]
    proto = machine(cells, me=me)
    for gone in set(fleet) - set(in_touch):
        proto.handle(PeerLeft(gone), 0)
    task = Task(TaskId(5, me, 1), (4, 0, 0))
    actions = confirmed(proto, proto.handle(NewTask(task), 0)
                        + [a for p in in_touch[1:]
                           for a in proto.handle(CurrentTraj(p, Trajectory.stationary(cells[p], 0), task.id), 0)])
    failed = [a for a in actions if isinstance(a, TaskFailed)]
    assert bool([a for a in actions if isinstance(a, StartExecuting)]) is plans
    assert [f.reason for f in failed] == ([] if plans else [f"in touch with {len(in_touch)} of the fleet's "
                                                           "drones: no majority"])


def test_a_peer_joining_during_coordination_is_asked_and_waited_for() -> None:
    proto = machine({"a": A, "b": B})
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    told = Present("c", Trajectory.stationary(A, 1), False)
    assert proto.handle(PeerJoined("c", C), 1) == [told, Send("c", request(ID_A, "a", 1))]
    assert proto.handle(PeerJoined("c", C), 1) == [told]  # already a member: told again, not asked
    assert proto.handle(CurrentTraj("b", location_of("b"), ID_A), 1) == []  # still waiting for c
    c_plan = traj(2, (0, 4), (0, 3), (1, 3))
    action = started(confirmed(proto, proto.handle(CurrentTraj("c", c_plan, ID_A), 2)))
    assert action.psi == {"b": location_of("b"), "c": c_plan}


def test_a_peer_joining_while_idle_is_asked_at_the_next_task() -> None:
    proto = machine({"a": A})
    assert proto.handle(PeerJoined("b", B), 0) == [Present("b", Trajectory.stationary(A, 0), False)]
    actions = proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    assert actions == [Broadcast(ReqForCurrentTraj(ID_A, "a", location_of("a"), ("b",)))]  # it waits for b now
    answered = proto.handle(CurrentTraj("b", location_of("b"), ID_A), 0)
    assert started(confirmed(proto, answered)).psi == {"b": location_of("b")}


# ============================================================== no plan found
CORRIDOR = Workspace.build(size=(6, 1, 1))  # 1 wide: a parked drone walls in what lies behind it


def test_no_plan_fails_the_task_and_answers_the_pending_peers() -> None:
    peers = {"a": (0, 0, 0), "b": (2, 0, 0), "c": (5, 0, 0)}
    proto = machine(peers, workspace=CORRIDOR)
    task = Task(ID_A, (4, 0, 0))  # behind b, which stays parked
    proto.handle(NewTask(task), 3)
    proto.handle(ReqForCurrentTraj(ID_C_LOW, "c", Trajectory.stationary((5, 0, 0), 3), others("c")), 3)
    actions = proto.handle(CurrentTraj("b", Trajectory.stationary((2, 0, 0), 3), ID_A), 4)
    assert actions[0] == Send("c", CurrentTraj("a", Trajectory.stationary((0, 0, 0), 4), ID_C_LOW))
    [failed] = actions[1:]
    assert isinstance(failed, TaskFailed) and failed.task == task
    assert (proto.state, proto.task, proto.pending, proto.location) == (State.WAIT_FOR_TASK, None, {}, (0, 0, 0))
    # back in WaitForTaskRequest: it takes the next task
    assert proto.handle(NewTask(Task(TaskId(9, "a", 2), (1, 0, 0))), 5) == [Broadcast(ReqForCurrentTraj(
        TaskId(9, "a", 2), "a", Trajectory.stationary((0, 0, 0), 5), others("a")))]


@pytest.mark.parametrize(("flight_steps", "hovering_since", "plans"), [
    (4, None, True),  # exactly the 4 steps of the way
    (3, None, False),  # one short
    (7, 2, True),  # hovered 3 steps (2 .. start step 5) of 7: 4 left
    (6, 2, False),  # hovered 3 of 6: 3 left
    (2, 0, False),  # hovered longer than the budget
])
def test_the_battery_budget_caps_the_plan(flight_steps: int, hovering_since: int | None, plans: bool) -> None:
    proto = machine({"a": A}, lead_steps=2)
    actions = proto.handle(NewTask(Task(ID_A, GOAL, flight_steps, hovering_since)), 3)  # plan starts at 5
    kinds = [type(a) for a in actions[1:]]
    # alone, it holds a majority and needs nobody's ack: the plan is flown at once
    assert kinds == ([Broadcast, StartExecuting, Broadcast] if plans else [TaskFailed])
    assert proto.state is (State.EXECUTING if plans else State.WAIT_FOR_TASK)


# ============================================================ whole clusters
CROSSING = Workspace.build(size=(5, 5, 1), obstacles=frozenset({(1, 1, 0), (3, 3, 0)}), beta_s=1.0,
                           lambda_s=0.0)  # delta 1
CLUSTER_STARTS = {"a": (0, 2, 0), "b": (2, 0, 0), "c": (4, 4, 0)}
CLUSTER_GOALS = {"a": (4, 2, 0), "b": (2, 4, 0), "c": (0, 0, 0)}  # three crossing ways
ORDERS: list[str | int] = ["fifo", "lifo", 0, 1, 2, 3, 4]  # an int is the seed of a random order


def run_round(cluster: ProtocolCluster, goals: Mapping[str, Cell], order: str | int) -> None:
    """Every drone gets its task at the same step, then the network delivers everything."""
    first = len(cluster.started)
    for drone, goal in goals.items():
        cluster.start_task(drone, goal)
    cluster.deliver_all(random.Random(order) if isinstance(order, int) else order)
    round_ = cluster.started[first:]
    assert sorted(s.drone for s in round_) == sorted(goals), "every drone starts exactly once"
    assert cluster.failed == []
    for s in round_:
        plan = s.action.trajectory
        assert (plan.first, plan.last, plan.start_step) == (
            cluster.protocols[s.drone].location, goals[s.drone], cluster.now + cluster.lead_steps)
        # Psi is exactly what every peer had committed when I planned ...
        assert dict(s.action.psi) == dict(s.peers_then)
    # ... and whoever planned after me had my final trajectory: the paper's safety argument
    for i, earlier in enumerate(round_):
        for later in round_[i + 1:]:
            assert later.action.psi[earlier.drone] == earlier.action.trajectory
            assert later.action.psi[earlier.drone] == cluster.trajectory(earlier.drone)
    flown = {s.drone: s.action.trajectory for s in round_}
    assert check_fleet(cluster.workspace, flown, cluster.delta) == []


@pytest.mark.parametrize("order", ORDERS)
@pytest.mark.parametrize("drones", [("a", "b"), ("a", "c"), ("a", "b", "c")], ids="+".join)
def test_simultaneous_tasks_all_start_safely(drones: tuple[str, ...], order: str | int) -> None:
    cluster = ProtocolCluster(CROSSING, {d: CLUSTER_STARTS[d] for d in drones})
    assert cluster.delta == 1 and cluster.lead_steps == 2
    run_round(cluster, {d: CLUSTER_GOALS[d] for d in drones}, order)
    # the highest priority (lowest id) plans first; with equal stamps that is the smallest name
    assert cluster.started[0].drone == min(drones)


@pytest.mark.parametrize("order", ORDERS)
def test_a_second_round_plans_against_the_finished_first(order: str | int) -> None:
    cluster = ProtocolCluster(CROSSING, CLUSTER_STARTS)
    run_round(cluster, CLUSTER_GOALS, order)
    cluster.now = max(t.end_step for t in cluster.executed().values()) + 1
    for drone in CLUSTER_STARTS:
        cluster.complete(drone)
    run_round(cluster, CLUSTER_STARTS, order)  # and back home: the idle drones answer with their finished plans
    assert {s.drone: s.action.trajectory.first for s in cluster.started[3:]} == CLUSTER_GOALS


def test_a_drone_that_answered_a_request_ranks_below_it() -> None:
    """The hybrid clock at work: c answers b's request, then gets a task at the same physical step.
    By name c would lose to b anyway, so let a (the smallest name) be the one that answered."""
    cluster = ProtocolCluster(CROSSING, CLUSTER_STARTS)
    task_b = cluster.start_task("b", CLUSTER_GOALS["b"])
    for _ in range(3):  # b's broadcast reaches a, b and c
        cluster.deliver()
    task_a = cluster.start_task("a", CLUSTER_GOALS["a"])
    assert task_a.id > task_b.id  # a saw b's stamp
    cluster.deliver_all("lifo")
    b, a = cluster.started
    assert (b.drone, a.drone) == ("b", "a")
    assert a.action.psi["b"] == b.action.trajectory
    assert check_fleet(CROSSING, cluster.executed(), cluster.delta) == []


def test_a_later_task_plans_around_a_drone_already_flying() -> None:
    cluster = ProtocolCluster(CROSSING, CLUSTER_STARTS)
    cluster.start_task("a", CLUSTER_GOALS["a"])
    cluster.deliver_all()
    cluster.now = 2  # a is under way
    cluster.start_task("b", CLUSTER_GOALS["b"])
    cluster.deliver_all("lifo")
    a, b = cluster.started
    assert b.action.psi["a"] == a.action.trajectory  # the executing drone answered with its plan
    assert b.action.task.id > a.action.task.id
    flown = {**cluster.executed(), "c": cluster.trajectory("c")}  # c stays where it is
    assert check_fleet(CROSSING, flown, cluster.delta) == []


def deliver_from(cluster: ProtocolCluster, sender: str, to: str, kind: type, task_id: TaskId | None = None) -> None:
    """Deliver the oldest message of type ``kind`` in flight from ``sender`` to ``to`` (a request: of ``task_id``)."""
    index = next(i for i, (s, t, m) in enumerate(cluster.network) if (s, t) == (sender, to) and isinstance(m, kind)
                 and (task_id is None or (isinstance(m, ReqForCurrentTraj) and m.task_id == task_id)))
    cluster.deliver(index)


def test_a_request_overtaken_by_its_senders_next_one_holds_up_no_one() -> None:
    """The issue tracker's deadlock end to end: b's request for a round that is over reaches a after its
    request for the next round, which ranks below a's task. Both still start, against what the other
    had committed, and safely."""
    cluster = ProtocolCluster(CROSSING, CLUSTER_STARTS)
    old = cluster.start_task("b", CLUSTER_GOALS["b"]).id
    deliver_from(cluster, "b", "c", ReqForCurrentTraj)  # c answers b; b's request to a is held up
    cluster.now = 2
    mine = cluster.start_task("a", CLUSTER_GOALS["a"]).id  # ranks below b's first task
    deliver_from(cluster, "a", "b", ReqForCurrentTraj)  # b holds a; a's request to c is held up
    deliver_from(cluster, "c", "b", CurrentTraj)  # b plans, and answers a with its plan once a and c hold it
    for peer in ("a", "c"):
        deliver_from(cluster, "b", peer, PlanProposal)
        deliver_from(cluster, peer, "b", PlanAck)
    deliver_from(cluster, "b", "a", CurrentTraj)
    cluster.now = cluster.trajectory("b").end_step
    cluster.complete("b")
    new = cluster.start_task("b", CLUSTER_STARTS["b"]).id  # b saw a's stamp: ranks below a's task
    assert old < mine < new
    deliver_from(cluster, "b", "a", ReqForCurrentTraj, new)  # its answer to a, waiting for a's plan
    deliver_from(cluster, "b", "a", ReqForCurrentTraj, old)  # late
    cluster.deliver_all()
    assert {d: p.state for d, p in cluster.protocols.items()} == {  # nothing in flight: nobody waits
        "a": State.EXECUTING, "b": State.EXECUTING, "c": State.WAIT_FOR_TASK}
    assert [(s.drone, s.action.task.id) for s in cluster.started] == [("b", old), ("a", mine), ("b", new)]
    horizon = range(max(t.end_step for t in cluster.executed().values()) + cluster.delta + 2)
    for s in cluster.started:  # Psi is what each peer had committed (a location's stamp may differ)
        assert {p: [t.at(i) for i in horizon] for p, t in s.action.psi.items()} == {
            p: [t.at(i) for i in horizon] for p, t in s.peers_then.items()}
    assert cluster.started[2].action.psi["a"] == cluster.started[1].action.trajectory
    assert check_fleet(CROSSING, cluster.executed(), cluster.delta) == []


def test_a_rejoined_peer_that_leaves_again_stays_an_obstacle_where_it_announced_itself() -> None:
    proto = machine({"a": A, "b": B})
    proto.handle(PeerLeft("b"), 0)
    back_at = (2, 0, 0)  # on a's shortest way to its goal
    proto.handle(PeerJoined("b", back_at), 1)
    proto.handle(NewTask(Task(ID_A, GOAL)), 2)
    action = started(confirmed(proto, proto.handle(PeerLeft("b"), 3)))  # gone again before answering
    assert check_trajectory(OPEN, action.trajectory, {"b": Trajectory.stationary(back_at, 1)}, 0) == []


# ============================================================ random schedules
def flown_paths(cluster: ProtocolCluster, horizon: int) -> dict[str, Trajectory]:
    """Where each drone is at every step 0..horizon: its latest started plan, else where it began."""
    paths = {}
    for drone, proto in cluster.protocols.items():
        plans = [s.action.trajectory for s in cluster.started if s.drone == drone]
        here = plans[0].first if plans else proto.location
        cells = []
        for t in range(horizon + 1):
            begun = [p for p in plans if p.start_step <= t]
            cells.append(begun[-1].at(t) if begun else here)
        paths[drone] = Trajectory(0, tuple(cells))
    return paths


@pytest.mark.parametrize("seed", range(10))
@pytest.mark.parametrize("n", [2, 3, 4])
def test_random_schedules_of_tasks_messages_and_time(n: int, seed: int) -> None:
    """Tasks to idle drones at random moments, messages delivered in random order, time going on
    and plans completing: Psi is always what the peers had committed, nobody stays stuck
    coordinating, and what the fleet flies is safe."""
    rng = random.Random(seed)
    starts = dict(list({**CLUSTER_STARTS, "d": (0, 0, 0)}.items())[:n])
    cluster = ProtocolCluster(CROSSING, starts)
    for _ in range(300):
        idle = [d for d, p in cluster.protocols.items() if p.state is State.WAIT_FOR_TASK]
        roll = rng.random()
        if roll < 0.5 and cluster.network:
            cluster.deliver(rng.randrange(len(cluster.network)))
        elif roll < 0.7 and idle:
            cluster.start_task(rng.choice(idle), rng.choice(CROSSING.free_cells))
        else:
            cluster.now += 1
            for drone, proto in cluster.protocols.items():
                if proto.state is State.EXECUTING and proto.trajectory and proto.trajectory.end_step <= cluster.now:
                    cluster.complete(drone)
    cluster.deliver_all(rng)
    assert all(p.state is not State.COORDINATING for p in cluster.protocols.values())
    assert len(cluster.started) >= n  # the schedule did something
    horizon = max(s.action.trajectory.end_step for s in cluster.started) + cluster.delta + 2
    for s in cluster.started:
        assert s.action.psi.keys() == s.peers_then.keys()
        for peer, answer in s.action.psi.items():  # the same positions (a location's stamp may differ)
            assert [answer.at(t) for t in range(horizon)] == [s.peers_then[peer].at(t) for t in range(horizon)]
    assert check_fleet(CROSSING, flown_paths(cluster, horizon), cluster.delta) == []


# =========================================================== hybrid clocks
def test_task_ids_are_unique_and_totally_ordered_across_drones() -> None:
    clocks = [HybridClock(d) for d in ("a", "b", "c")]
    ids = [clock.next_id(physical) for physical in (0, 0, 5, 3, 3, 10) for clock in clocks]
    assert len(set(ids)) == len(ids)
    for x, y in itertools.combinations(ids, 2):
        assert (x < y) != (y < x)  # exactly one way round: a strict total order
    for clock in clocks:  # each drone's own ids only grow, even when physical time steps back
        own = [i for i in ids if i.drone == clock.drone]
        assert own == sorted(own) and [i.seq for i in own] == list(range(1, 7))


def test_ids_follow_physical_time_and_never_go_back() -> None:
    clock = HybridClock("a")
    assert clock.next_id(100).stamp == 100
    assert clock.next_id(50).stamp == 101
    assert clock.next_id(200).stamp == 200


def test_an_observed_stamp_makes_later_ids_rank_below_it() -> None:
    a, b = HybridClock("a"), HybridClock("b")
    seen = a.next_id(40)
    b.observe(seen.stamp)
    later = b.next_id(0)
    assert later.stamp > seen.stamp
    assert later > seen and later > TaskId(seen.stamp, "zzz", 10**6)
    b.observe(3)  # an older stamp does not pull the clock back
    assert b.next_id(0) > later


# ============================================================ a lost vehicle
def test_a_lost_vehicle_may_trail_its_plan_by_the_window_so_those_cells_are_held_too() -> None:
    """Delta covers a vehicle up to lambda late: lost at step 5 of its plan, seen in the plan's cell of
    step 5, it may still be in those of steps 3 and 4 (a killed vehicle's peer flew into one)."""
    proto = machine({"a": A, "b": B})
    proto.delta = 2
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    plan = started(confirmed(proto, proto.handle(CurrentTraj("b", location_of("b"), ID_A), 0))).trajectory
    proto.handle(VehicleLost(5, plan.at(5)), 5)
    assert {plan.at(3), plan.at(4)} <= set(proto.holds()) and plan.at(3) != plan.at(5)


def test_a_drone_whose_vehicle_is_lost_holds_the_rest_of_its_plan_and_plans_nothing() -> None:
    """Lost at step 4 of its plan, last seen in (1, 0): its vehicle may be anywhere on the rest of the
    plan from then on. Its answers and requests say so; a task of its own finds no plan."""
    proto = machine({"a": A, "b": B})
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    plan = started(confirmed(proto, proto.handle(CurrentTraj("b", location_of("b"), ID_A), 0))).trajectory
    assert proto.handle(VehicleLost(4, (1, 0, 0)), 4) == [Holding(proto.holds())]  # every peer is told at once
    answer = proto.handle(request(ID_B_LOW, "b", 4), 4)
    assert answer == [Send("b", CurrentTraj("a", plan, ID_B_LOW, ((1, 0, 0), A, *plan.suffix_from(4).cells)))]
    reply = answer[0]
    assert isinstance(reply, Send) and isinstance(reply.message, CurrentTraj)
    assert set(reply.message.holds) == {A, (1, 0, 0), (2, 0, 0), (3, 0, 0), (4, 0, 0)}

    proto.handle(PlanCompleted(), plan.end_step)
    actions = proto.handle(NewTask(Task(TaskId(20, "a", 2), (0, 3, 0))), 10)
    assert actions[0] == Broadcast(ReqForCurrentTraj(TaskId(20, "a", 2), "a", plan, ("b",), proto.holds()))
    failed = proto.handle(CurrentTraj("b", location_of("b", 10), TaskId(20, "a", 2)), 10)
    assert [type(a) for a in failed] == [TaskFailed]
    assert isinstance(failed[0], TaskFailed) and "vehicle is lost" in failed[0].reason

    assert proto.handle(Relocated((2, 0, 0)), 11) == [Holding(())]
    assert proto.holds() == () and proto.current_trajectory(11) == Trajectory.stationary((2, 0, 0), 11)


def test_a_plan_avoids_every_cell_a_lost_peer_holds_for_good() -> None:
    """b's vehicle is lost: the straight way from a to the goal crosses cells b holds, though b's own
    trajectory (resting at B) never comes near. a plans around them, for good."""
    proto = machine({"a": A, "b": B})
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    held = ((2, 0, 0), (2, 1, 0))
    plan = started(confirmed(proto, proto.handle(CurrentTraj("b", location_of("b"), ID_A, held), 0)))
    assert not set(plan.trajectory.cells) & set(held)
    assert check_trajectory(OPEN, plan.trajectory, {"hold": Trajectory.stationary((2, 0, 0), 0)}, 0) == []
    assert manhattan(A, GOAL) < len(plan.trajectory.cells) - 1  # the detour


# ========================================== a peer leaves across the plan I fly
B_AWAY = traj(0, (3, 0), (3, 1))  # b's plan: it leaves (3, 0) long before a flies through it


def flying_past_b() -> tuple[CoordinationProtocol, Trajectory]:
    """a (peers b and c) flies row 0 to GOAL, through (3, 0) at step 5, having planned around B_AWAY."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    proto.handle(CurrentTraj("b", B_AWAY, ID_A), 0)
    plan = started(confirmed(proto, proto.handle(CurrentTraj("c", location_of("c"), ID_A), 0))).trajectory
    assert plan.at(5) == (3, 0, 0)
    return proto, plan


def test_a_peer_that_leaves_across_the_rest_of_my_plan_has_me_plan_that_rest_anew() -> None:
    """Found by the systematic tester with a crash: b's agent died before it flew its plan (silent since
    step 0), its vehicle holding where it was; a drone that had planned around b's plan flew into it.
    Plans made before a leave is noticed avoided only the plan: the rest of mine is planned anew, flown
    on meanwhile."""
    proto, plan = flying_past_b()
    assert proto.handle(PeerLeft("b", silent_since=0), 2) == [Threatened("b", ((3, 0, 0),))]
    proto.handle(Reroute(Task(TaskId(6, "a", 2), GOAL)), 2)
    assert proto.state is State.REROUTING and proto.trajectory == plan  # what it answers meanwhile
    actions = confirmed(proto, proto.handle(CurrentTraj("c", location_of("c"), TaskId(6, "a", 2)), 2))
    new = started(actions).trajectory
    assert all(new.at(s) == plan.at(s) for s in range(0, 5))  # the same until the new rest starts
    assert not {(3, 0, 0), (3, 1, 0)} & set(new.suffix_from(4).cells) and new.last == GOAL
    assert state_of(proto) is State.EXECUTING and proto.trajectory == new


def test_a_leave_behind_my_plan_changes_nothing() -> None:
    proto, _ = flying_past_b()
    assert proto.handle(PeerLeft("c"), 2) == []


def test_a_reroute_round_ends_when_the_plan_does() -> None:
    """The plan ended before the round: the drone rests at its end, and the round is moot."""
    proto, plan = flying_past_b()
    proto.handle(PeerLeft("b"), 2)
    proto.handle(Reroute(Task(TaskId(6, "a", 2), GOAL)), 2)
    actions = proto.handle(PlanCompleted(), 6)
    assert [type(a) for a in actions] == [RerouteFailed]
    assert proto.state is State.WAIT_FOR_TASK and proto.location == plan.last


def test_a_peer_that_leaves_is_held_along_its_newest_plan_not_an_old_answer() -> None:
    """Found by a crash sweep: b answered my round at rest, then announced a plan and died; I kept
    the old answer as its last trajectory, held only where it had rested, and planned into its plan."""
    proto = machine({"a": A, "b": B})
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    started(confirmed(proto, proto.handle(CurrentTraj("b", location_of("b"), ID_A), 0)))
    b_plan = traj(3, (4, 4), (3, 4), (3, 3), (3, 2))
    proto.heard("b", b_plan)
    proto.handle(PeerLeft("b"), 4)
    assert {(3, 3, 0), (3, 2, 0)} <= set(proto.ghosts["b"].cells) and proto.ghosts["b"].last == (3, 2, 0)


# ================================================ a vehicle that comes down by itself
def test_a_drone_whose_vehicle_came_down_stays_there_and_tells_every_peer() -> None:
    """Found once the tester kept a vehicle down where it came down (its model flew the plan on):
    peers planned, and flew, into it. It rests there for good, says so, and plans nothing more."""
    proto, plan = flying_past_b()
    actions = proto.handle(VehicleDown(plan.at(3)), 3)
    assert actions[0] == Grounded(Trajectory.stationary(plan.at(3), 3))
    assert proto.state is State.WAIT_FOR_TASK and proto.current_trajectory(9) == Trajectory.stationary(plan.at(3), 3)
    failed = proto.handle(NewTask(Task(TaskId(9, "a", 2), GOAL)), 4)
    failed += proto.handle(CurrentTraj("b", location_of("b"), TaskId(9, "a", 2)), 4)
    failed += proto.handle(CurrentTraj("c", location_of("c"), TaskId(9, "a", 2)), 4)
    assert [a.reason for a in failed if isinstance(a, TaskFailed)] == ["my vehicle is down"]


def test_a_peer_down_on_the_rest_of_my_plan_has_me_plan_it_anew_and_stays_an_obstacle() -> None:
    proto, plan = flying_past_b()
    assert proto.handle(PeerDown("c", plan.at(5)), 2) == [Threatened("c", (plan.at(5),))]
    assert proto.handle(PeerDown("b", (2, 4, 0)), 2) == [Threatened("b", (plan.at(5),))]  # off my plan: c's stands
    proto.handle(Reroute(Task(TaskId(6, "a", 2), GOAL)), 2)
    late_answer = CurrentTraj("c", traj(0, (0, 4), (1, 4)), TaskId(6, "a", 2))  # sent before it came down
    new = started(confirmed(proto, proto.handle(CurrentTraj("b", location_of("b"), TaskId(6, "a", 2)), 2)
                            + proto.handle(late_answer, 2))).trajectory
    assert plan.at(5) not in new.suffix_from(4).cells
    assert proto.received["c"] == Trajectory.stationary(plan.at(5), 0)


def test_a_reroute_with_no_peer_left_to_ask_plans_from_the_plan_flown() -> None:
    """Found by a crash sweep: with nobody to wait for, the round planned at once, before it was
    marked a reroute, from where the drone had rested before its plan."""
    proto = machine({"a": A, "b": B})
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    plan = started(confirmed(proto, proto.handle(CurrentTraj("b", B_AWAY, ID_A), 0))).trajectory
    assert proto.handle(PeerLeft("b", silent_since=0), 2) == [Threatened("b", ((3, 0, 0),))]
    new = started(confirmed(proto, proto.handle(Reroute(Task(TaskId(6, "a", 2), GOAL)), 2))).trajectory
    assert all(new.at(s) == plan.at(s) for s in range(0, 5)) and (3, 0, 0) not in new.suffix_from(4).cells


# ======================================================== braking short of a cell held for good
def test_a_vehicle_down_too_close_to_plan_around_has_me_brake_short_of_it() -> None:
    """Found by a sweep (seed 2027): a vehicle came down two steps ahead of a drone's plan, sooner than a
    round can plan around it, and the drone flew into it. It now stops at the cell before, and says so."""
    proto, plan = flying_past_b()
    actions = proto.handle(PeerDown("c", plan.at(5)), 4)
    cut = Trajectory(plan.start_step, (*(plan.at(t) for t in range(plan.start_step, 5)), plan.at(4)))
    assert actions == [Braked(cut, plan.at(5))]
    assert proto.trajectory == cut and proto.state is State.EXECUTING
    assert [a.message.trajectory for a in proto.handle(request(ID_B_LOW, "b"), 4) if isinstance(a, Send)
            and isinstance(a.message, CurrentTraj)] == [cut]


def test_a_drone_that_braked_tells_a_peer_back_of_the_brake() -> None:
    """Its announcement of the brake went nowhere across a partition: a peer back is told, as a brake."""
    proto, plan = flying_past_b()
    [braked] = proto.handle(PeerDown("c", plan.at(5)), 4)
    assert isinstance(braked, Braked)
    proto.handle(PeerLeft("b", silent_since=4), 4)
    assert proto.handle(PeerJoined("b", B), 5) == [Present("b", braked.trajectory, True)]


def test_a_peer_back_is_held_where_it_may_be_until_it_says_what_it_flies() -> None:
    """Sweep 10033: the cut healed, d4 dropped d1's ghost at once, and flew into d1, which had braked
    while they were apart. A peer back stays held where it may be until its own word comes."""
    proto = machine({"a": A, "b": B})
    way = traj(0, (4, 4), (3, 4), (2, 4), (2, 3))
    proto.heard("b", way)
    proto.handle(PeerLeft("b", silent_since=0), 1)
    held = {t.last for t in proto.ghost_obstacles().values()}
    assert set(way.cells) <= held
    proto.handle(PeerJoined("b", way.last), 2)
    assert {t.last for t in proto.ghost_obstacles().values()} == held and "b" in proto.members
    cut = traj(0, (4, 4), (3, 4), (3, 4))
    proto.handle(PeerBraked("b", cut), 3)
    assert proto.ghost_obstacles() == {} and proto.known["b"] == cut and proto.braked == {"b": cut}


def test_a_round_that_ends_too_late_to_plan_around_a_vehicle_down_brakes_at_the_last_step() -> None:
    """Found by a crash sweep (seed 5151): the round to plan around it was still waiting for an answer
    when the plan entered the cell. At the boundary before, the drone brakes and the round ends."""
    proto, plan = flying_past_b()
    assert proto.handle(PeerDown("c", plan.at(5)), 2) == [Threatened("c", (plan.at(5),))]
    proto.handle(Reroute(Task(TaskId(6, "a", 2), GOAL)), 2)
    assert proto.handle(NextStep(), 3) == []  # (3, 0) is two steps away: a plan may still come
    actions = proto.handle(NextStep(), 4)
    assert [type(a) for a in actions] == [Braked, RerouteFailed]
    assert proto.state is State.EXECUTING and proto.trajectory is not None and proto.trajectory.last == plan.at(4)
    assert plan.at(5) not in proto.trajectory.cells


def test_a_peer_that_braked_overrides_its_older_answer_until_its_next_plan() -> None:
    """Found by the tester once drones braked: a drone planned with a braked peer's answer, sent before
    the brake and delivered after its news, and so planned through where the peer held."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    cut = traj(0, (3, 0), (3, 0))
    proto.handle(PeerBraked("b", cut), 0)
    proto.handle(CurrentTraj("b", B_AWAY, ID_A), 0)  # sent before it braked
    assert proto.received["b"] == cut
    plan = started(confirmed(proto, proto.handle(CurrentTraj("c", location_of("c"), ID_A), 0))).trajectory
    assert (3, 0, 0) not in plan.cells
    later = traj(4, (3, 0), (3, 1))
    proto.heard("b", later)
    assert proto.known["b"] == later and "b" not in proto.braked


def test_a_peer_that_braked_twice_on_one_plan_holds_where_it_braked_last_whatever_the_order_heard() -> None:
    """Found by the tester (sweep 20164 with --skews 1): a drone braked, then braked again shorter on the
    same plan; its first cut came last, and a peer planned through where it held."""
    proto = machine()
    first, second = traj(0, (3, 2), (3, 1), (3, 0), (3, 0)), traj(0, (3, 2), (3, 1), (3, 1))
    proto.handle(PeerBraked("b", second), 0)
    proto.handle(PeerBraked("b", first), 0)
    assert proto.known["b"] == second and proto.braked["b"] == second


def test_a_brake_heard_after_the_peers_rest_still_overtakes_the_answer_my_round_holds() -> None:
    """Found by the tester (sweep 20171 with --skews 1): b answered my round with its plan, braked on it,
    and, its clock off, said at once that it rests. The rest came first, so its brake was taken for old
    news, and I planned with the plan it had cut."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    plan = traj(0, (3, 2), (3, 1), (3, 0), (4, 0))
    cut = traj(0, (3, 2), (3, 1), (3, 1))
    proto.handle(CurrentTraj("b", plan, ID_A), 0)
    proto.handle(PeerAnnounced("b", Trajectory.stationary((3, 1, 0), 3)), 3)
    proto.handle(PeerBraked("b", cut), 3)
    assert proto.received["b"] == cut


def test_a_peers_brake_holds_on_past_the_rest_it_says_it_takes_there() -> None:
    """Found by the tester (sweep 20181 with --skews 1): b braked and, its clock off, said at once that it
    rests where it braked. Its answer to my round, sent before, came after both: the rest had ended the
    brake, and I planned with the plan b had cut."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    plan, cut = traj(0, (4, 4), (4, 3), (3, 3), (2, 3)), traj(0, (4, 4), (4, 3), (4, 3))
    proto.handle(PeerBraked("b", cut), 1)
    proto.handle(PeerAnnounced("b", Trajectory.stationary((4, 3, 0), 3)), 3)
    proto.handle(CurrentTraj("b", plan, ID_A), 3)  # sent before it braked
    assert proto.received["b"] == cut


def test_a_peers_brake_heard_after_its_rest_drops_the_plan_i_made_with_what_it_cut() -> None:
    """Found by the tester (sweep 20181 with --skews 1): b answered my round with its plan, braked, said
    it rests there, and acked my plan; its rest came first, so its brake was taken for old news and my
    plan, made with what it cut, was flown."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    plan, cut = traj(0, (4, 4), (4, 3), (3, 3), (2, 3)), traj(0, (4, 4), (4, 3), (4, 3))
    proto.handle(CurrentTraj("b", plan, ID_A), 0)
    proto.handle(CurrentTraj("c", location_of("c"), ID_A), 0)
    assert proto.state is State.CONFIRMING
    proto.handle(PeerAnnounced("b", Trajectory.stationary((4, 3, 0), 3)), 3)
    proto.handle(PeerBraked("b", cut), 3)
    assert state_of(proto) is not State.CONFIRMING and proto.proposed is None


def test_a_peer_that_braked_holds_there_until_the_plan_it_made_since_starts() -> None:
    """Found by the tester (sweep 20213 with --partitions 2): b braked across a cut; told once it healed,
    my rest could not be planned anew, and NextStep would have braked, but b's next plan, from where it
    held and starting later, came first and ended the brake. I flew into b, still waiting there."""
    proto, plan = flying_past_b()
    proto.handle(PeerBraked("b", traj(0, (3, 1), (3, 0), (3, 0))), 1)  # holds (3, 0) from step 2
    proto.heard("b", traj(9, (3, 0), (3, 1)))  # its next plan, from there, starts at step 9
    actions = proto.handle(NextStep(), 4)
    assert [type(a) for a in actions] == [Braked]
    assert proto.trajectory is not None and (3, 0, 0) not in proto.trajectory.suffix_from(4).cells
    assert plan.at(5) == (3, 0, 0)


@pytest.mark.parametrize("brake_heard_last", [False, True])
def test_a_peer_down_elsewhere_no_longer_holds_where_it_braked(brake_heard_last: bool) -> None:
    """Found by the tester (sweep 20242 with --skews 1): b braked on a plan it never flew (its clock off),
    then its vehicle came down where it was. Its brake held a cell for good, which plans did not avoid: a
    drone planned into it, braked at once, and planned again, for good, its mail never delivered. A
    vehicle down stays where it came down: nothing else of it holds, nor does its brake heard late."""
    proto, plan = flying_past_b()
    down = PeerDown("b", (6, 6, 0))
    brake = PeerBraked("b", traj(0, (3, 1), (3, 0), (3, 0)))  # holds (3, 0) from step 2
    for event in (down, brake) if brake_heard_last else (brake, down):
        proto.handle(event, 2)
    assert "b" not in proto.braked
    assert proto.handle(NextStep(), 4) == []
    assert proto.trajectory == plan and plan.at(5) == (3, 0, 0)


def test_a_peer_down_then_restarted_holds_where_it_braked_since() -> None:
    """A second review: a peer's vehicle came down, its agent was restarted (it left and joined again), and
    it braked on a plan flown since. That brake is news of its new run, not of the vehicle down."""
    proto, plan = flying_past_b()
    proto.handle(PeerDown("b", (6, 6, 0)), 1)
    proto.handle(PeerLeft("b", silent_since=1), 1)
    proto.handle(PeerJoined("b", (6, 6, 0)), 1)
    actions = proto.handle(PeerBraked("b", traj(2, (3, 1), (3, 0), (3, 0))), 2)  # holds (3, 0) from step 3
    assert [type(a) for a in actions] in ([Threatened], [Braked])
    assert plan.at(5) == (3, 0, 0)


def test_a_peer_that_braked_on_my_plan_has_me_brake_or_plan_anew() -> None:
    """A brake holds a cell that plans made before it did not avoid: the plan flown steers clear of it."""
    proto, plan = flying_past_b()
    far = proto.handle(PeerBraked("b", traj(0, (3, 1), (3, 0), (3, 0))), 2)
    assert far == [Threatened("b", (plan.at(5),))]
    proto, plan = flying_past_b()
    near = proto.handle(PeerBraked("b", traj(0, (3, 1), (3, 0), (3, 0))), 4)
    assert [type(a) for a in near] == [Braked] and proto.trajectory is not None
    assert proto.trajectory.last == plan.at(4)


def test_a_drone_whose_vehicle_is_down_tells_a_peer_that_joins() -> None:
    """Found by a crash sweep (seed 101): an agent that restarted had missed the news, took the vehicle
    down for a drone at rest that would make way, and flew between two chargers for good."""
    proto, plan = flying_past_b()
    proto.handle(VehicleDown(plan.at(3)), 3)
    proto.handle(PeerLeft("b"), 4)
    assert proto.handle(PeerJoined("b", B), 5) == [Grounded(Trajectory.stationary(plan.at(3), 3))]


def test_the_operator_releases_a_departed_drones_cells_and_nothing_else() -> None:
    """A killed drone's whole remaining path stayed blocked for good (issue 25: 37 refusals in one
    run). Once the operator saw its vehicle out of the air, no cell is held for it; a drone in the
    fleet cannot be released."""
    proto, _ = flying_past_b()
    proto.handle(PeerLeft("c"), 2)
    assert proto.ghosts["c"].last == C
    with pytest.raises(ProblemError, match="b is not a drone gone"):
        proto.handle(Released("b"), 3)
    assert proto.handle(Released("c"), 3) == [] and "c" not in proto.ghosts and "c" not in proto.known
    assert proto.ghost_obstacles() == {}
    proto.handle(PeerJoined("c", (2, 2, 0)), 4)
    assert proto.known["c"] == Trajectory.stationary((2, 2, 0), 4) and "c" in proto.members


# ============================================== a plan is flown once every member holds it
def confirming(lead_steps: int = 2) -> tuple[CoordinationProtocol, PlanProposal]:
    """a planned (b and c answered, c waits for a's plan), and waits for b's and c's acks."""
    proto = machine(lead_steps=lead_steps)
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    proto.handle(request(ID_C_LOW, "c"), 0)
    [broadcast] = proto.handle(CurrentTraj("b", location_of("b"), ID_A), 0)
    assert isinstance(broadcast, Broadcast) and isinstance(broadcast.message, PlanProposal)
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
                       Send("c", CurrentTraj("a", stay, ID_C_LOW)),
                       TaskFailed(Task(ID_A, GOAL), "not every peer held my plan in time")]
    assert proto.state is State.WAIT_FOR_TASK and proto.trajectory is None
    assert proto.handle(PlanAck("c", ID_A, location_of("c")), 1) == []  # too late


def test_a_request_while_confirming_is_answered_once_decided() -> None:
    proto, proposal = confirming()
    assert proto.handle(request(ID_B_HIGH, "b"), 0) == []  # even a higher priority waits (a lead at most)
    proto.handle(PlanAck("b", ID_A, location_of("b")), 0)
    actions = proto.handle(PlanAck("c", ID_A, location_of("c")), 0)
    assert {a.to for a in actions if isinstance(a, Send)} == {"b", "c"}
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


# ====================================================== a clock beyond the fleet's bound
def test_a_drone_whose_clock_is_off_holds_where_its_plan_ends_and_plans_nothing() -> None:
    """Its steps are not the fleet's: every cell of the rest of its plan is held for good in its answers,
    and it plans nothing; the others plan around that and go on (they do not wait for it)."""
    proto = machine()
    plan = started(confirmed(proto, proto.handle(NewTask(Task(ID_A, GOAL)), 0)
                             + proto.handle(CurrentTraj("b", location_of("b"), ID_A), 0)
                             + proto.handle(CurrentTraj("c", location_of("c"), ID_A), 0))).trajectory
    assert proto.handle(ClockBound(mine_off=True), 3) == []
    assert set(plan.suffix_from(3).cells) <= set(proto.holds())
    [answer] = proto.handle(request(ID_B_LOW, "b", 4), 4)
    assert isinstance(answer, Send) and isinstance(answer.message, CurrentTraj)
    assert set(answer.message.holds) == set(proto.holds())
    proto.handle(PlanCompleted(), plan.end_step)
    failed = proto.handle(NewTask(Task(TaskId(9, "a", 2), A)), plan.end_step)
    failed += proto.handle(CurrentTraj("b", location_of("b"), TaskId(9, "a", 2)), plan.end_step)
    failed += proto.handle(CurrentTraj("c", location_of("c"), TaskId(9, "a", 2)), plan.end_step)
    assert [a.reason for a in failed if isinstance(a, TaskFailed)] == ["my clock is beyond the fleet's bound"]
    # At rest, it answers with the cell it rests in alone: peers hold every cell it answers with for good.
    assert proto.holds() == (GOAL,)
    [answer] = proto.handle(request(TaskId(30, "b", 3), "b", plan.end_step + 1), plan.end_step + 1)
    assert isinstance(answer, Send) and isinstance(answer.message, CurrentTraj)
    assert set(answer.message.trajectory.cells) == {GOAL}
    proto.handle(ClockBound(mine_off=False), plan.end_step + 1)
    assert proto.holds() == ()


def test_a_peer_whose_clock_is_off_gets_no_ack_and_is_held_where_it_flies_for_good() -> None:
    proto = machine()
    proto.handle(ClockBound(mine_off=False, outliers=frozenset({"b"})), 0)
    assert proto.handle(PlanProposal("b", ID_B_LOW, traj(3, (4, 4), (3, 4)), ("a", "c")), 0) == []
    b_way = traj(0, (2, 1), (2, 0), (2, 1))  # across a's way, long before a gets there: in b's steps, not ours
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    proto.handle(CurrentTraj("b", b_way, ID_A), 0)
    action = started(confirmed(proto, proto.handle(CurrentTraj("c", location_of("c"), ID_A), 0)))
    held = {t.last for name, t in action.psi.items() if name.startswith("b@")}
    assert held == set(b_way.cells) and (2, 0, 0) not in action.trajectory.cells


@pytest.mark.parametrize(("verdict_at", "steered"), [(2, Threatened), (3, Braked)])
def test_the_plan_i_fly_steers_clear_of_the_plan_of_a_peer_found_with_its_clock_off(verdict_at: int,
                                                                                   steered: type) -> None:
    """Found in review: the cells of a peer whose clock is off were held for good only in plans made after
    the verdict. The plan I fly went on through a cell b left a few steps before, in steps b's clock no
    longer keeps with mine: it is planned anew there, or (too close for a round) cut short of it."""
    proto, _ = flying_past_b()
    actions = proto.handle(ClockBound(mine_off=False, outliers=frozenset({"b"})), verdict_at)
    assert [type(a) for a in actions] == [steered]
    if steered is Threatened:
        assert actions == [Threatened("b", ((3, 0, 0),))]
    else:
        assert proto.trajectory is not None and (3, 0, 0) not in proto.trajectory.suffix_from(verdict_at).cells
    assert proto.handle(ClockBound(mine_off=False, outliers=frozenset({"b"})), verdict_at) == []  # news once


def test_two_peers_found_off_at_once_have_the_plan_i_fly_planned_anew_once() -> None:
    """Found by the tester (sweep 20182 with --skews 2): one clock check found b and c off, each on the
    rest of my plan. Each was reported Threatened; the first had the rest planned anew, and the second
    asked for a new rest while that round was under way, which no state takes."""
    proto, _ = flying_past_b()
    proto.handle(PeerAnnounced("c", traj(1, (0, 4), (1, 4), (1, 3), (4, 3), (4, 1), (4, 0))), 1)
    actions = proto.handle(ClockBound(mine_off=False, outliers=frozenset({"b", "c"})), 2)
    assert [type(a) for a in actions] == [Threatened]
    assert actions == [Threatened("b, c", ((3, 0, 0), (4, 0, 0)))]


def test_a_drone_whose_clock_is_off_stops_short_of_every_cell_of_its_peers_plans() -> None:
    """Its steps are not the fleet's: b left (3, 0) steps before I fly there by my clock, but by b's I may
    come while it is there (or after it rests there). Flying on to the plan's end, as before, is no longer
    safe: the plan is cut short of the first cell a peer's plan holds, and that is what I answer with."""
    proto, plan = flying_past_b()
    actions = proto.handle(ClockBound(mine_off=True), 2)
    assert [type(a) for a in actions] == [Braked]
    assert proto.trajectory is not None and proto.trajectory.last == plan.at(4) == (2, 0, 0)
    assert not set(proto.holds()) & set(B_AWAY.cells)


def test_a_drone_whose_clock_is_off_tells_every_peer_at_once_that_it_rests() -> None:
    """Found by the systematic tester (sweep 20132 with --skews 1): peers hold every cell of the plan they
    last heard a drone off fly, and one braked short of a charger that drone had left long before, walling
    it in. At its plan's end the drone off says it rests in one cell, without waiting to be asked."""
    proto, _ = flying_past_b()
    proto.handle(ClockBound(mine_off=True), 2)
    assert proto.trajectory is not None
    rest = Trajectory.stationary(proto.trajectory.last, proto.trajectory.end_step)
    told = proto.handle(PlanCompleted(), proto.trajectory.end_step)
    assert told == [Present(peer, rest, braked=False) for peer in ("b", "c")]


def test_a_drone_found_off_at_rest_after_a_plan_tells_every_peer_at_once_that_it_rests() -> None:
    """Found by the systematic tester (sweep 20132, seed 74613): the clock check found a drone off after
    its plan had ended; it still answered with that plan, so peers held the charger it had left for good."""
    proto, _ = flying_past_b()
    assert proto.trajectory is not None
    end = proto.trajectory.end_step
    proto.handle(PlanCompleted(), end)
    rest = Trajectory.stationary(proto.trajectory.last, end + 3)
    told = proto.handle(ClockBound(mine_off=True), end + 3)
    assert told == [Present(peer, rest, braked=False) for peer in ("b", "c")]
    assert proto.current_trajectory(end + 4) == rest


def test_a_request_of_a_round_whose_plan_was_decided_is_late_even_after_a_rejoin() -> None:
    """Found by a partition sweep (seed 9201): b's decision made it a member again (and forgot its newest
    request, as a join does); b's request of that same round came after, was taken as current, and
    put where b was before that plan in my Psi."""
    proto = machine()
    proto.handle(PeerLeft("b"), 0)
    b_plan = traj(3, (4, 4), (3, 4), (2, 4))
    proto.handle(PlanDecision("b", ID_B_LOW, b_plan, flown=True), 1)
    assert "b" in proto.members and proto.known["b"] == b_plan
    proto.handle(NewTask(Task(ID_A, GOAL)), 1)
    proto.handle(CurrentTraj("b", b_plan, ID_A), 1)
    assert proto.handle(request(ID_B_LOW, "b"), 1) == []  # late: its plan is decided
    assert proto.received["b"] == b_plan and "b" not in proto.pending


def test_a_peers_lost_vehicle_on_the_rest_of_my_plan_has_me_plan_it_anew_and_stays_an_obstacle() -> None:
    """Found over real processes: b's vehicle was lost where my plan was to pass later; b's answers said
    so, but only in my next round. Told at once (PeerLost), I steer clear as of a vehicle down."""
    proto, plan = flying_past_b()
    assert proto.handle(PeerLost("b", (plan.at(5), (4, 4, 0))), 2) == [Threatened("b", (plan.at(5),))]
    proto.handle(Reroute(Task(TaskId(6, "a", 2), GOAL)), 2)
    new = started(confirmed(proto, proto.handle(CurrentTraj("b", location_of("b"), TaskId(6, "a", 2)), 2)
                            + proto.handle(CurrentTraj("c", location_of("c"), TaskId(6, "a", 2)), 2))).trajectory
    assert plan.at(5) not in new.suffix_from(4).cells
    proto.handle(PeerLost("b", ()), 3)  # back
    assert proto.peers_lost == {}


def test_an_ack_that_says_the_member_holds_my_way_drops_my_plan() -> None:
    """Found in review: a member whose clock is off checked my plan on its own steps, which said nothing,
    and acked. Its ack says what it flies and holds: a plan across that is not flown."""
    proto, proposal = confirming()
    held = tuple(proposal.trajectory.cells[1:3])
    actions = proto.handle(PlanAck("b", ID_A, location_of("b"), held), 0)
    assert [type(a) for a in actions] == [Broadcast, Send, TaskFailed] and proto.state is State.WAIT_FOR_TASK
    assert isinstance(actions[-1], TaskFailed) and actions[-1].reason == "b flies or holds across it"


def test_a_drone_whose_clock_is_off_acks_with_the_cells_it_holds_for_good() -> None:
    """Its own check runs on steps that are not the fleet's: the proposer judges its plan against the cells
    the ack holds. Acking nothing stalled every plan of the fleet (found over real processes)."""
    proto = machine()
    proto.handle(ClockBound(mine_off=True), 0)
    proposal = PlanProposal("b", ID_B_LOW, traj(3, (4, 4), (4, 3)), ("a", "c"))
    assert proto.handle(proposal, 0) == [Send("b", PlanAck("a", ID_B_LOW, location_of("a"), proto.holds()))]
    assert A in proto.holds()


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
    proto.heard("c", Trajectory.stationary(C, 3))
    assert not any(name.startswith("c!") for name in proto.ghost_obstacles())


def test_a_round_asks_again_the_members_that_have_not_answered() -> None:
    """Seen once over real processes: a round waited for good after a partition healed (most likely a
    request or answer lost while the link's routes came back). Every few steps the silent members are
    asked again."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    proto.handle(CurrentTraj("b", location_of("b"), ID_A), 0)  # c's answer is lost
    assert [proto.handle(NextStep(), step) for step in range(1, ASK_AGAIN_STEPS)] == [[]] * (ASK_AGAIN_STEPS - 1)
    assert proto.handle(NextStep(), ASK_AGAIN_STEPS) == [Send("c", request(ID_A, "a", ASK_AGAIN_STEPS))]
    planned = proto.handle(CurrentTraj("c", location_of("c"), ID_A), ASK_AGAIN_STEPS)
    assert proto.state is State.CONFIRMING and isinstance(planned[0], Broadcast)
