"""A test seam for the coordination protocol: N drones joined by an in-memory network.

Like h11's ``ConnectionPair``, :class:`ProtocolCluster` wires real
:class:`~drona_gcs.stack.protocol.CoordinationProtocol` machines (planning with
a real :class:`~drona_gcs.planner.SafePlanner`) so a test drives the whole
exchange and decides the network's behaviour::

    cluster = ProtocolCluster(workspace, {"a": (0, 0, 0), "b": (4, 4, 0)})
    cluster.start_task("a", (4, 0, 0))
    cluster.start_task("b", (0, 4, 0))
    cluster.deliver_all(random.Random(3))     # or "fifo", "lifo", or deliver(i) by hand
    cluster.started                            # every StartExecuting, with context

Every drone shares one global step ``now`` (perfect synchrony); a test may
move it. A broadcast goes to every drone, the sender included (as in the
paper's P model). The messages travel over the systematic tester's in-memory
network (:class:`drona_gcs.verify.network.Network`: a bag, no delay bound);
``network`` lists what is in flight, oldest first, as ``(sender, to, message)``.
"""

from __future__ import annotations

import random
from collections.abc import Mapping
from dataclasses import dataclass

from drona_gcs.motion import Trajectory
from drona_gcs.planner import SafePlanner
from drona_gcs.stack.messages import HybridClock, Message, Task, task_of
from drona_gcs.stack.protocol import (
    Action,
    Broadcast,
    CoordinationProtocol,
    Event,
    NewTask,
    PlanCompleted,
    Send,
    StartExecuting,
)
from drona_gcs.verify.network import Network
from drona_gcs.workspace import Cell, Workspace


@dataclass(frozen=True)
class Started:
    """A drone's ``StartExecuting`` at step ``step``, and every peer's committed trajectory at that moment."""

    drone: str
    step: int
    action: StartExecuting
    peers_then: Mapping[str, Trajectory]


class ProtocolCluster:
    """Protocol machines for the drones of ``starts``, an in-memory network and a shared clock."""

    def __init__(self, workspace: Workspace, starts: Mapping[str, Cell], *,
                 delta: int | None = None, lead_steps: int | None = None, at_once: bool = False) -> None:
        self.workspace = workspace
        self.planner = SafePlanner(workspace, delta)
        self.delta = self.planner.delta
        self.lead_steps = self.delta + 1 if lead_steps is None else lead_steps  # as DroneStack does
        self.protocols = {d: CoordinationProtocol(d, cell, dict(starts), self.planner.plan, self.lead_steps, self.delta,
                                                  propose_at_once=at_once) for d, cell in starts.items()}
        self.clocks = {d: HybridClock(d) for d in starts}
        self.net: Network[Message] = Network()
        self.started: list[Started] = []
        self.failed: list[tuple[str, Action]] = []  #: every other action (TaskFailed, Threatened, Braked, ...)
        self.now = 0

    # ----------------------------------------------------------- inputs
    def start_task(self, drone: str, goal: Cell, flight_steps: int | None = None) -> Task:
        """Give ``drone`` a new task (its id from the drone's hybrid clock at ``now``)."""
        task = Task(self.clocks[drone].next_id(self.now), goal, flight_steps)
        self._handle(drone, NewTask(task))
        return task

    def deliver(self, index: int = 0) -> tuple[str, str, Message]:
        """Deliver the in-flight message at ``index`` (0: the oldest) and queue what it causes."""
        sent = self.net.take(self.net.inflight[index].seq)
        self.clocks[sent.to].observe(task_of(sent.message))
        self._handle(sent.to, sent.message)
        return (sent.sender, sent.to, sent.message)

    def deliver_all(self, order: str | random.Random = "fifo", limit: int = 1000) -> None:
        """Deliver until nothing is in flight: oldest first ("fifo"), newest first ("lifo"),
        or in an order drawn from a seeded ``random.Random``. More than ``limit`` deliveries fail."""
        for _ in range(limit):
            if not self.net:
                return
            if isinstance(order, random.Random):
                self.deliver(order.randrange(len(self.net)))
            else:
                self.deliver({"fifo": 0, "lifo": -1}[order])
        raise AssertionError(f"still {len(self.net)} message(s) in flight after {limit} deliveries")

    def complete(self, drone: str) -> None:
        """The executor of ``drone`` finished its trajectory."""
        self._handle(drone, PlanCompleted())

    # ---------------------------------------------------------- outputs
    @property
    def network(self) -> list[tuple[str, str, Message]]:
        """What is in flight, oldest first, as ``(sender, to, message)``."""
        return [(m.sender, m.to, m.message) for m in self.net]

    def trajectory(self, drone: str) -> Trajectory:
        """What ``drone`` would answer now: its committed plan, or its location."""
        return self.protocols[drone].current_trajectory(self.now)

    def executed(self) -> dict[str, Trajectory]:
        """The last trajectory each drone started (drones that never started are left out)."""
        return {s.drone: s.action.trajectory for s in self.started}

    # ----------------------------------------------------------- wiring
    def _handle(self, drone: str, event: Event) -> None:
        for action in self.protocols[drone].handle(event, self.now):
            if isinstance(action, Broadcast):
                for to in self.protocols:
                    self.net.post(drone, to, action.message)
            elif isinstance(action, Send):
                self.net.post(drone, action.to, action.message)
            elif isinstance(action, StartExecuting):
                peers = {p: self.trajectory(p) for p in self.protocols if p != drone}
                self.started.append(Started(drone, self.now, action, peers))
            else:
                self.failed.append((drone, action))
