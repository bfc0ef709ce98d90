"""What the rest of the fleet needs from a vehicle link, as typing protocols.

The backends (pymavlink, MAVSDK) implement :class:`VehicleLink`; the setpoint
loop only needs the smaller :class:`SetpointSink`, so it can be driven and
tested without an autopilot.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from drona_gcs.geo import GeoPoint, Ned


@dataclass(frozen=True)
class Position:
    """The latest position the vehicle reported, with the link's clock time of the report."""

    ned: Ned
    at: float


class SetpointSink(Protocol):
    """Where the setpoint loop sends targets and reads positions."""

    async def send_position_target(self, target: Ned) -> None: ...

    def last_position(self) -> Position | None: ...


class VehicleLink(SetpointSink, Protocol):
    """The whole link: connection, readiness, commands and telemetry."""

    async def connect(self) -> None: ...

    async def wait_ready(self, timeout: float) -> None: ...

    async def arm(self) -> None: ...

    async def takeoff(self, altitude_m: float) -> None: ...

    async def land(self) -> None: ...

    async def close(self) -> None: ...

    def last_global(self) -> GeoPoint | None: ...
