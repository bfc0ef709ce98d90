"""Many fake vehicles in one process: one simulated clock, one tick loop, one TaskGroup.

Vehicle ``i`` (system id ``i + 1``; with the ArduPilot personality 1, as every ArduPilot SITL
instance: a ground station tells vehicles apart by their links) starts on the ground under drone
``i``'s start cell of the
workspace (``workspace.drones`` order); without a workspace the vehicles stand 5 m apart
eastwards at ArduPilot SITL's default home. Its link is, as the real SITLs:

* UDP (PX4 SITL): it sends to the ground station at ``host:(base_port + i)``, default base
  14540, and replies to whatever address last wrote to it;
* TCP (ArduPilot SITL): a server on ``host:(base_port + 10 i)``, default base 5760;
* serial (a flight controller's UART or telemetry radio): a pseudo-terminal at a baud rate.

The messages a vehicle has to send at once (a tick's telemetry, a command's answers) go out
together, several MAVLink packets to a datagram, as a real autopilot's do; on a serial line a
message at a time, so that one the line has no room for is skipped whole.

Local positions (LOCAL_POSITION_NED, SET_POSITION_TARGET_LOCAL_NED) are relative to the
vehicle's own home on the ground, as a real autopilot's EKF origin; GLOBAL_POSITION_INT and
HOME_POSITION place it in the workspace (:class:`drona_gcs.geo.GeoFrame`). A vehicle landed and
disarmed on a charging-station cell's ground recharges.

Simulated time runs ``speedup`` times faster than the wall clock; every rule of the model
(ready delay, auto-disarm, stream rates, offboard timeout) is in simulated seconds.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, replace

from drona_gcs.errors import WorkspaceError
from drona_gcs.geo import GeoFrame, Ned
from drona_gcs.workspace import GeoOrigin, Workspace
from fleet.clock import periodic
from fleet.sim.codec import Codec, decode
from fleet.sim.config import Placement, VehicleConfig
from fleet.sim.mav import Message
from fleet.sim.model import VehicleModel
from fleet.sim.transport import DataCallback, PtyLink, TcpServerLink, UdpLink
from fleet.sim.truth import TruthRecord

UDP_BASE_PORT = 14540
TCP_BASE_PORT = 5760
TCP_PORT_STRIDE = 10
#: ArduPilot SITL's default home (CMAC, Canberra), for runs without a workspace.
DEFAULT_HOME = GeoOrigin(lat=-35.363261, lon=149.165230, alt_m=584.0)
DEFAULT_SPACING_M = 5.0
#: A tick's messages share datagrams up to this size, as ArduPilot and PX4 pack whole MAVLink
#: packets into each UDP datagram (within an Ethernet MTU); a ground station parses them all.
DATAGRAM_BYTES = 1400


@dataclass(frozen=True)
class FleetConfig:
    count: int = 1
    vehicle: VehicleConfig = field(default_factory=VehicleConfig)  #: system_id is set per vehicle
    tcp: bool = False
    host: str = "127.0.0.1"
    base_port: int | None = None  #: None: 14540 for UDP, 5760 for TCP
    speedup: float = 1.0
    tick_s: float = 0.02  #: wall-clock seconds between physics/telemetry steps
    signing_key: bytes | None = None
    serial_baud: int | None = None  #: set: each vehicle on a pseudo-terminal at this baud rate (no port)
    first: int = 0  #: the first vehicle's instance (SITL's -I): its drone of the workspace, its port

    @property
    def instances(self) -> range:
        return range(self.first, self.first + self.count)

    def port(self, index: int) -> int:
        if self.tcp:
            return (TCP_BASE_PORT if self.base_port is None else self.base_port) + TCP_PORT_STRIDE * index
        return (UDP_BASE_PORT if self.base_port is None else self.base_port) + index


class SimClock:
    """Simulated seconds since the start, ``speedup`` times the wall clock."""

    def __init__(self, speedup: float = 1.0) -> None:
        if not speedup > 0:
            raise ValueError(f"speedup must be > 0, got {speedup}")
        self.speedup = speedup
        self._start = time.monotonic()

    def now(self) -> float:
        return (time.monotonic() - self._start) * self.speedup


def placements(workspace: Workspace | None, count: int, first: int = 0) -> list[Placement]:
    """Where vehicles ``first`` to ``count - 1`` start (raises WorkspaceError if the workspace has too few
    drones)."""
    if workspace is None:
        ws = Workspace.build(size=(max(1, count), 1, 1), cell_size_m=DEFAULT_SPACING_M, geo=DEFAULT_HOME)
        cells = [(i, 0, 0) for i in range(count)]
    else:
        ws, cells = workspace, list(workspace.drones.values())
        if len(cells) < count:
            asked = f"{count - first} vehicles asked for" + (f" from instance {first}" if first else "")
            raise WorkspaceError(f"has {len(cells)} drone(s), {asked}",
                                 field="drones", source=workspace.source)
    frame = GeoFrame(ws)
    chargers = frozenset((x, y) for x, y, _ in ws.charging_stations)
    out = []
    for cell in cells[first:count]:
        centre = frame.cell_to_ned(cell)
        out.append(Placement(frame, Ned(centre.north, centre.east, 0.0), chargers))
    return out


class SimNode:
    """One vehicle model on its link: decodes what arrives, encodes and sends what the model says."""

    def __init__(self, model: VehicleModel, codec: Codec, clock: SimClock) -> None:
        self.model = model
        self.codec = codec
        self.clock = clock
        self.link: UdpLink | TcpServerLink | PtyLink | None = None

    @property
    def system_id(self) -> int:
        return self.model.config.system_id

    async def open(self, config: FleetConfig, index: int) -> None:
        if config.serial_baud is not None:
            self.link = await PtyLink.open(config.serial_baud, self.session)
            return
        port = config.port(index)
        if config.tcp:
            self.link = await TcpServerLink.open(config.host, port, self.session)
        else:
            self.link = await UdpLink.open(config.host, port, self.session)

    def session(self) -> DataCallback:
        decoder = self.codec.decoder()

        def on_data(data: bytes) -> None:
            now = self.clock.now()
            for msg in decode(decoder, data):
                self.send(self.model.handle(msg, now))

        return on_data

    def step(self, now: float) -> None:
        self.send(self.model.step(now))

    def send(self, messages: list[Message]) -> None:
        if self.link is None:
            return
        frames = (self.codec.encode(msg) for msg in messages)
        for chunk in frames if isinstance(self.link, PtyLink) else pack_datagrams(frames):
            self.link.send(chunk)

    def close(self) -> None:
        if self.link is not None:
            self.link.close()


def pack_datagrams(frames: Iterable[bytes], limit: int = DATAGRAM_BYTES) -> Iterator[bytes]:
    """Consecutive frames joined into datagrams of at most ``limit`` bytes (a longer frame alone)."""
    chunk: list[bytes] = []
    size = 0
    for frame in frames:
        if chunk and size + len(frame) > limit:
            yield b"".join(chunk)
            chunk, size = [], 0
        chunk.append(frame)
        size += len(frame)
    if chunk:
        yield b"".join(chunk)


def build_nodes(config: FleetConfig, workspace: Workspace | None, clock: SimClock) -> list[SimNode]:
    now = clock.now()
    nodes = []
    for i, place in zip(config.instances, placements(workspace, config.instances.stop, config.first), strict=True):
        sysid = 1 if config.vehicle.personality.one_system_id else i + 1
        vehicle = replace(config.vehicle, system_id=sysid, instance=i, speedup=config.speedup)
        codec = Codec(sysid, signing_key=config.signing_key)
        nodes.append(SimNode(VehicleModel(vehicle, place, now), codec, clock))
    return nodes


async def run_fleet(config: FleetConfig, workspace: Workspace | None, stop: asyncio.Event,
                    on_ready: Callable[[list[SimNode]], None] | None = None, truth: TruthRecord | None = None) -> None:
    """Run the vehicles until ``stop`` is set; ``on_ready(nodes)`` once every link is open; ``truth``
    records where they are at every tick."""
    clock = SimClock(config.speedup)
    nodes = build_nodes(config, workspace, clock)
    try:
        for i, node in zip(config.instances, nodes, strict=True):
            await node.open(config, i)
        if on_ready is not None:
            on_ready(nodes)
        async with asyncio.TaskGroup() as tg:
            ticker = tg.create_task(_tick(nodes, clock, config.tick_s, truth))
            await stop.wait()
            ticker.cancel()
    finally:
        for node in nodes:
            node.close()
        for node in nodes:
            if node.link is not None:
                await node.link.wait_closed()


async def _tick(nodes: list[SimNode], clock: SimClock, period: float, truth: TruthRecord | None) -> None:
    async for _ in periodic(period):
        now = clock.now()
        for node in nodes:
            node.step(now)
        if truth is not None:
            truth.observe(time.time(), [node.model.ned() for node in nodes])
