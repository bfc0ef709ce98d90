"""The fakes at the autopilot seam: what a vehicle link (or what drives one) talks to.

* :func:`fake_vehicle` runs one fake autopilot (:mod:`fleet.sim`, ArduCopter's or PX4's rules: it
  refuses what the real one refuses) in the test's own event loop, with real MAVLink bytes on
  127.0.0.1 (UDP, TCP, or a pseudo-terminal as a serial port); :func:`connected` opens a link of
  either backend (:data:`BACKENDS`) to it. Simulated time runs ``SPEEDUP`` times faster, so the
  fake's rules are scaled to stay realistic against the link's wall-clock rates.
States the fake autopilot cannot be brought into on cue (a landing called back at 0.3 m, the ground
above home) are scripted one seam up, on :class:`tests.fakes.vehicle.FakeVehicle`.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
from collections.abc import AsyncIterator, Callable, Coroutine
from dataclasses import dataclass
from typing import Any, Protocol

import pytest

from fleet.sim.config import VehicleConfig
from fleet.sim.fleet import FleetConfig, SimNode, run_fleet
from fleet.sim.personality import PERSONALITIES, Personality
from fleet.sim.ports import free_port
from fleet.sim.transport import PtyLink
from fleet.vehicle.link import VehicleLink
from fleet.vehicle.mavlink_link import PymavlinkLink

SPEEDUP = 10.0
#: A companion computer's UART: the fake vehicle's telemetry, ten times faster (SPEEDUP), must fit.
SERIAL_BAUD = 921600
SCENARIO_DEADLINE_S = 30.0


# ------------------------------------------------------------------ the links to it
class Backend(Protocol):
    def __call__(self, url: str, *, heartbeat_timeout: float = 3.0, frame: Any = None,
                 stream_hz: float = 10.0) -> VehicleLink: ...


def _pymavlink(url: str, *, heartbeat_timeout: float = 3.0, frame: Any = None, stream_hz: float = 10.0,
               setpoint_hz: float = 20.0) -> VehicleLink:
    return PymavlinkLink(url, heartbeat_timeout=heartbeat_timeout, frame=frame, setpoint_hz=setpoint_hz,
                         stream_hz=stream_hz)


def _mavsdk(url: str, *, heartbeat_timeout: float = 3.0, frame: Any = None, stream_hz: float = 10.0) -> VehicleLink:
    try:
        from fleet.vehicle.mavsdk_link import MavsdkLink
    except Exception as exc:  # no package, or its native library does not load here
        reason = f"MAVSDK cannot run here: {type(exc).__name__}: {exc}"
        print(reason)
        pytest.skip(reason)
    return MavsdkLink(url, heartbeat_timeout=heartbeat_timeout, frame=frame, stream_hz=stream_hz)


#: Backend name -> factory. Every contract test below runs against each.
BACKENDS: dict[str, Backend] = {"pymavlink": _pymavlink, "mavsdk": _mavsdk}


# ------------------------------------------------------------------ the fake autopilot
@dataclass
class FakeAutopilot:
    """A fake autopilot (fleet.sim: ArduCopter or PX4) running in the test's event loop; ``url`` reaches it."""

    url: str
    personality: Personality
    stop: asyncio.Event
    task: asyncio.Task[None]
    nodes: list[SimNode]

    async def silence(self) -> None:
        """Stop the fake vehicle (its links close; over UDP it just goes quiet)."""
        self.stop.set()
        await asyncio.wait_for(self.task, 5)


@contextlib.asynccontextmanager
async def fake_vehicle(personality: str, transport: str, port: int | None = None, speedup: float = SPEEDUP,
                       signing_key: bytes | None = None, **vehicle: Any) -> AsyncIterator[FakeAutopilot]:
    """One fake vehicle in this event loop; ``url`` is how a ground station reaches it. ``serial``: on a
    pseudo-terminal at :data:`SERIAL_BAUD`, as a flight controller wired to a companion computer. With
    ``signing_key`` it signs what it sends and ignores unsigned commands."""
    tcp, serial = transport == "tcp", transport == "serial"
    port = port or free_port(socket.SOCK_STREAM if tcp else socket.SOCK_DGRAM)
    settings: dict[str, Any] = {"ready_after_s": 1.0, "auto_disarm_s": 60.0, "offboard_timeout_s": 5.0, **vehicle}
    config = FleetConfig(vehicle=VehicleConfig(personality=PERSONALITIES[personality], **settings), tcp=tcp,
                         base_port=port, speedup=speedup, serial_baud=SERIAL_BAUD if serial else None,
                         signing_key=signing_key)
    stop, started = asyncio.Event(), asyncio.Event()
    nodes: list[SimNode] = []

    def ready(opened: list[SimNode]) -> None:
        nodes.extend(opened)
        started.set()

    task = asyncio.create_task(run_fleet(config, None, stop, on_ready=ready))
    waiter = asyncio.ensure_future(started.wait())
    await asyncio.wait([task, waiter], timeout=5, return_when=asyncio.FIRST_COMPLETED)
    waiter.cancel()
    if task.done():
        task.result()  # raises why it did not start
    assert started.is_set(), "the fake vehicle did not start"
    url = f"tcp://127.0.0.1:{port}" if tcp else f"udpin://127.0.0.1:{port}"
    if serial:
        assert isinstance(nodes[0].link, PtyLink)
        url = f"serial://{nodes[0].link.device}:{SERIAL_BAUD}"
    fake = FakeAutopilot(url, PERSONALITIES[personality], stop, task, nodes)
    try:
        yield fake
    finally:
        if not task.done():
            await fake.silence()


@contextlib.asynccontextmanager
async def connected(backend: str, fake: FakeAutopilot, **options: Any) -> AsyncIterator[VehicleLink]:
    link = BACKENDS[backend](fake.url, **options)
    await link.connect(timeout=5)
    try:
        yield link
    finally:
        await link.close()


def run(scenario: Callable[[], Coroutine[Any, Any, None]]) -> None:
    """Run ``scenario`` in a new event loop, within :data:`SCENARIO_DEADLINE_S`."""
    async def bounded() -> None:
        async with asyncio.timeout(SCENARIO_DEADLINE_S):
            await scenario()

    asyncio.run(bounded())

