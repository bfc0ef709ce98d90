"""The protocol's, the battery monitor's and the executor's states change only as their one table says."""

from __future__ import annotations

import pytest

from drona_gcs.errors import ProtocolViolation
from drona_gcs.motion import Trajectory
from drona_gcs.planner import SafePlanner
from drona_gcs.stack.battery import TRANSITIONS as BATTERY
from drona_gcs.stack.battery import BatteryLow, BatteryMonitor, BatteryRecharged, BatteryState
from drona_gcs.stack.executor import TRANSITIONS as EXECUTOR
from drona_gcs.stack.executor import Completed, ExecutorEvent, ExecutorState, PlanExecutor, Setpoint
from drona_gcs.stack.messages import Task, TaskId
from drona_gcs.stack.protocol import TRANSITIONS, CoordinationProtocol, Move, NewTask, PlanCompleted, Relocated, State
from drona_gcs.workspace import Cell, Workspace

OPEN = Workspace.build(size=(5, 5, 1))
A, B = (0, 0, 0), (4, 4, 0)


def protocol(peers: dict[str, Cell] | None = None) -> CoordinationProtocol:
    """Drone a, with peer b unless told otherwise."""
    peers = {"a": A, "b": B} if peers is None else peers
    return CoordinationProtocol("a", A, peers, SafePlanner(OPEN, 0).plan, 2)


# ================================================================ the protocol
def test_every_state_has_a_row_and_every_target_is_a_state() -> None:
    assert set(TRANSITIONS) == set(State)
    for row in TRANSITIONS.values():
        for move in row.values():
            assert callable(move.handler)
            assert all(isinstance(target, State) for target in move.targets)


def test_an_event_a_state_does_not_take_is_refused_by_name() -> None:
    proto = protocol()
    with pytest.raises(ProtocolViolation, match="drone 'a': 'PlanCompleted' in state WaitForTaskRequest cannot lead "
                                                "anywhere"):
        proto.handle(PlanCompleted(), 0)
    assert proto.state is State.WAIT_FOR_TASK


def test_a_handler_cannot_lead_where_the_table_does_not_allow(monkeypatch: pytest.MonkeyPatch) -> None:
    """Relocated rests the drone; with a row that does not allow it, the change is refused, naming the event
    and the state, and nothing changes."""
    row = TRANSITIONS[State.WAIT_FOR_TASK]
    monkeypatch.setitem(row, Relocated, Move(row[Relocated].handler, frozenset({State.EXECUTING})))
    proto = protocol()
    with pytest.raises(ProtocolViolation, match="drone 'a': 'Relocated' in state WaitForTaskRequest cannot lead to "
                                                "WaitForTaskRequest"):
        proto.handle(Relocated((1, 0, 0)), 0)
    assert proto.state is State.WAIT_FOR_TASK and proto.location == A
    assert proto._taking is None  # the next event is checked against its own entry


def test_every_state_on_the_way_is_checked(monkeypatch: pytest.MonkeyPatch) -> None:
    """A drone alone plans its task at once and flies it: the row of NewTask must allow each state it passes."""
    row = TRANSITIONS[State.WAIT_FOR_TASK]
    monkeypatch.setitem(row, NewTask, Move(row[NewTask].handler, frozenset({State.COORDINATING, State.EXECUTING})))
    with pytest.raises(ProtocolViolation, match="'NewTask' in state WaitForTaskRequest cannot lead to ConfirmPlan"):
        protocol({"a": A}).handle(NewTask(Task(TaskId(1, "a", 1), (4, 0, 0))), 0)


def test_the_table_lets_a_drone_alone_fly_its_task() -> None:
    proto = protocol({"a": A})
    proto.handle(NewTask(Task(TaskId(1, "a", 1), (4, 0, 0))), 0)
    assert proto.state is State.EXECUTING


def test_no_state_changes_outside_an_event() -> None:
    proto = protocol()
    with pytest.raises(ProtocolViolation, match="a change outside any event in state WaitForTaskRequest cannot lead to "
                                                "WaitForPlanCompletion"):
        proto._enter(State.EXECUTING)
    assert proto.state is State.WAIT_FOR_TASK


def test_the_protocol_state_is_read_only() -> None:
    with pytest.raises(AttributeError):
        protocol().state = State.EXECUTING  # type: ignore[misc]


# ======================================================== the battery monitor
def test_every_battery_state_has_a_row_and_every_target_is_a_state() -> None:
    assert set(BATTERY) == set(BatteryState)
    assert all(isinstance(target, BatteryState) for row in BATTERY.values() for target in row.values())


def test_a_battery_event_its_state_does_not_take_names_both() -> None:
    monitor = BatteryMonitor(low=40, recharged=95)
    with pytest.raises(ProtocolViolation, match="battery monitor: 'BatteryRecharged' in state ok cannot lead anywhere"):
        monitor._report(BatteryRecharged(99))
    assert monitor.state is BatteryState.OK
    low = BatteryMonitor(low=40, recharged=95)
    assert low.reading(30) == [BatteryLow(30)]
    with pytest.raises(ProtocolViolation, match="battery monitor: 'BatteryLow' in state low cannot lead anywhere"):
        low._report(BatteryLow(10))
    assert low.state is BatteryState.LOW


def test_the_battery_state_is_read_only() -> None:
    with pytest.raises(AttributeError):
        BatteryMonitor().state = BatteryState.LOW  # type: ignore[misc]


# =============================================================== the executor
def test_every_executor_state_has_a_row_and_every_target_is_a_state() -> None:
    assert set(EXECUTOR) == set(ExecutorState)
    assert all(isinstance(target, ExecutorState) for row in EXECUTOR.values() for target in row.values())


def test_an_executor_event_its_state_does_not_take_names_both() -> None:
    executor = PlanExecutor(A)
    with pytest.raises(ProtocolViolation, match="executor: 'complete' in state holding cannot lead anywhere"):
        executor._enter(ExecutorEvent.COMPLETE)
    assert executor.state is ExecutorState.HOLDING


def test_the_executor_state_is_read_only() -> None:
    with pytest.raises(AttributeError):
        PlanExecutor(A).state = ExecutorState.EXECUTING  # type: ignore[misc]


def test_an_executor_given_a_trajectory_starts_it_through_the_table() -> None:
    flight = Trajectory(0, (A, (1, 0, 0)))
    executor = PlanExecutor(A, trajectory=flight)
    started = (executor.state, executor.trajectory)
    assert executor.tick(0) == [Setpoint(0, A, moving=False)]
    assert executor.tick(1) == [Setpoint(1, (1, 0, 0), moving=True), Completed(flight)]
    assert [started, (executor.state, executor.trajectory)] == [(ExecutorState.EXECUTING, flight),
                                                                (ExecutorState.HOLDING, None)]


def test_an_executor_refuses_a_trajectory_it_cannot_start() -> None:
    with pytest.raises(ProtocolViolation, match="the drone holds"):
        PlanExecutor(B, trajectory=Trajectory(0, (A, (1, 0, 0))))
    with pytest.raises(ProtocolViolation, match="already at step 3"):
        PlanExecutor(A, step=3, trajectory=Trajectory(2, (A, (1, 0, 0))))
