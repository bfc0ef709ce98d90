"""Seeded bugs: small subclasses of the production machines, planted by the tester.

The code that flies carries no test hooks. :func:`plant` swaps the class of a
drone's protocol or mail planner for one of these, which differ from the real
one in a single rule; each must be caught by a monitor. (Swapping ``__class__``
keeps the machine's fields: none of the subclasses adds any.)
"""

from __future__ import annotations

from collections.abc import Collection

from drona_gcs.motion import Trajectory
from drona_gcs.stack.drone import SERVICE_LOST, DroneStack
from drona_gcs.stack.executor import ExecutorAction, ExecutorState, PlanExecutor
from drona_gcs.stack.mail import Budget, MailAction, MailPlanner, MailRequest
from drona_gcs.stack.messages import ReqForCurrentTraj, TaskId
from drona_gcs.stack.protocol import Action, CoordinationProtocol, Event, PeerLost, State

#: Bugs that ``--seed-bug`` can plant, and what each does.
SEEDED_BUGS = {
    "stale-trajectory": "a drone keeps its peers' answers from its previous task and plans with them",
    "tie-break-reversed": "a request ranks above mine when its task id is higher, not lower (and a round "
                          "never asks again)",
    "answer-while-coordinating": "a coordinating drone answers every request with its location",
    "no-battery-check": "the task planner starts legs without checking the battery",
    "skip-delta": "the planner ignores the clock-skew window (plans with Delta 0)",
    "executor-early": "the executor flies each cell of its plan one step early",
    "fly-unheld": "a drone flies a plan at once, held by its peers or not, with a majority of the fleet or not",
    "pickup-uncleared": "a drone takes mail on board without the service's clearance, and keeps it when "
                        "out of touch with the service",
    "skew-blind": "a drone reads the steps of a clock found off as its own, and takes no notice of where that "
                  "drone says its vehicle may be: the plan it flies goes on through that drone's cells, and with "
                  "its own clock off it flies its plan to the end",
}


class StaleTrajectory(CoordinationProtocol):
    def _forget_answers(self) -> None:
        pass  # last round's answers stay in Psi


class TieBreakReversed(CoordinationProtocol):
    def _outranks(self, theirs: TaskId, mine: TaskId) -> bool:
        return theirs > mine

    def _ask_again(self, now: int) -> list[Action]:
        return []  # asked again, the drones that wait for each other for good would be woken


class AnswerWhileCoordinating(CoordinationProtocol):
    def handle(self, event: Event, now: int) -> list[Action]:
        if self.state is State.COORDINATING and isinstance(event, ReqForCurrentTraj):
            return self._answer(event, now) if self._current(event) else []
        return super().handle(event, now)


class FlyUnheld(CoordinationProtocol):
    def in_quorum(self) -> bool:
        return True

    def _go_if_held(self, now: int) -> list[Action]:
        self.acked = set(self.members)
        return super()._go_if_held(now)


class SkewBlind(CoordinationProtocol):
    def _timeless(self) -> list[Trajectory]:
        return []

    def handle(self, event: Event, now: int) -> list[Action]:
        return [] if isinstance(event, PeerLost) else super().handle(event, now)


class ExecutorEarly(PlanExecutor):
    def tick(self, step: int) -> list[ExecutorAction]:
        actions = super().tick(step)
        if self.state is ExecutorState.EXECUTING and self.trajectory is not None:
            self.cell = self.trajectory.at(step + 1)
        return actions


class NoBatteryCheck(MailPlanner):
    def _budget(self, now: int, level: float) -> Budget:
        return Budget(now, self.battery.steps_affordable(level), unchecked=True)


class PickupUncleared(MailPlanner):
    def _may_pick_up(self, request: MailRequest) -> bool:
        return True

    def release(self, reason: str, keep_cleared: bool = False) -> list[MailAction]:
        return [] if reason == SERVICE_LOST else super().release(reason, keep_cleared)


_PROTOCOLS: dict[str, type[CoordinationProtocol]] = {
    "stale-trajectory": StaleTrajectory, "tie-break-reversed": TieBreakReversed,
    "answer-while-coordinating": AnswerWhileCoordinating, "fly-unheld": FlyUnheld, "skew-blind": SkewBlind,
}
_MAIL_PLANNERS: dict[str, type[MailPlanner]] = {"no-battery-check": NoBatteryCheck,
                                                "pickup-uncleared": PickupUncleared}
_EXECUTORS: dict[str, type[PlanExecutor]] = {"executor-early": ExecutorEarly}


#: Bugs of a round's requests and answers: planted in a drone that asks first, for a round is otherwise only
#: what a direct proposal not held falls back to.
_ROUND_BUGS = frozenset({"stale-trajectory", "tie-break-reversed", "answer-while-coordinating"})


def plant(stack: DroneStack, bugs: Collection[str]) -> None:
    """Give ``stack`` the seeded ``bugs`` (at most one per machine; skip-delta is the planner's)."""
    for bug in bugs:
        if bug in _PROTOCOLS:
            stack.protocol.__class__ = _PROTOCOLS[bug]
            stack.protocol.propose_at_once = bug not in _ROUND_BUGS
        elif bug in _MAIL_PLANNERS:
            stack.mail.__class__ = _MAIL_PLANNERS[bug]
        elif bug in _EXECUTORS:
            stack.executor.__class__ = _EXECUTORS[bug]


def planner_delta(delta: int, bugs: Collection[str]) -> int:
    """The planner's Delta: 0 with skip-delta."""
    return 0 if "skip-delta" in bugs else delta
