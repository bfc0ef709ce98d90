"""What the rest of the fleet needs from a vehicle link, as typing protocols.

The backends (pymavlink, MAVSDK) implement :class:`VehicleLink`; the setpoint
loop only needs the smaller :class:`SetpointSink`, so it can be driven and
tested without an autopilot. :class:`Telemetry` is what every backend reports,
in the same units, whatever the autopilot.
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from drona_gcs.geo import GeoPoint, Ned


@dataclass(frozen=True)
class Position:
    """The latest position the vehicle reported, with the link's clock time of the report."""

    ned: Ned
    at: float


class Autopilot(enum.Enum):
    ARDUPILOT = "ardupilot"  #: MAV_AUTOPILOT_ARDUPILOTMEGA
    PX4 = "px4"  #: MAV_AUTOPILOT_PX4
    OTHER = "other"  #: anything else: no mode names known


class LandedState(enum.IntEnum):
    """MAV_LANDED_STATE, from EXTENDED_SYS_STATE."""

    UNDEFINED = 0  #: not reported (yet)
    ON_GROUND = 1
    IN_AIR = 2
    TAKEOFF = 3
    LANDING = 4


@dataclass(frozen=True)
class Telemetry:
    """A snapshot of what the vehicle last reported (None: not reported yet)."""

    autopilot: Autopilot | None
    armed: bool
    mode: str | None  #: the autopilot's mode name ("GUIDED", "OFFBOARD"), or "custom_mode=<n>" when unknown
    position: Position | None  #: in the link's frame (see the backend)
    velocity: Ned | None  #: m/s
    global_position: GeoPoint | None
    height_m: float | None  #: above home
    battery_pct: int | None
    battery_v: float | None
    gps_fix: int  #: GPS_FIX_TYPE: 3 is a 3D fix
    satellites: int
    landed: LandedState
    heartbeat_at: float | None  #: link clock time of the last HEARTBEAT


class SetpointSink(Protocol):
    """Where the setpoint loop sends targets and reads positions."""

    async def send_position_target(self, target: Ned) -> None: ...

    def last_position(self) -> Position | None: ...


class VehicleLink(SetpointSink, Protocol):
    """The whole link: connection, readiness, commands and telemetry."""

    async def connect(self, timeout: float = ...) -> None: ...

    async def wait_ready(self, timeout: float) -> None: ...

    async def arm(self) -> None: ...

    async def disarm(self) -> None: ...

    async def set_mode(self, mode: str) -> None: ...

    async def follow_setpoints(self) -> None:
        """Enter the mode that follows setpoints (GUIDED, OFFBOARD), streaming one first where needed."""

    async def takeoff(self, altitude_m: float) -> None: ...

    async def land(self) -> None: ...

    async def close(self) -> None: ...

    def last_global(self) -> GeoPoint | None: ...

    def telemetry(self) -> Telemetry: ...

    async def wait_until(self, predicate: Callable[[Telemetry], bool], timeout: float,
                         what: str) -> Telemetry:
        """The first snapshot for which ``predicate`` holds; VehicleError naming ``what`` after ``timeout``."""
