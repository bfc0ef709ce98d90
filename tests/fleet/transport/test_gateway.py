"""The fleet's links: the service gateway open only while linked to the fleet, and UDP links
given a host name.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import socket
import sys

import pytest

from drona_gcs.workspace import Workspace
from fleet.sim.ports import free_port
from fleet.sim.transport import UdpLink
from fleet.transport.gateway import ZenohGateway
from fleet.vehicle.urls import open_transport, parse_link_url

#: A fleet peer in a process of its own, as an agent is: it listens where the gateway connects, says
#: "up", and closes its session when its stdin ends, then exits.
PEER = """
import sys, zenoh
from fleet.transport.settings import ZenohSettings
session = zenoh.open(ZenohSettings(listen=(sys.argv[1],)).config())
print("up", flush=True)
sys.stdin.read()
session.close()
"""


@pytest.mark.parametrize("leaves", ["closes its session", "is killed"])
def test_the_service_gateway_is_open_only_while_linked_to_the_fleet(leaves: str) -> None:
    """``/readyz`` reads it: an open session that no peer is linked to reaches no drone.

    The peer runs in its own process because a peer leaves with its process. In one process, Zenoh
    (1.10.2) can keep a link up after ``close``: the gateway reconnects at once, and a link accepted
    while the session closes lives on, answering keep-alives (measured: 5 of 270 closes, one still up
    20 s later). The process exiting ends it, as it does for a real agent."""
    endpoint = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    ws = Workspace.build(size=(2, 2, 1), cell_size_m=1.0, tau_s=1.0)

    async def until(gateway: ZenohGateway, linked: bool) -> bool:
        for _ in range(100):  # polled, as /readyz asks it
            if gateway.is_open() is linked:
                return True
            await asyncio.sleep(0.05)
        return False

    async def start_peer() -> asyncio.subprocess.Process:
        peer = await asyncio.create_subprocess_exec(
            sys.executable, "-c", PEER, endpoint, stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE)
        assert peer.stdout is not None
        assert await asyncio.wait_for(peer.stdout.readline(), 30) == b"up\n", "the peer never came up"
        return peer

    async def stop_peer(peer: asyncio.subprocess.Process) -> None:
        assert peer.stdin is not None
        if leaves == "is killed":
            peer.kill()
        else:
            peer.stdin.close()
        assert await asyncio.wait_for(peer.wait(), 30) == (-9 if leaves == "is killed" else 0)

    async def scenario() -> tuple[bool, bool, bool, bool]:
        gateway = ZenohGateway(ws, argparse.Namespace(fleet="t", connect=[endpoint], zenoh_config=None))
        running = asyncio.create_task(gateway.run())
        peer: asyncio.subprocess.Process | None = None
        try:
            await asyncio.wait_for(gateway.ready.wait(), 10)
            alone = gateway.is_open()
            peer = await start_peer()
            linked = await until(gateway, True)
            await stop_peer(peer)
            cut = await until(gateway, False)
        finally:
            if peer is not None and peer.returncode is None:
                peer.kill()
                await peer.wait()
            running.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await running
        return alone, linked, cut, gateway.is_open()

    alone, linked, cut, after = asyncio.run(scenario())
    assert not alone, "open with nobody to link to"
    assert linked, "a peer came up where the gateway connects: never linked"
    assert cut, f"the peer {leaves}: still linked"
    assert not after


@pytest.mark.parametrize("event_loop", ["asyncio", "uvloop"])
def test_udp_links_given_a_host_name_send_on_either_event_loop(event_loop: str) -> None:
    """uvloop's sendto looks no name up: the fake vehicle's link and a udpout:// link to "localhost"
    must still reach their peer (the processes run on uvloop, fleet/runtime.py)."""
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    receiver.settimeout(5)
    port = receiver.getsockname()[1]

    async def send_both() -> None:
        vehicle_side = await UdpLink.open("localhost", port, lambda: lambda data: None)
        ground_side = await open_transport(parse_link_url(f"udpout://localhost:{port}"), lambda data: None,
                                           lambda why: None)
        try:
            vehicle_side.send(b"from the vehicle")
            ground_side.send(b"from the ground")
            await asyncio.sleep(0.05)  # the datagrams are on their way: nothing to wait on but the socket
        finally:
            vehicle_side.close()
            ground_side.close()

    try:
        if event_loop == "uvloop":
            uvloop = pytest.importorskip("uvloop", reason="uvloop is not installed here")
            uvloop.run(send_both())
        else:
            asyncio.run(send_both())
        assert {receiver.recv(64), receiver.recv(64)} == {b"from the vehicle", b"from the ground"}
    finally:
        receiver.close()
