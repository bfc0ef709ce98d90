"""asyncio links for the fake vehicle: bytes in, bytes out, nothing about MAVLink.

* :class:`UdpLink`, as PX4 SITL: sends from an ephemeral port to the ground station's
  ``host:port`` and replies to whichever address wrote to it last.
* :class:`TcpServerLink`, as ArduPilot SITL: a TCP server; what the vehicle sends goes to
  every connected client.

Both are callback protocols, so they add no tasks of their own. ``new_session()`` is called
once per byte stream (the UDP socket, each TCP connection) and returns the function that takes
that stream's bytes, so each stream can keep its own parser.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from typing import cast

from drona_gcs.errors import VehicleError

log = logging.getLogger(__name__)

DataCallback = Callable[[bytes], None]
SessionFactory = Callable[[], DataCallback]

#: A TCP client that lets this much pile up unread loses messages instead of our memory.
MAX_TCP_BACKLOG = 1 << 20


class UdpLink(asyncio.DatagramProtocol):
    def __init__(self, peer: tuple[str, int], new_session: SessionFactory) -> None:
        self.peer = peer
        self._on_data = new_session()
        self._transport: asyncio.DatagramTransport | None = None

    @classmethod
    async def open(cls, host: str, peer_port: int, new_session: SessionFactory) -> UdpLink:
        loop = asyncio.get_running_loop()
        try:
            _, link = await loop.create_datagram_endpoint(lambda: cls((host, peer_port), new_session),
                                                          local_addr=(host, 0))
        except OSError as exc:
            raise VehicleError(f"cannot open a UDP socket on {host}: {exc.strerror}") from exc
        return link

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self._transport = cast(asyncio.DatagramTransport, transport)  # 3.11's selector one is not a subclass

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self.peer = addr
        self._on_data(data)

    def error_received(self, exc: Exception) -> None:
        # ICMP "port unreachable" for an earlier datagram: no ground station listens yet.
        log.debug("udp link to %s: %s", self.peer, exc)

    def send(self, data: bytes) -> None:
        if self._transport is not None and not self._transport.is_closing():
            self._transport.sendto(data, self.peer)

    def close(self) -> None:
        if self._transport is not None:
            self._transport.close()

    async def wait_closed(self) -> None:
        return None


class TcpServerLink:
    def __init__(self, new_session: SessionFactory) -> None:
        self.new_session = new_session
        self.clients: set[_TcpConnection] = set()
        self._server: asyncio.Server | None = None

    @classmethod
    async def open(cls, host: str, port: int, new_session: SessionFactory) -> TcpServerLink:
        link = cls(new_session)
        loop = asyncio.get_running_loop()
        try:
            link._server = await loop.create_server(lambda: _TcpConnection(link), host, port)
        except OSError as exc:
            raise VehicleError(f"cannot listen on {host}:{port}: {exc.strerror}") from exc
        return link

    @property
    def port(self) -> int:
        assert self._server is not None
        port: int = self._server.sockets[0].getsockname()[1]
        return port

    def send(self, data: bytes) -> None:
        for client in self.clients:
            client.write(data)

    def close(self) -> None:
        if self._server is not None:
            self._server.close()
        for client in list(self.clients):
            client.close()

    async def wait_closed(self) -> None:
        if self._server is not None:
            await self._server.wait_closed()


class _TcpConnection(asyncio.Protocol):
    def __init__(self, link: TcpServerLink) -> None:
        self._link = link
        self._on_data = link.new_session()
        self._transport: asyncio.Transport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self._transport = cast(asyncio.Transport, transport)
        self._link.clients.add(self)

    def data_received(self, data: bytes) -> None:
        self._on_data(data)

    def connection_lost(self, exc: Exception | None) -> None:
        self._link.clients.discard(self)

    def write(self, data: bytes) -> None:
        t = self._transport
        if t is not None and not t.is_closing() and t.get_write_buffer_size() < MAX_TCP_BACKLOG:
            t.write(data)

    def close(self) -> None:
        if self._transport is not None:
            self._transport.close()
