"""asyncio links for the fake vehicle: bytes in, bytes out, nothing about MAVLink.

* :class:`UdpLink`, as PX4 SITL: sends from an ephemeral port to the ground station's
  ``host:port`` and replies to whichever address wrote to it last.
* :class:`TcpServerLink`, as ArduPilot SITL: a TCP server; what the vehicle sends goes to
  every connected client.
* :class:`PtyLink`, as a flight controller on a serial port (a telemetry radio, a companion
  computer's UART): one end of a pseudo-terminal, the other end's device is what the ground
  station opens; the line carries ``baud / 10`` bytes a second, as a UART.

All are callback protocols, so they add no tasks of their own. ``new_session()`` is called
once per byte stream (the UDP socket, each TCP connection, the serial line) and returns the
function that takes that stream's bytes, so each stream can keep its own parser.
"""

from __future__ import annotations

import asyncio
import logging
import os
import termios
import tty
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
            transport, link = await loop.create_datagram_endpoint(lambda: cls((host, peer_port), new_session),
                                                                  local_addr=(host, 0))
        except OSError as exc:
            raise VehicleError(f"cannot open a UDP socket on {host}: {exc.strerror}") from exc
        # The address the host name resolved to: uvloop's sendto takes no name to look up.
        link.peer = (transport.get_extra_info("sockname")[0], peer_port)
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


#: What the line may hold queued ahead of its rate: a flight controller's UART transmit buffer.
SERIAL_TX_BUFFER = 1024


class PtyLink:
    """A serial line on a pseudo-terminal. The ground station opens :attr:`device`.

    As a UART: what the vehicle sends is queued in a transmit buffer (:data:`SERIAL_TX_BUFFER`)
    that drains at the baud rate (10 bits a byte), and each message reaches the other end when
    its last byte is through, behind everything queued before it. A message the buffer has no
    room for is skipped whole, as ArduPilot and PX4 skip one when the UART lacks room. Bytes
    nobody reads are lost, as on a wire nobody listens to. Not modelled: a pseudo-terminal has
    no speed, so a ground station opening it at the wrong baud rate still reads it.
    """

    def __init__(self, new_session: SessionFactory, baud: int, loop: asyncio.AbstractEventLoop) -> None:
        if baud <= 0:
            raise ValueError(f"the baud rate must be > 0, got {baud}")
        self._on_data = new_session()
        self._loop = loop
        self.rate = baud / 10  #: bytes a second
        self._master, self._slave = os.openpty()
        try:
            # Raw at once: a terminal's line discipline would echo what we send back to us, and
            # turn bytes into other bytes, before the ground station opens its end.
            tty.setraw(self._slave)
            os.set_blocking(self._master, False)
            self.device = os.ttyname(self._slave)
            loop.add_reader(self._master, self._readable)
        except BaseException:
            os.close(self._master)
            os.close(self._slave)
            raise
        self._drained_at = loop.time()  #: when the line will have sent everything queued
        self._closed = False
        self.sent = 0  #: bytes the line carried
        self.unsent = 0  #: bytes the transmit buffer had no room for

    @classmethod
    async def open(cls, baud: int, new_session: SessionFactory) -> PtyLink:
        try:
            return cls(new_session, baud, asyncio.get_running_loop())
        except (OSError, termios.error) as exc:
            raise VehicleError(f"cannot open a pseudo-terminal: {exc}") from exc

    def _readable(self) -> None:
        try:
            data = os.read(self._master, 4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:  # the terminal is gone (never while we hold its other end): stop reading
            log.debug("serial %s: %s", self.device, exc)
            data = b""
        if data:
            self._on_data(data)
        else:
            self._loop.remove_reader(self._master)

    def queued(self) -> float:
        """Bytes in the transmit buffer now."""
        return max(0.0, self._drained_at - self._loop.time()) * self.rate

    def send(self, data: bytes) -> None:
        if self._closed:
            return
        if self.queued() + len(data) > SERIAL_TX_BUFFER:
            self.unsent += len(data)
            return
        self._drained_at = max(self._loop.time(), self._drained_at) + len(data) / self.rate
        self._loop.call_at(self._drained_at, self._deliver, data)

    def _deliver(self, data: bytes) -> None:
        if self._closed:
            return
        self.sent += len(data)
        if self._write(data) < len(data):
            # The other end's input is full: nobody reads it. What nobody read is lost, as on a
            # wire, the head of this message too (the flush takes it); the message goes again, whole.
            termios.tcflush(self._slave, termios.TCIFLUSH)
            self._write(data)

    def _write(self, data: bytes) -> int:
        try:
            return os.write(self._master, data)
        except (BlockingIOError, InterruptedError):
            return 0

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._loop.remove_reader(self._master)
            os.close(self._master)
            os.close(self._slave)

    async def wait_closed(self) -> None:
        return None
