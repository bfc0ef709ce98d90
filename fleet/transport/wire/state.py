"""What a drone publishes of itself: its state (``state/<drone>``) and the mail it holds (``held/<drone>``)."""

from __future__ import annotations

from typing import Literal

import msgspec

from fleet.transport.wire.base import CellList, MailId, Priority, WireBody, WireStruct, WireTrajectory


class Health(WireStruct, frozen=True, kw_only=True):
    ok: bool = True
    alarms: list[str] = msgspec.field(default_factory=list)


class TaskView(WireStruct, frozen=True, kw_only=True):
    goal: CellList
    purpose: str
    mail_id: str | None = None


class MailView(WireStruct, frozen=True, kw_only=True):
    """A mail a drone holds: queued, current (flying to its pickup) or on board; or one it handed back
    that no peer has taken over yet (with no service, its heir adopts it)."""

    id: MailId  #: a departed peer's mail is taken over from these: checked as an order is
    pickup: CellList
    dropoff: CellList
    priority: Priority
    stage: Literal["queued", "current", "carrying", "handed_back"]


class VehicleView(WireStruct, frozen=True, kw_only=True):
    """What the vehicle itself last reported, and whether it can fly plans."""

    status: Literal["ready", "waiting_for_position", "not_ready", "lost"]
    reason: str = ""  #: what keeps it from flying plans
    mode: str | None = None
    armed: bool = False
    landed: str = "undefined"  #: MAV_LANDED_STATE, lower case: on_ground, takeoff, in_air, landing
    height_m: float | None = None  #: above home
    gps_fix: int = 0  #: GPS_FIX_TYPE: 3 is a 3D fix
    satellites: int = 0
    battery_v: float | None = None


class DroneState(WireBody, frozen=True, kw_only=True, tag="state"):
    drone: str
    step: int
    cell: CellList  #: where the stack holds the drone (its executor's cell)
    actual: CellList | None = None  #: where telemetry puts the vehicle
    position: tuple[float, float, float] | None = None  #: lat, lon, alt_m (AMSL)
    battery_pct: float | None = None
    mode: str  #: the protocol's state
    phase: str  #: the task planner's phase
    landed: bool
    task: TaskView | None = None
    trajectory: WireTrajectory | None = None
    mail: list[MailView] = msgspec.field(default_factory=list)
    health: Health = msgspec.field(default_factory=Health)
    clock_offset_s: dict[str, float] = msgspec.field(default_factory=dict)  #: measured offset of each peer's clock
    plans: int = 0  #: plans made so far
    messages_sent: int = 0  #: protocol messages sent so far
    coordination_ms: float | None = None  #: the last plan's: task arrival to plan scheduled
    command: str | None = None  #: the operator's command in force: pause, recall or land (None: none)
    vehicle: VehicleView | None = None


class HeldMail(WireBody, frozen=True, kw_only=True, tag="held"):
    """The mail a drone holds, published when it changes: a drone's heir takes it over if it leaves."""

    drone: str
    mail: list[MailView]
