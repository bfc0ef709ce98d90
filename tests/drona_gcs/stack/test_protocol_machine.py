"""The coordination protocol (paper Protocol 1) as a sans-I/O state machine: its table,
answers to requests, a new task and a task with no plan.
"""

from __future__ import annotations

import itertools

import pytest

from drona_gcs.errors import ProtocolViolation
from drona_gcs.motion import Trajectory
from drona_gcs.safety import check_trajectory
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
from drona_gcs.stack.protocol import (
    TRANSITIONS,
    Brake,
    Broadcast,
    ClockBound,
    CoordinationProtocol,
    Event,
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
    Send,
    StartExecuting,
    State,
    TaskFailed,
    VehicleDown,
    VehicleLost,
)
from drona_gcs.workspace import Workspace
from tests.drona_gcs.stack.protocol_helpers import (
    GOAL,
    ID_A,
    ID_B_LOW,
    ID_C_LOW,
    OPEN,
    A,
    B,
    C,
    confirmed,
    location_of,
    machine,
    manhattan,
    others,
    request,
    started,
    traj,
)

# =========================================================== the state table
EVENT_TYPES: tuple[type, ...] = (NewTask, PlanCompleted, PeerLeft, PeerJoined, ReqForCurrentTraj, CurrentTraj,
                                 VehicleLost, Relocated, Reroute, VehicleDown, PeerDown, PeerBraked, PeerAnnounced,
                                 Released, NextStep, PlanProposal, PlanAck, PlanRefusal, PlanDecision, ClockBound,
                                 PeerLost, Brake)
#: What Protocol 1 takes in each state (paper section 3.1); the rest is a protocol violation. A vehicle
#: found again is not placed while a round is under way (its request carried where it was). Only a
#: drone flying a plan plans its rest anew (Reroute), and that round ends when the plan does; a
#: drone whose rest found no plan brakes (Brake) once the round is over, flying the plan.
REJECTED = {*((state, Brake) for state in State if state is not State.EXECUTING),
            (State.COORDINATING, NewTask), (State.EXECUTING, NewTask), (State.REROUTING, NewTask),
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
        Brake: Brake(),
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
