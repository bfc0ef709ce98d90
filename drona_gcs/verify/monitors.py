"""The tester's monitors: the properties the paper's model checker verified.

(a) every Psi a planner used is consistent: each peer's entry equals what that
    peer is committed to when the plan starts (its plan, or its location);
(b) the cells the executors actually occupy pass the safety checker under Delta;
(c) each drone starts its mail in priority order (most urgent, then oldest);
(d) every request is delivered within a bound once the environment stops sending;
(e) no battery drops below the safe threshold.

A violation raises :class:`Violation`, which ends the schedule.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from drona_gcs.errors import DronaError
from drona_gcs.motion import Trajectory
from drona_gcs.safety import check_pair
from drona_gcs.stack.mail import MailDelivered, MailStarted
from drona_gcs.stack.protocol import StartExecuting
from drona_gcs.workspace import Cell

if TYPE_CHECKING:
    from drona_gcs.verify.world import World, WorldConfig


class Violation(DronaError):
    """A monitor saw a property fail; ``monitor`` names which: a .. e."""

    def __init__(self, monitor: str, message: str) -> None:
        self.monitor = monitor
        super().__init__(f"({monitor}) {message}")


@dataclass
class Monitors:
    config: WorldConfig
    delivered: set[str] = field(default_factory=set)
    history: dict[str, list[Cell]] = field(default_factory=dict)
    judged: int = -1  #: the last step (b) has judged for every pair

    def action(self, drone: str, action: object, world: World) -> None:
        if isinstance(action, StartExecuting):
            self._consistent(drone, action, world)
        elif isinstance(action, MailStarted):
            self._in_order(drone, action)
        elif isinstance(action, MailDelivered):
            self.delivered.add(action.request.id)

    # (a)
    def _consistent(self, drone: str, action: StartExecuting, world: World) -> None:
        members = world.stacks[drone].protocol.members
        since = action.trajectory.start_step - self.config.delta - 1
        for peer, used in action.psi.items():
            if peer in members and not same_future(used, world.commitment(peer), since, self.config.delta):
                raise Violation("a", f"{drone} planned task {action.task.id} with a stale trajectory of "
                                     f"{peer}: used {_cells(used)}, but {peer} is committed to "
                                     f"{_cells(world.commitment(peer))}")

    # (b)
    def position(self, drone: str, step: int, cell: Cell, steps: dict[str, int]) -> None:
        """Record where ``drone`` is at ``step``; judge every step whose whole window has been flown."""
        self.history.setdefault(drone, []).append(cell)
        delta = self.config.delta
        while self.judged < min(steps.values()) - delta - 1:
            self.judged += 1
            self._judge(self.judged)

    def _judge(self, t: int) -> None:
        flown = {d: Trajectory(0, tuple(cells)) for d, cells in self.history.items()}
        drones = sorted(flown)
        for i, a in enumerate(drones):
            for b in drones[i + 1:]:
                for v in check_pair(flown[a], flown[b], self.config.delta, b, from_step=t, until=t):
                    raise Violation("b", f"{a} and {b}: {v}")

    # (c)
    def _in_order(self, drone: str, started: MailStarted) -> None:
        ahead = [r for r in started.waiting if r.rank < started.request.rank]
        if ahead:
            raise Violation("c", f"{drone} started mail {started.request.id} (priority "
                                 f"{started.request.priority}) before {ahead[0].id} (priority {ahead[0].priority})")

    # (d)
    def liveness(self, steps_since_last_request: int) -> None:
        if steps_since_last_request > self.config.liveness_steps and len(self.delivered) < len(self.config.requests):
            missing = sorted({r.id for r in self.config.requests} - self.delivered)
            raise Violation("d", f"mail {missing} not delivered {self.config.liveness_steps} steps after the "
                                 "last request arrived")

    # (e)
    def battery(self, drone: str, step: int, level: float) -> None:
        if level < self.config.battery.safe_threshold:
            raise Violation("e", f"{drone}'s battery fell to {level:.1f}% at step {step}, below the safe "
                                 f"threshold {self.config.battery.safe_threshold}%")


def same_future(a: Trajectory, b: Trajectory, since: int, delta: int) -> bool:
    """Whether two trajectories put the drone in the same cells at every step from ``since`` on."""
    horizon = max(a.end_step, b.end_step, since) + delta + 1
    return all(a.at(t) == b.at(t) for t in range(since, horizon + 1))


def _cells(traj: Trajectory) -> str:
    cells = " ".join(f"{c[0]}{c[1]}" for c in traj.cells[:10])
    return f"step {traj.start_step}: {cells}{' ...' if len(traj.cells) > 10 else ''}"
