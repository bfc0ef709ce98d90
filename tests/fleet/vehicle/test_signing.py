"""The pymavlink link against what others put on its wire: forgeries, strangers and garbage.

Real MAVLink bytes on 127.0.0.1: a ``drona sim-vehicle`` process for the signed flight, the fake
vehicle in the test's own event loop for the rest (its own socket puts garbage or forgeries "on the
link", from the vehicle's address or inside its TCP stream), and plain sockets for strangers. A
change of the link's view is caught at whatever message causes it: ``wait_until`` checks its
predicate at every message the link takes. Every wait and every loop is bounded.
"""

from __future__ import annotations

import asyncio
import random
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from drona_gcs.errors import VehicleError
from fleet.clock import periodic
from fleet.sim.mav import mavlink2
from fleet.sim.ports import free_port
from fleet.vehicle.link import VehicleLink
from fleet.vehicle.mavlink_link import PymavlinkLink
from fleet.vehicle.signing import sign_outgoing
from tests.fakes.autopilot import FakeAutopilot, fake_vehicle, run

REPO = Path(__file__).resolve().parents[3]
KEY = bytes(range(32))
OTHER_KEY = bytes(range(1, 33))
QUAD, ARDUPILOT = mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA
LAND = 9  #: ArduCopter's LAND custom mode: what a forged "came down by itself" HEARTBEAT says


# ------------------------------------------------------------------ helpers
def heartbeat(sysid: int = 1, compid: int = 1, *, armed: bool = False, mode: int = LAND, kind: int = QUAD,
              autopilot: int = ARDUPILOT, key: bytes | None = None, ahead_s: float = 0.0) -> bytes:
    """A HEARTBEAT as bytes on the wire; with ``key`` signed, its timestamp ``ahead_s`` in the future."""
    enc = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    if key is not None:
        sign_outgoing(enc, key)
        enc.signing.timestamp += int(ahead_s * 100_000)  # in 10 µs
    base = mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mavlink2.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
    frame: bytes = enc.heartbeat_encode(kind, autopilot, base, mode, mavlink2.MAV_STATE_ACTIVE).pack(enc)
    return frame


def garbage(rng: random.Random) -> bytes:
    """Noise, a frame cut short, or a header that promises more than follows (MAVLink 2 and 1)."""
    kind = rng.randrange(4)
    if kind == 0:
        return rng.randbytes(rng.randint(1, 200))
    if kind == 1:
        frame = heartbeat()
        return frame[:rng.randint(1, len(frame) - 1)]
    if kind == 2:
        return bytes([0xFD, 0xFF, 0, 0]) + rng.randbytes(rng.randint(0, 40))
    return bytes([0xFE, 0xFF]) + rng.randbytes(rng.randint(0, 40))


def bad_crc(rng: random.Random) -> bytes:
    """A real HEARTBEAT of the vehicle's ids with its checksum broken, or noise."""
    if rng.random() < 0.5:
        return rng.randbytes(rng.randint(1, 200))
    frame = bytearray(heartbeat(armed=True))
    frame[-1] ^= 0xFF
    return bytes(frame)


def on_the_link(fake: FakeAutopilot) -> Callable[[bytes], None]:
    """Bytes put on the link by the vehicle's side: from its UDP address, or inside its TCP stream."""
    transport = fake.nodes[0].link
    assert transport is not None
    return transport.send


class Stranger:
    """A UDP socket of its own that writes to the link's udpin port and counts what comes back."""

    def __init__(self, port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.target = ("127.0.0.1", port)

    def send(self, data: bytes) -> None:
        self.sock.sendto(data, self.target)

    def received(self) -> int:
        count = 0
        while True:
            try:
                self.sock.recv(65536)
            except BlockingIOError:
                return count
            count += 1

    def close(self) -> None:
        self.sock.close()


async def write_for(seconds: float, rate_hz: float, send: Callable[[bytes], None],
                    make: Callable[[random.Random], bytes], seed: int = 1) -> None:
    rng, deadline = random.Random(seed), time.monotonic() + seconds
    async for _ in periodic(1 / rate_hz):
        if time.monotonic() > deadline:
            return
        send(make(rng))


async def view_unchanged(link: VehicleLink, seconds: float) -> None:
    """The link's armed state and mode stay as they are at every message for ``seconds``."""
    before = link.telemetry()
    with pytest.raises(VehicleError, match="waited"):  # timed out waiting for a change, not a lost link
        await link.wait_until(lambda t: (t.armed, t.mode) != (before.armed, before.mode), seconds, "a change")
    assert link.problem() is None


def pymavlink(url: str, **options: Any) -> PymavlinkLink:
    return PymavlinkLink(url, setpoint_hz=20.0, **options)


# ------------------------------------------------------------------ signing
def test_a_signed_link_flies_a_sim_vehicle_started_with_its_key() -> None:
    """`drona sim-vehicle --signing-key` ignores whatever is unsigned: the link signs, and flies it."""
    port = free_port(socket.SOCK_DGRAM)
    proc = subprocess.Popen([sys.executable, "-m", "fleet.cli", "sim-vehicle", "--signing-key", KEY.hex(),
                             "--base-port", str(port), "--speedup", "10", "--ready-after", "1"],
                            cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)

    async def scenario() -> None:
        link = pymavlink(f"udpin://127.0.0.1:{port}", signing_key=KEY)
        await link.connect(timeout=15)  # the process starts meanwhile
        try:
            await link.wait_ready(timeout=5)
            t = link.telemetry()
            assert t.battery_pct == 100 and t.position is not None and t.gps_fix >= 3
            await link.arm()
            await link.takeoff(3.0)
            await link.wait_until(lambda t: (t.height_m or 0) > 2.7, 5, "3 m up")
            await link.land()
            await link.wait_until(lambda t: not t.armed, 10, "touchdown")
        finally:
            await link.close()

    try:
        run(scenario)
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.communicate(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()


def test_a_link_with_the_wrong_key_hears_no_vehicle() -> None:
    async def scenario() -> None:
        async with fake_vehicle("ardupilot", "udp", signing_key=KEY) as fake:
            link = pymavlink(fake.url, signing_key=OTHER_KEY)
            with pytest.raises(VehicleError, match="HEARTBEAT"):
                await link.connect(timeout=1)

    run(scenario)


@pytest.mark.parametrize("forgery", ["unsigned", "wrong key", "wrong key, timestamp ahead"])
@pytest.mark.parametrize("transport", ["udp", "tcp"])
def test_with_signing_a_forged_heartbeat_is_not_heard(forgery: str, transport: str) -> None:
    """From the vehicle's own address (or inside its TCP stream), with its ids: only the signature
    tells the forgery apart. A wrongly signed one dated ahead must not make the vehicle's own,
    rightly signed messages look old either (pymavlink records a stream's time before the check)."""
    key = {"unsigned": None, "wrong key": OTHER_KEY, "wrong key, timestamp ahead": OTHER_KEY}[forgery]
    ahead = 3600.0 if "ahead" in forgery else 0.0

    async def scenario() -> None:
        async with fake_vehicle("ardupilot", transport, signing_key=KEY) as fake:
            link = pymavlink(fake.url, signing_key=KEY, heartbeat_timeout=1.0)
            await link.connect(timeout=5)
            try:
                await link.wait_ready(timeout=5)
                await link.arm()
                send, heard = on_the_link(fake), link.heartbeats
                forging = asyncio.create_task(write_for(1.0, 50, send, lambda rng: heartbeat(key=key, ahead_s=ahead)))
                await view_unchanged(link, 1.2)
                await forging
                assert link.heartbeats >= heard + 8  # the vehicle's own, at 10 Hz here, still heard
                assert link.telemetry().armed
            finally:
                await link.close()

    run(scenario)


# ------------------------------------------------------------------ whom the link listens to
@pytest.mark.parametrize("ids", [(7, 1), (1, 2), (1, 1)], ids=["other system", "other component", "same ids"])
def test_on_udpin_a_strangers_heartbeat_changes_nothing_and_draws_nothing(ids: tuple[int, int]) -> None:
    """A forged disarmed HEARTBEAT from another address (today: "the vehicle came down by itself"):
    the view stays, and the link keeps answering its vehicle, never the stranger."""
    async def scenario() -> None:
        async with fake_vehicle("ardupilot", "udp") as fake:
            link = pymavlink(fake.url)
            await link.connect(timeout=5)
            stranger = Stranger(int(fake.url.rsplit(":", 1)[1]))
            try:
                await link.wait_ready(timeout=5)
                await link.arm()
                forging = asyncio.create_task(write_for(1.0, 50, stranger.send, lambda rng: heartbeat(*ids)))
                await view_unchanged(link, 1.2)
                await forging
                await link.disarm()  # commands still reach the vehicle
                assert not link.telemetry().armed
                assert stranger.received() == 0
            finally:
                stranger.close()
                await link.close()

    run(scenario)


def test_a_heartbeat_that_is_no_autopilots_changes_nothing_even_with_the_vehicles_ids() -> None:
    """A ground station's HEARTBEAT (or one with no autopilot) says nothing of the vehicle's state,
    whoever's ids it carries: here inside the vehicle's own TCP stream."""
    async def scenario() -> None:
        async with fake_vehicle("ardupilot", "tcp") as fake:
            link = pymavlink(fake.url)
            await link.connect(timeout=5)
            try:
                await link.wait_ready(timeout=5)
                await link.arm()
                gcs = heartbeat(kind=mavlink2.MAV_TYPE_GCS, autopilot=mavlink2.MAV_AUTOPILOT_INVALID)
                nothing = heartbeat(autopilot=mavlink2.MAV_AUTOPILOT_INVALID)
                forge = on_the_link(fake)
                forging = asyncio.create_task(write_for(1.0, 50, forge, lambda rng: rng.choice([gcs, nothing])))
                await view_unchanged(link, 1.2)
                await forging
            finally:
                await link.close()

    run(scenario)


def test_on_udpin_a_strangers_bad_crc_datagrams_draw_none_of_the_links() -> None:
    """The stranger writes at 100 Hz before the vehicle is even heard, and on while the link connects,
    asks for telemetry and arms: not one datagram goes its way."""
    async def scenario() -> None:
        port = free_port(socket.SOCK_DGRAM)
        stranger = Stranger(port)
        link = pymavlink(f"udpin://127.0.0.1:{port}")
        try:
            writing = asyncio.create_task(write_for(3.0, 100, stranger.send, bad_crc))
            connecting = asyncio.create_task(link.connect(timeout=5))
            await asyncio.sleep(0.3)  # the stranger alone, first
            async with fake_vehicle("ardupilot", "udp", port=port):
                await connecting
                await link.wait_ready(timeout=5)
                await link.arm()
                await link.disarm()
                await writing
            assert stranger.received() == 0
        finally:
            stranger.close()
            await link.close()

    run(scenario)


# ------------------------------------------------------------------ garbage on the link
@pytest.mark.parametrize("transport", ["udp", "tcp"])
def test_garbage_on_the_link_hides_no_heartbeat_and_no_telemetry(transport: str) -> None:
    """Noise and truncated frames at 100 Hz on the vehicle's own link, at real speed (HEARTBEAT at
    1 Hz, positions at 10 Hz): every HEARTBEAT is still heard and the positions keep coming."""
    seconds = 5.0

    async def scenario() -> None:
        async with fake_vehicle("ardupilot", transport, speedup=1.0, ready_after_s=0.5) as fake:
            link = pymavlink(fake.url, heartbeat_timeout=1.5)
            await link.connect(timeout=5)
            try:
                await link.wait_ready(timeout=5)
                heard, worst = link.heartbeats, 0.0
                writing = asyncio.create_task(write_for(seconds, 100, on_the_link(fake), garbage))
                async for _ in periodic(0.05):
                    if writing.done():
                        break
                    position = link.last_position()
                    assert position is not None and link.problem() is None, link.problem()
                    worst = max(worst, time.monotonic() - position.at)
                await writing
                assert link.heartbeats - heard >= seconds - 1
                assert worst < 0.5, f"no position for {worst:.2f} s"
            finally:
                await link.close()

    run(scenario)
