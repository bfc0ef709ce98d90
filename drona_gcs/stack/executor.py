"""The plan executor (paper section 3.3) as a sans-I/O periodic machine.

At each local step boundary ``k`` (the edge calls :meth:`PlanExecutor.tick`
at ``epoch + k * tau`` on the drone's clock; the tester when its scheduler
lets the drone step) it takes the cell of the trajectory for step ``k``,
reports it as the setpoint, holds at the last cell, and reports completion
once. The safety argument assumes every drone follows its timed trajectory,
so a trajectory whose start the executor has already passed is refused.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

from drona_gcs.errors import ProtocolViolation
from drona_gcs.motion import Trajectory
from drona_gcs.stack.transitions import lookup
from drona_gcs.workspace import Cell


class ExecutorState(enum.Enum):
    HOLDING = "holding"  #: no trajectory: hold the current cell
    EXECUTING = "executing"  #: following a trajectory


class ExecutorEvent(enum.Enum):
    """What moves an executor from one :class:`ExecutorState` to another (see :data:`TRANSITIONS`)."""

    START = "start"  #: a trajectory to follow (a new one, or another while following one)
    RELOCATE = "relocate"  #: the vehicle found in a cell after it was lost
    COMPLETE = "complete"  #: the trajectory's last step taken


#: Every change of an executor's state: TRANSITIONS[state][event] -> the state it leads to.
TRANSITIONS: dict[ExecutorState, dict[ExecutorEvent, ExecutorState]] = {
    ExecutorState.HOLDING: {ExecutorEvent.START: ExecutorState.EXECUTING,
                            ExecutorEvent.RELOCATE: ExecutorState.HOLDING},
    ExecutorState.EXECUTING: {ExecutorEvent.START: ExecutorState.EXECUTING,
                              ExecutorEvent.RELOCATE: ExecutorState.HOLDING,
                              ExecutorEvent.COMPLETE: ExecutorState.HOLDING},
}


@dataclass(frozen=True)
class Setpoint:
    """Be at ``cell`` during step ``step`` (moving there from the previous cell)."""

    step: int
    cell: Cell
    moving: bool


@dataclass(frozen=True)
class Completed:
    trajectory: Trajectory


ExecutorAction = Setpoint | Completed


@dataclass
class PlanExecutor:
    cell: Cell
    step: int = -1  #: the last step boundary taken
    _state: ExecutorState = field(default=ExecutorState.HOLDING, init=False)  #: read as :attr:`state`
    trajectory: Trajectory | None = None  #: one given to the constructor is started, as :meth:`start` does

    def __post_init__(self) -> None:
        """An executor starts holding: a trajectory to follow from the outset goes through the table too."""
        given, self.trajectory = self.trajectory, None
        if given is not None:
            self.start(given)

    @property
    def state(self) -> ExecutorState:
        """Changed only by :meth:`_enter`, as :data:`TRANSITIONS` allows."""
        return self._state

    def _enter(self, event: ExecutorEvent) -> None:
        """The one place the state changes: to where :data:`TRANSITIONS` says ``event`` leads."""
        self._state = lookup(TRANSITIONS, "executor", self._state, event)

    @property
    def flying(self) -> bool:
        """Whether the trajectory has begun: the drone leaves its first cell after its start step."""
        return self.trajectory is not None and self.step >= self.trajectory.start_step

    def start(self, trajectory: Trajectory) -> None:
        """Follow ``trajectory`` from its start step; it must start after the last boundary taken,
        or be the one followed now until then (a new rest of it, see :meth:`Trajectory.spliced`)."""
        if self._continues(trajectory):
            self.trajectory = trajectory
            return
        if trajectory.start_step <= self.step:
            raise ProtocolViolation(
                f"trajectory starts at step {trajectory.start_step} but the executor is already at step "
                f"{self.step}")
        if trajectory.first != self.cell:
            raise ProtocolViolation(f"trajectory starts at {list(trajectory.first)} but the drone holds "
                                    f"{list(self.cell)}")
        self._enter(ExecutorEvent.START)
        self.trajectory = trajectory

    def _continues(self, trajectory: Trajectory) -> bool:
        flown = self.trajectory
        return (flown is not None and trajectory.start_step <= self.step < trajectory.end_step
                and all(trajectory.at(s) == flown.at(s) for s in range(trajectory.start_step, self.step + 1)))

    def relocate(self, cell: Cell) -> None:
        """The vehicle is in ``cell`` (found there after it was lost): hold it, with no trajectory."""
        self._enter(ExecutorEvent.RELOCATE)
        self.cell, self.trajectory = cell, None

    def tick(self, step: int) -> list[ExecutorAction]:
        """Take step boundary ``step`` (each exactly once, in order)."""
        if step != self.step + 1 and self.step >= 0:
            raise ProtocolViolation(f"step {step} after step {self.step}: boundaries must come in order")
        self.step = step
        if self.state is ExecutorState.HOLDING or self.trajectory is None:
            return [Setpoint(step, self.cell, moving=False)]
        previous, self.cell = self.cell, self.trajectory.at(step)
        actions: list[ExecutorAction] = [Setpoint(step, self.cell, moving=previous != self.cell)]
        if step >= self.trajectory.end_step:
            actions.append(Completed(self.trajectory))
            self._enter(ExecutorEvent.COMPLETE)
            self.trajectory = None
        return actions
