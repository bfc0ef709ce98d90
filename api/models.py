"""Request and response bodies of ``/v1``: strict, and unknown fields refused.

Requests are validated in pydantic's strict mode (a priority ``"3"`` or ``3.0`` is
refused, not coerced). Cells are JSON arrays ``[x, y, z]`` of integers.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, StrictInt, StrictStr

from api.alarms import Alarm
from api.gateway import DroneView
from api.lifecycle import Status
from api.store import AuditEntry, MailRecord
from api.watch import LogEntry
from drona_gcs.geo import GeoFrame, Ned
from drona_gcs.workspace import Workspace

CellIn = Annotated[list[StrictInt], Field(min_length=3, max_length=3, description="[x, y, z]", examples=[[1, 2, 0]])]
CellOut = Annotated[list[int], Field(min_length=3, max_length=3, description="[x, y, z]")]
#: Most characters of a note.
NOTE_MAX = 500


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)


class MailCreate(_Strict):
    pickup: CellIn
    dropoff: CellIn
    priority: Annotated[StrictInt, Field(ge=0, le=9, description="0..9, 9 the most urgent")]
    note: Annotated[StrictStr, Field(max_length=NOTE_MAX)] = ""


#: The body, header and 422 of POST /v1/mail in the OpenAPI document (the route parses the request itself).
MAIL_CREATE_EXTRA: dict[str, Any] = {
    "requestBody": {"required": True, "content": {"application/json": {
        "schema": {"$ref": "#/components/schemas/MailCreate"}}}},
    "parameters": [{"name": "Idempotency-Key", "in": "header", "required": False,
                    "description": "retrying with the same key (and body) answers with the mail made the first time",
                    "schema": {"type": "string", "pattern": "^[\\x21-\\x7e]{1,200}$"}}],
    "responses": {"422": {"description": "a field is wrong: loc names it, msg says why", "content": {
        "application/json": {"schema": {"$ref": "#/components/schemas/HTTPValidationError"}}}}},
}


class AuditPublic(BaseModel):
    status: Status
    at: datetime
    drone: str | None
    reason: str


class MailPublic(BaseModel):
    id: str
    status: Status
    created_at: datetime
    updated_at: datetime
    pickup: CellOut
    dropoff: CellOut
    priority: int
    note: str
    drone: str | None = Field(description="the drone that holds or held it")
    reason: str = Field(description="why it is in its status (requeued, failed, cancelled), else empty")
    owner: str

    @classmethod
    def of(cls, r: MailRecord) -> MailPublic:
        # Built from our own record: no need to validate (model_construct is several times faster).
        return cls.model_construct(id=r.id, status=r.status, created_at=_time(r.created_at),
                                   updated_at=_time(r.updated_at), pickup=list(r.pickup), dropoff=list(r.dropoff),
                                   priority=r.priority, note=r.note, drone=r.drone, reason=r.reason, owner=r.owner)


class MailDetail(MailPublic):
    history: list[AuditPublic] = Field(description="every status it went through, oldest first")

    @classmethod
    def with_history(cls, r: MailRecord, history: list[AuditEntry]) -> MailDetail:
        entries = [AuditPublic.model_construct(status=h.status, at=_time(h.at), drone=h.drone, reason=h.reason)
                   for h in history]
        return cls.model_construct(**MailPublic.of(r).__dict__, history=entries)


class MailPage(BaseModel):
    items: list[MailPublic]
    next_cursor: str | None = Field(description="pass as ?cursor= for the next (older) page; null at the end")


class FleetPublic(BaseModel):
    drones: list[DroneView]
    lost: list[DroneView] = Field(default_factory=list, description="the last known state of each drone that "
                                  "left (alive false; seen_at says when it was last heard)")


class GeoOriginPublic(BaseModel):
    lat: float
    lon: float
    alt_m: float
    layer0_alt_m: float
    layer_height_m: float
    cell_dlat: float = Field(description="degrees of latitude a cell spans: grid y grows north, so the corner "
                             "(x, y) of the grid is at lat + y * cell_dlat")
    cell_dlon: float = Field(description="degrees of longitude a cell spans: grid x grows east, lon + x * cell_dlon")


class BaseMapPublic(BaseModel):
    url: str = Field(description="a tile URL template ({z}, {x}, {y}) the dashboard draws under the grid")
    attribution: str


class WorkspacePublic(BaseModel):
    name: str
    size: CellOut
    obstacles: list[CellOut]
    charging_stations: list[CellOut]
    parking: list[CellOut]
    pickups: list[CellOut]
    dropoffs: list[CellOut]
    drones: dict[str, CellOut] = Field(description="start cell of each drone")
    cell_size_m: float
    tau_s: float
    beta_s: float = Field(description="the fleet's bound on clock skew")
    lambda_s: float = Field(description="how late a vehicle may enter its step's cell (set or derived)")
    delta: int = Field(description="ceil((beta_s + lambda_s) / tau_s): the separation window in steps")
    geo_origin: GeoOriginPublic
    base_map: BaseMapPublic | None = Field(None, description="none: the dashboard draws the grid alone")

    @classmethod
    def of(cls, ws: Workspace, base_map: BaseMapPublic | None = None) -> WorkspacePublic:
        geo, frame = ws.geo, GeoFrame(ws)
        far = frame.ned_to_global(Ned(ws.cell_size_m, ws.cell_size_m, 0.0))  # the grid's corner is the origin
        return cls(name=ws.name, size=list(ws.size), obstacles=[list(c) for c in sorted(ws.obstacles)],
                   charging_stations=[list(c) for c in ws.charging_stations], parking=[list(c) for c in ws.parking],
                   pickups=[list(c) for c in ws.pickups], dropoffs=[list(c) for c in ws.dropoffs],
                   drones={d: list(c) for d, c in ws.drones.items()}, cell_size_m=ws.cell_size_m, tau_s=ws.tau_s,
                   beta_s=ws.beta_s, lambda_s=ws.lateness_s, delta=ws.delta, base_map=base_map,
                   geo_origin=GeoOriginPublic(lat=geo.lat, lon=geo.lon, alt_m=geo.alt_m, layer0_alt_m=geo.layer0_alt_m,
                                              layer_height_m=ws.layer_height_m, cell_dlat=far.lat - geo.lat,
                                              cell_dlon=far.lon - geo.lon))


class AlarmPublic(BaseModel):
    n: int = Field(description="its number: POST /v1/alarms/{n}/ack acknowledges it")
    drone: str
    kind: str = Field(description="lag, down, vehicle, behind, vehicle_lost, placement, leg, clock, left, ...")
    meaning: str = Field(description="what the kind means, for an operator")
    text: str = Field(description="what the drone said when it was raised")
    raised_at: datetime
    cleared_at: datetime | None = Field(description="null while it holds")
    acked_at: datetime | None
    acked_by: str | None

    @classmethod
    def of(cls, a: Alarm) -> AlarmPublic:
        return cls(n=a.n, drone=a.drone, kind=a.kind, meaning=a.meaning, text=a.text, raised_at=_time(a.raised_at),
                   cleared_at=_maybe_time(a.cleared_at), acked_at=_maybe_time(a.acked_at), acked_by=a.acked_by)


class AlarmPage(BaseModel):
    items: list[AlarmPublic]


class LogEntryPublic(BaseModel):
    at: datetime
    kind: str = Field(description="drone (joined, left), alarm (raised, cleared, acknowledged) or mail")
    text: str
    drone: str | None
    mail_id: str | None

    @classmethod
    def of(cls, e: LogEntry) -> LogEntryPublic:
        return cls(at=_time(e.at), kind=e.kind, text=e.text, drone=e.drone, mail_id=e.mail_id)


class LogPage(BaseModel):
    items: list[LogEntryPublic] = Field(description="newest first")


class SamplePublic(BaseModel):
    at: float = Field(description="Unix seconds")
    drone: str
    value: float


class WaitingPublic(BaseModel):
    priority: int
    count: int
    p50_s: float
    p90_s: float
    max_s: float


class StatsPublic(BaseModel):
    now: float = Field(description="Unix seconds: the last delivery bucket ends here")
    bucket_s: float
    deliveries: list[int] = Field(description="deliveries per bucket, oldest first")
    waiting: list[WaitingPublic] = Field(description="from submitted to picked up, per priority (most urgent "
                                                     "first), of mail picked up within the window")
    coordination_ms: list[SamplePublic] = Field(description="each plan's coordination latency, as drones report it")
    battery_pct: list[SamplePublic] = Field(description="each drone's battery, sampled every few seconds")


class ErrorOut(BaseModel):
    detail: str


class HealthOut(BaseModel):
    status: str


class ReadyOut(BaseModel):
    ready: bool
    fleet_connected: bool  #: the gateway is linked to the fleet (its Zenoh session has a peer or router)
    drones: int
    queued: int
    held_by_drones: int


def _time(t: float) -> datetime:
    return datetime.fromtimestamp(t, UTC)


def _maybe_time(t: float | None) -> datetime | None:
    return None if t is None else _time(t)
