"""The fleet gateway: the only way the service reaches the drones.

The service never touches the network itself. A gateway (Zenoh in production:
``fleet.transport``; an in-memory simulation in the tests) carries mail orders
to the agents and brings back what they say, as the frozen dataclasses below.

Threading: every method is called on the service's event loop, and the gateway
calls the listener's methods **on that loop too** (a gateway fed by another
thread hands samples over with ``loop.call_soon_threadsafe``). Listener methods
return at once; the service does the work in its own tasks.

Life: the service calls :meth:`FleetGateway.listen` once, then runs
:meth:`FleetGateway.run` in its task group for as long as it serves; run
returns only if the gateway is finished (it is normally cancelled at shutdown,
and closes its links then).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal, Protocol

from drona_gcs.workspace import Cell

#: What an agent says about a mail it was given.
ReportStatus = Literal["accepted", "started", "picked_up", "delivered", "rejected", "failed"]
REPORT_STATUSES: tuple[ReportStatus, ...] = ("accepted", "started", "picked_up", "delivered", "rejected", "failed")


@dataclass(frozen=True)
class MailOrder:
    """A mail handed to a drone: go to ``pickup``, carry it to ``dropoff``. 9 is the most urgent."""

    id: str
    pickup: Cell
    dropoff: Cell
    priority: int
    note: str = ""


@dataclass(frozen=True)
class Position:
    """WGS84 latitude and longitude (degrees) and altitude AMSL (m)."""

    lat: float
    lon: float
    alt_m: float


@dataclass(frozen=True)
class TaskView:
    """The motion task a drone is on: its goal, why (a mail planner phase) and for which mail."""

    goal: Cell
    purpose: str  #: drona_gcs.stack.mail.Phase value: to_pickup, to_dropoff, to_charger, to_parking
    mail_id: str | None = None


@dataclass(frozen=True)
class TrajectoryView:
    """The planned trajectory: ``cells[k]`` is where the drone is at step ``start_step + k``."""

    start_step: int
    cells: tuple[Cell, ...]


@dataclass(frozen=True)
class Health:
    ok: bool
    alarms: tuple[str, ...] = ()


@dataclass(frozen=True)
class VehicleInfo:
    """What the vehicle itself last reported (None where it reports nothing)."""

    status: str  #: ready, waiting_for_position, not_ready, lost
    reason: str = ""  #: what keeps it from flying plans
    mode: str | None = None  #: the autopilot's flight mode (GUIDED, LAND, ...)
    armed: bool = False
    landed: str = "undefined"  #: MAV_LANDED_STATE, lower case: on_ground, takeoff, in_air, landing
    height_m: float | None = None  #: above home
    gps_fix: int = 0  #: GPS_FIX_TYPE: 3 is a 3D fix
    satellites: int = 0
    battery_v: float | None = None


@dataclass(frozen=True)
class DroneView:
    """The latest state of one drone, as its agent publishes it."""

    id: str
    cell: Cell
    position: Position
    battery_pct: float
    mode: str  #: the autopilot's flight mode
    phase: str  #: drona_gcs.stack.mail.Phase value (idle, to_pickup, ...)
    task: TaskView | None
    trajectory: TrajectoryView | None
    queue: tuple[str, ...]  #: ids of the mails waiting on board the drone's planner
    carrying: str | None  #: id of the mail on board
    health: Health
    step: int  #: the drone's step counter
    alive: bool = True  #: False: the drone left (its last known state, kept by api.watch)
    vehicle: VehicleInfo | None = None  #: None: the agent reports no vehicle (simulated, or an old agent)
    coordination_ms: float | None = None  #: the last plan's coordination latency (task arrival to plan scheduled)
    seen_at: float = 0.0  #: the service's wall clock when this state came (Unix seconds; 0: not stamped)

    def mentions(self, mail_id: str) -> bool:
        """Whether the drone shows ``mail_id`` as queued, on board or the goal of its task."""
        return (mail_id in self.queue or self.carrying == mail_id
                or (self.task is not None and self.task.mail_id == mail_id))


@dataclass(frozen=True)
class MailStatusReport:
    """An agent's word about a mail; ``at`` is the agent's wall clock (Unix seconds)."""

    mail_id: str
    drone: str
    status: ReportStatus
    reason: str = ""
    step: int = 0
    at: float = 0.0


class FleetListener(Protocol):
    """What the service gives the gateway to push fleet events in (called on the event loop)."""

    def on_drone_state(self, view: DroneView) -> None: ...

    def on_drone_lost(self, drone: str) -> None: ...

    def on_mail_status(self, report: MailStatusReport) -> None: ...


@dataclass(frozen=True)
class CommandAck:
    """A drone's answer to an operator's command (api.commands)."""

    drone: str
    accepted: bool
    reason: str = ""


class FleetGateway(Protocol):
    def listen(self, listener: FleetListener) -> None:
        """Register the service's listener (called once, before :meth:`run`)."""
        ...

    async def run(self) -> None:
        """Keep the links up and push events to the listener until cancelled."""
        ...

    def is_open(self) -> bool:
        """Whether the service is linked to the fleet (over Zenoh: its session has a link to a peer or a
        router), so that a mail taken can reach a drone."""
        ...

    async def assign(self, drone: str, mail: MailOrder) -> None:
        """Hand ``mail`` to ``drone``; raises :class:`api.errors.AssignRefused` (with the reason) if the
        drone refused it or could not be reached in time. Returns once the drone has it."""
        ...

    async def cancel(self, drone: str, mail_id: str) -> None:
        """Ask ``drone`` to drop ``mail_id``: best effort, never raises for an unreachable drone."""
        ...

    async def clear(self, drone: str, mail_id: str) -> None:
        """Tell ``drone`` it may take ``mail_id`` on board: best effort, never raises for an unreachable
        drone (the service holds the mail as that drone's from before it asks)."""
        ...

    async def command(self, drone: str | None, action: str, by: str, about: str | None = None) -> list[CommandAck]:
        """Tell ``drone`` (None: every live drone) an operator's ``action`` (pause, resume, recall, land,
        release ``about`` a drone gone) asked by ``by``; the answers that came in time (never raises for
        an unreachable drone)."""
        ...

    def drones(self) -> Mapping[str, DroneView]:
        """The latest view of every live drone, by id."""
        ...
