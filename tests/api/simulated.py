"""``SimulatedGateway``: a test double of :class:`api.gateway.FleetGateway`, in memory.

Drones fly one cell per ``step_s`` along a static shortest path (no collision
avoidance: this is not the fleet, only something that behaves like its gateway):
to the pickup, then to the drop-off, reporting ``accepted``, ``started``,
``picked_up`` and ``delivered``, and publishing their state every step. Tests
can lose a drone (:meth:`lose`), cut its link for a while (:meth:`freeze`, :meth:`thaw`), give
its state alarms (``alarms``), make one refuse mail (``refusing``) or take
mail and then never speak of it (``silent``), and inject any report (:meth:`report`).
``drona serve --gateway simulated`` runs it (dev and test mode only).
"""

from __future__ import annotations

import asyncio
import time
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field

from api.errors import AssignRefused
from api.gateway import (
    CommandAck,
    DroneView,
    FleetListener,
    Health,
    MailOrder,
    MailStatusReport,
    Position,
    ReportStatus,
    TaskView,
    TrajectoryView,
    VehicleInfo,
)
from api.validation import MailChecker
from drona_gcs.geo import GeoFrame
from drona_gcs.workspace import Cell, Workspace
from fleet.clock import periodic


@dataclass
class _Drone:
    id: str
    cell: Cell
    queue: deque[MailOrder] = field(default_factory=deque)
    current: MailOrder | None = None
    carrying: bool = False
    path: list[Cell] = field(default_factory=list)
    battery: float = 100.0
    coordination_ms: float | None = None  #: how long its last path took to find


class SimulatedGateway:
    def __init__(self, workspace: Workspace, drones: int | None = None, step_s: float | None = 0.02) -> None:
        """``step_s`` None: the drones move only when the test calls :meth:`tick`."""
        self.ws = workspace
        self.step_s = step_s
        self.frame = GeoFrame(workspace)
        self._checker = MailChecker(workspace)
        starts = dict(workspace.drones) or {}
        if drones is not None and drones != len(starts):
            cells = sorted(workspace.main_region)
            starts = {f"sim{i + 1}": cells[(i * 7919) % len(cells)] for i in range(drones)}
        self._drones = {d: _Drone(d, c) for d, c in starts.items()}
        self._views: dict[str, DroneView] = {}
        self.listener: FleetListener | None = None
        self.step = 0
        self.refusing: dict[str, str] = {}  #: drone -> the reason it refuses every mail
        self.silent: set[str] = set()  #: drones that take mail and then never mention it
        self.assigned: list[tuple[str, str]] = []  #: (drone, mail id) as assigned
        self.cleared: list[tuple[str, str]] = []  #: (drone, mail id) as cleared for pickup
        self.cancelled: list[tuple[str, str]] = []
        #: (drone or None: all, action, by[, about]) as told
        self.commands: list[tuple[str | None, str, str] | tuple[str | None, str, str, str]] = []
        self.commanded: dict[str, str] = {}  #: drone -> the command in force (it takes no mail)
        self.frozen: set[str] = set()  #: drones whose link is down: no state, and they stay put
        self.alarms: dict[str, tuple[str, ...]] = {}  #: drone -> the alarm texts its state carries
        self._views = {d: self._view(sim) for d, sim in self._drones.items()}
        self.opened = asyncio.Event()  #: run() sets it; a test may clear it (the links to the fleet went down)

    # ------------------------------------------------------------ gateway
    def listen(self, listener: FleetListener) -> None:
        self.listener = listener

    def is_open(self) -> bool:
        return self.opened.is_set()

    async def run(self) -> None:
        self.opened.set()
        self.publish()
        if self.step_s is None:
            await asyncio.Event().wait()  # the test steps the drones
        else:
            async for _ in periodic(self.step_s):
                self.tick()

    async def assign(self, drone: str, mail: MailOrder) -> None:
        sim = self._drones.get(drone)
        if sim is None or drone not in self._views:
            raise AssignRefused(drone, mail.id, "unreachable: no such live drone")
        if drone in self.refusing:
            raise AssignRefused(drone, mail.id, self.refusing[drone])
        if drone in self.commanded:
            raise AssignRefused(drone, mail.id, f"the operator's {self.commanded[drone]} is in force")
        self.assigned.append((drone, mail.id))
        if drone in self.silent:
            return
        sim.queue.append(mail)
        self._report(mail.id, drone, "accepted")

    async def cancel(self, drone: str, mail_id: str) -> None:
        self.cancelled.append((drone, mail_id))
        sim = self._drones.get(drone)
        if sim is None:
            return
        sim.queue = deque(m for m in sim.queue if m.id != mail_id)
        if sim.current is not None and sim.current.id == mail_id and not sim.carrying:
            sim.current, sim.path = None, []

    async def clear(self, drone: str, mail_id: str) -> None:
        self.cleared.append((drone, mail_id))

    async def command(self, drone: str | None, action: str, by: str, about: str | None = None) -> list[CommandAck]:
        """Live drones that are not silent answer; a recalled or landed one hands back its queue."""
        self.commands.append((drone, action, by) if about is None else (drone, action, by, about))
        acks = []
        for name in [drone] if drone is not None else sorted(self._views):
            sim = self._drones.get(name)
            if sim is None or name not in self._views or name in self.silent:
                continue
            if action == "release":
                acks.append(CommandAck(name, True))
                continue
            if action in ("recall", "land"):
                self._hand_back(sim, f"{action} by {by}")
            if action == "resume":
                self.commanded.pop(name, None)
            else:
                self.commanded[name] = action
            acks.append(CommandAck(name, True))
        return acks

    def _hand_back(self, sim: _Drone, reason: str) -> None:
        """Every mail not on board, as a real drone hands it back."""
        waiting = [*sim.queue, *([sim.current] if sim.current is not None and not sim.carrying else [])]
        for mail in waiting:
            self._report(mail.id, sim.id, "rejected", reason)
        sim.queue.clear()
        if sim.current is not None and not sim.carrying:
            sim.current, sim.path = None, []

    def drones(self) -> Mapping[str, DroneView]:
        return self._views

    # -------------------------------------------------------- test hooks
    def lose(self, drone: str) -> None:
        """The drone goes silent: the gateway says it is lost, and it flies no more."""
        self._views.pop(drone, None)
        self._drones.pop(drone, None)
        if self.listener is not None:
            self.listener.on_drone_lost(drone)

    def freeze(self, drone: str) -> None:
        """The drone's link goes down: it is announced lost, publishes nothing and stays put until thawed."""
        self.frozen.add(drone)
        self._views.pop(drone, None)
        if self.listener is not None:
            self.listener.on_drone_lost(drone)

    def thaw(self, drone: str) -> None:
        """The link is back: the drone publishes its state again from the next step."""
        self.frozen.discard(drone)

    def restart(self, drone: str) -> None:
        """The drone's agent restarts where its vehicle is, knowing none of its mail, and publishes again."""
        sim = self._drones[drone]
        sim.queue.clear()
        sim.current, sim.carrying, sim.path = None, False, []
        self.thaw(drone)

    def report(self, report: MailStatusReport) -> None:
        if self.listener is not None:
            self.listener.on_mail_status(report)

    def tick(self) -> None:
        """One step: every drone moves a cell and publishes its state."""
        self.step += 1
        for sim in list(self._drones.values()):
            if sim.id not in self.frozen:
                self._advance(sim)
        self.publish()

    def publish(self) -> None:
        for sim in [s for s in self._drones.values() if s.id not in self.frozen]:
            view = self._view(sim)
            self._views[sim.id] = view
            if self.listener is not None:
                self.listener.on_drone_state(view)

    # ------------------------------------------------------------ flying
    def _advance(self, sim: _Drone) -> None:
        if sim.current is None and sim.queue:
            sim.current = sim.queue.popleft()
            sim.path = self._path(sim.cell, sim.current.pickup, sim)
            self._report(sim.current.id, sim.id, "started")
        if sim.path:
            sim.cell = sim.path.pop(0)
            sim.battery = max(30.0, sim.battery - 0.2)
        else:
            sim.battery = min(100.0, sim.battery + 1.0)
        if sim.current is None or sim.path:
            return
        if not sim.carrying:
            sim.carrying = True
            sim.path = self._path(sim.cell, sim.current.dropoff, sim)
            self._report(sim.current.id, sim.id, "picked_up")
        else:
            self._report(sim.current.id, sim.id, "delivered")
            sim.current, sim.carrying = None, False

    def _path(self, start: Cell, goal: Cell, sim: _Drone | None = None) -> list[Cell]:
        """The cells after ``start`` on a shortest static path to ``goal`` (timed: the drone's coordination)."""
        began = time.perf_counter()
        path = self._checker.path(start, goal)[1:]
        if sim is not None:
            sim.coordination_ms = round((time.perf_counter() - began) * 1000, 3)
        return path

    def _view(self, sim: _Drone) -> DroneView:
        p = self.frame.cell_to_global(sim.cell)
        current = sim.current
        task = None
        if current is not None:
            goal = current.dropoff if sim.carrying else current.pickup
            task = TaskView(goal, "to_dropoff" if sim.carrying else "to_pickup", current.id)
        trajectory = TrajectoryView(self.step, (sim.cell, *sim.path)) if sim.path else None
        phase = task.purpose if task else "idle"
        alarms = self.alarms.get(sim.id, ())
        flying = bool(sim.path)
        vehicle = VehicleInfo("ready", mode="GUIDED", armed=flying, landed="in_air" if flying else "on_ground",
                              height_m=p.alt_m - self.frame.origin.alt_m if flying else 0.0, gps_fix=3, satellites=14,
                              battery_v=round(13.2 + 3.6 * sim.battery / 100, 2))
        return DroneView(sim.id, sim.cell, Position(p.lat, p.lon, p.alt_m), round(sim.battery, 1), "GUIDED", phase,
                         task, trajectory, tuple(m.id for m in sim.queue),
                         current.id if current is not None and sim.carrying else None,
                         Health(not alarms, alarms), self.step, vehicle=vehicle, coordination_ms=sim.coordination_ms)

    def _report(self, mail_id: str, drone: str, status: ReportStatus, reason: str = "") -> None:
        self.report(MailStatusReport(mail_id, drone, status, reason, self.step, time.time()))

