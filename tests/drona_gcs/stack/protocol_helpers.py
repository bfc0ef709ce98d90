"""Shared helpers of the coordination protocol tests (``test_protocol_*.py``).

Unit tests feed one drone's machine events by hand on an open 5 x 5 x 1 grid
(the unit tests use delta 0, so the shortest plan is the Manhattan path).
"""

from __future__ import annotations

from collections.abc import Mapping

from drona_gcs.motion import Trajectory
from drona_gcs.planner import SafePlanner
from drona_gcs.stack.messages import (
    CurrentTraj,
    PlanAck,
    PlanProposal,
    ReqForCurrentTraj,
    Task,
    TaskId,
)
from drona_gcs.stack.protocol import (
    Action,
    Broadcast,
    CoordinationProtocol,
    NewTask,
    StartExecuting,
    State,
)
from drona_gcs.workspace import Cell, Workspace

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
            workspace: Workspace = OPEN, at_once: bool = False) -> CoordinationProtocol:
    """Drone ``me`` with ``peers`` (default a, b and c); the peer map includes ``me``. ``at_once``: a new
    task's plan is proposed at once (off: every task asks first, the rounds these tests follow)."""
    peers = dict(STARTS if peers is None else peers)
    return CoordinationProtocol(me, peers[me], peers, SafePlanner(workspace, 0).plan, lead_steps,
                                propose_at_once=at_once)


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


ID_B_NEXT = TaskId(9, "b", 2)  # b's next task, after ID_B_HIGH or ID_B_LOW: a drone's ids only grow


B_AWAY = traj(0, (3, 0), (3, 1))  # b's plan: it leaves (3, 0) long before a flies through it


def flying_past_b() -> tuple[CoordinationProtocol, Trajectory]:
    """a (peers b and c) flies row 0 to GOAL, through (3, 0) at step 5, having planned around B_AWAY."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    proto.handle(CurrentTraj("b", B_AWAY, ID_A), 0)
    plan = started(confirmed(proto, proto.handle(CurrentTraj("c", location_of("c"), ID_A), 0))).trajectory
    assert plan.at(5) == (3, 0, 0)
    return proto, plan
