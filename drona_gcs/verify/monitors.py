"""The tester's monitors: the properties the paper's model checker verified, and ours.

Each states its property in its own simple code from what the drones did (their
actions) and what the environment did (the mail it gave, the steps it took), and
shares nothing with the code it judges: no production ranking, no protocol query.

(a) every plan avoided every other drone, and each with what that drone was
    committed to when the plan starts: the trajectory it last started executing
    (beyond its end, its last cell), or its start cell before any;
(b) the cells the executors actually occupy pass the safety checker under Delta;
(c) each drone starts its mail in priority order: never one while a more urgent
    one (higher priority, or equal and sent by the environment earlier) waits, unstarted;
(d) every request is delivered within a bound once the environment stops sending (but one
    cancelled, lost on board a vehicle that came down, or whose pickup or drop-off such a
    vehicle now rests on for good);
(e) no battery drops below the safe threshold;
(f) a drone carrying mail flies only to its drop-off, or to a charger.

A violation raises :class:`Violation`, which ends the schedule.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from drona_gcs.errors import DronaError
from drona_gcs.motion import Trajectory
from drona_gcs.safety import check_pair
from drona_gcs.stack.mail import MailDelivered, MailLost, MailPickedUp, MailRejected, MailRequest, MailStarted
from drona_gcs.stack.protocol import StartExecuting
from drona_gcs.workspace import Cell

if TYPE_CHECKING:
    from drona_gcs.verify.world import WorldConfig


class Violation(DronaError):
    """A monitor saw a property fail; ``monitor`` names which: a .. f."""

    def __init__(self, monitor: str, message: str) -> None:
        self.monitor = monitor
        super().__init__(f"({monitor}) {message}")


@dataclass
class Monitors:
    """Every container holds immutable values only, so that a one-level copy is a clone."""

    config: WorldConfig
    delivered: set[str] = field(default_factory=set)
    settled: set[str] = field(default_factory=set)  #: delivered, cancelled, or lost with its vehicle
    history: dict[str, list[Cell]] = field(default_factory=dict)
    judged: int = -1  #: the last step (b) has judged for every pair
    committed: dict[str, Trajectory] = field(default_factory=dict)  #: (a) each drone's last started plan
    waiting: dict[str, tuple[tuple[int, MailRequest], ...]] = field(default_factory=dict)  #: (c) given, unstarted
    carrying: dict[str, MailRequest] = field(default_factory=dict)  #: (f) mail on board, per drone

    def __post_init__(self) -> None:
        for drone, start in zip(self.config.drones, self.config.starts, strict=True):
            self.committed[drone] = Trajectory(0, (start,))

    def key(self) -> Hashable:
        """What of the monitors' own state decides future verdicts (for the DFS's state cache)."""
        return (tuple(sorted((d, t.start_step, t.cells) for d, t in self.committed.items())),
                tuple(sorted((d, tuple(r.id for _, r in w)) for d, w in self.waiting.items())),
                tuple(sorted((d, r.id) for d, r in self.carrying.items())))

    def given_mail(self, drone: str, request: MailRequest) -> None:
        """The environment gave ``request`` to ``drone`` (again, if another handed it back)."""
        sent = next(i for i, r in enumerate(self.config.requests) if r.id == request.id)
        self.waiting[drone] = (*self.waiting.get(drone, ()), (sent, request))

    def action(self, drone: str, action: object) -> None:
        if isinstance(action, StartExecuting):
            self._consistent(drone, action)
            self._carried_to_its_dropoff(drone, action)
            self.committed[drone] = action.trajectory
        elif isinstance(action, MailStarted):
            self._in_order(drone, action.request)
        elif isinstance(action, MailPickedUp):
            self.carrying[drone] = action.request
        elif isinstance(action, MailDelivered):
            self.delivered.add(action.request.id)
            self.settled.add(action.request.id)
            self.carrying.pop(drone, None)
        elif isinstance(action, MailLost):
            self.settled.add(action.request.id)
            self._forget(drone, action.request)
        elif isinstance(action, MailRejected):
            self._forget(drone, action.request)

    def cancelled(self, drone: str, request: MailRequest) -> None:
        """The environment took ``request`` back from ``drone``'s queue."""
        self.settled.add(request.id)
        self._forget(drone, request)

    # (a)
    def _consistent(self, drone: str, action: StartExecuting) -> None:
        since = action.trajectory.start_step - self.config.delta - 1
        for peer in self.config.drones:
            if peer == drone:
                continue
            used = action.psi.get(peer)
            if used is None:
                raise Violation("a", f"{drone} planned task {action.task.id} without {peer}")
            if not same_future(used, self.committed[peer], since):
                raise Violation("a", f"{drone} planned task {action.task.id} with a stale trajectory of "
                                     f"{peer}: used {_cells(used)}, but {peer} is committed to "
                                     f"{_cells(self.committed[peer])}")

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
    def _in_order(self, drone: str, started: MailRequest) -> None:
        queue = self.waiting.get(drone, ())
        mine = next((order for order, r in queue if r.id == started.id), None)
        if mine is None:
            return  # started before: a leg flown again is no new start
        before = [r for order, r in queue if r.priority > started.priority
                  or (r.priority == started.priority and order < mine)]
        if before:
            raise Violation("c", f"{drone} started mail {started.id} (priority {started.priority}) before "
                                 f"{before[0].id} (priority {before[0].priority})")
        self._forget(drone, started)

    def _forget(self, drone: str, request: MailRequest) -> None:
        self.waiting[drone] = tuple((o, r) for o, r in self.waiting.get(drone, ()) if r.id != request.id)
        if drone in self.carrying and self.carrying[drone].id == request.id:
            del self.carrying[drone]

    # (d)
    def liveness(self, steps_since_last_request: int, wait_for: Callable[[], str] = lambda: "",
                 blocked: frozenset[Cell] = frozenset()) -> None:
        """``wait_for`` describes who waits for whom, for the counterexample; ``blocked``: the cells
        vehicles that came down rest on for good."""
        if steps_since_last_request <= self.config.liveness_steps:
            return
        carried = {r.id for r in self.carrying.values()}
        missing = sorted(r.id for r in self.config.requests if r.id not in self.settled
                         and r.dropoff not in blocked and (r.id in carried or r.pickup not in blocked))
        if missing:
            raise Violation("d", f"mail {missing} not delivered {self.config.liveness_steps} steps after the "
                                 f"last request arrived. Wait-for: {wait_for()}")

    # (e)
    def battery(self, drone: str, step: int, level: float) -> None:
        if level < self.config.battery.safe_threshold:
            raise Violation("e", f"{drone}'s battery fell to {level:.1f}% at step {step}, below the safe "
                                 f"threshold {self.config.battery.safe_threshold}%")

    # (f)
    def _carried_to_its_dropoff(self, drone: str, action: StartExecuting) -> None:
        mail = self.carrying.get(drone)
        goal = action.trajectory.cells[-1]
        if mail is not None and goal != mail.dropoff and goal not in self.config.workspace.charging_stations:
            raise Violation("f", f"{drone} carries mail {mail.id} (drop-off {list(mail.dropoff)}) but flies to "
                                 f"{list(goal)}, neither its drop-off nor a charger")


def same_future(a: Trajectory, b: Trajectory, since: int) -> bool:
    """Whether two trajectories put the drone in the same cell at every step from ``since`` on (each
    at its first cell before it starts, at its last after it ends)."""
    horizon = max(a.end_step, b.end_step, since)
    return all(_at(a, t) == _at(b, t) for t in range(since, horizon + 1))


def _at(traj: Trajectory, step: int) -> Cell:
    k = min(max(step - traj.start_step, 0), len(traj.cells) - 1)
    return traj.cells[k]


def _cells(traj: Trajectory) -> str:
    cells = " ".join(f"[{c[0]},{c[1]},{c[2]}]" for c in traj.cells[:10])
    return f"step {traj.start_step}: {cells}{' ...' if len(traj.cells) > 10 else ''}"
