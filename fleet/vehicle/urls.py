"""Connection strings as users know them from PX4, ArduPilot and MAVSDK, and the byte transports they open.

* ``udpin://0.0.0.0:14540``: listen on a UDP port (PX4 SITL sends to 14540) and answer the vehicle
  (the sender of its HEARTBEAT, see :class:`_Datagrams`);
* ``udpout://10.0.0.2:14550``: send to a UDP address (the vehicle listens there);
* ``tcp://127.0.0.1:5760``: connect to a TCP server (ArduPilot SITL listens on 5760);
* ``serial:///dev/ttyUSB0:57600``: a serial device and its baud rate (57600 when left out).

A bad string raises :class:`LinkUrlError` (a :class:`~drona_gcs.errors.DronaError` and a
``ValueError``) whose message quotes the string and says what is wrong with it.
:func:`open_transport` opens a :class:`LinkUrl` as an asyncio transport that moves bytes and
knows nothing about MAVLink (serial needs pyserial-asyncio: the ``serial`` extra).
"""

from __future__ import annotations

import asyncio
import enum
import logging
import math
import time
import urllib.parse
from collections.abc import Callable
from dataclasses import dataclass

from drona_gcs.errors import DronaError, VehicleError

log = logging.getLogger(__name__)

DEFAULT_BAUD = 57600
_BAUDS = frozenset({9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 921600, 1500000, 2000000, 3000000})


class LinkUrlError(DronaError, ValueError):
    """A connection string that cannot be used; the message says why."""


class Scheme(enum.Enum):
    UDPIN = "udpin"  #: listen on host:port for datagrams
    UDPOUT = "udpout"  #: send datagrams to host:port
    TCP = "tcp"  #: connect to host:port
    SERIAL = "serial"  #: a serial device at a baud rate


@dataclass(frozen=True)
class LinkUrl:
    scheme: Scheme
    host: str = ""  #: network schemes: the address (an IPv6 one without brackets)
    port: int = 0  #: network schemes: the port
    device: str = ""  #: serial: the device path
    baud: int = 0  #: serial: the baud rate

    def __str__(self) -> str:
        if self.scheme is Scheme.SERIAL:
            return f"serial://{self.device}:{self.baud}"
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{self.scheme.value}://{host}:{self.port}"


def parse_link_url(text: str) -> LinkUrl:
    """Parse a connection string; raises :class:`LinkUrlError` naming the problem."""
    scheme_text, sep, rest = text.strip().partition("://")
    known = ", ".join(f"{s.value}://" for s in Scheme)
    if not sep:
        raise LinkUrlError(f"{text!r}: a connection string starts with a scheme, one of {known}")
    try:
        scheme = Scheme(scheme_text.lower())
    except ValueError:
        raise LinkUrlError(f"{text!r}: unknown scheme {scheme_text!r}, expected one of {known}") from None
    if scheme is Scheme.SERIAL:
        return _serial(text, rest)
    return _network(text, scheme, rest)


def _network(text: str, scheme: Scheme, rest: str) -> LinkUrl:
    if not rest or "/" in rest or "?" in rest or "#" in rest:
        raise LinkUrlError(f"{text!r}: expected {scheme.value}://host:port and nothing after the port")
    split = urllib.parse.urlsplit(f"//{rest}")
    try:
        port = split.port
    except ValueError:
        raise LinkUrlError(f"{text!r}: the port must be a number from 1 to 65535") from None
    host = split.hostname or ""
    if split.username is not None:
        raise LinkUrlError(f"{text!r}: user names are not supported")
    if not host:
        raise LinkUrlError(f"{text!r}: the host is missing (use 0.0.0.0 to listen on every interface)")
    if port is None:
        raise LinkUrlError(f"{text!r}: the port is missing, e.g. {scheme.value}://{host}:14540")
    if not 0 < port < 65536:
        raise LinkUrlError(f"{text!r}: the port must be a number from 1 to 65535")
    if scheme is not Scheme.UDPIN and host in ("0.0.0.0", "::"):
        raise LinkUrlError(f"{text!r}: {host} is a listening address; {scheme.value} needs the vehicle's address")
    return LinkUrl(scheme, host=host, port=port)


def _serial(text: str, rest: str) -> LinkUrl:
    device, sep, baud_text = rest.rpartition(":")
    if not sep or "/" in baud_text:  # no baud given (or the colon belongs to the path)
        device, baud_text = rest, ""
    if not device:
        raise LinkUrlError(f"{text!r}: the serial device is missing, e.g. serial:///dev/ttyUSB0:57600")
    if not baud_text:
        return LinkUrl(Scheme.SERIAL, device=device, baud=DEFAULT_BAUD)
    if not baud_text.isdigit() or int(baud_text) not in _BAUDS:
        raise LinkUrlError(f"{text!r}: unsupported baud rate {baud_text!r}, expected one of "
                           f"{', '.join(str(b) for b in sorted(_BAUDS))}")
    return LinkUrl(Scheme.SERIAL, device=device, baud=int(baud_text))


# ------------------------------------------------------------------ transports: bytes only
class _Datagrams(asyncio.DatagramProtocol):
    """udpout sends to its fixed peer (its connected socket hears nobody else). udpin answers the
    sender of the vehicle's HEARTBEAT, as the link vouches for it (:meth:`vouch`), and hears only
    that address while it is alive (vouched for within ``lost_after`` seconds): whoever else writes
    draws nothing. After that silence it hears anyone again, and locks on the next HEARTBEAT's sender."""

    def __init__(self, on_data: Callable[[bytes], None], peer: tuple[str, int] | None,
                 lost_after: float, clock: Callable[[], float]) -> None:
        self.on_data, self.peer, self.listening = on_data, peer, peer is None
        self.lost_after, self.clock = lost_after, clock
        self.transport: asyncio.DatagramTransport | None = None
        self.ignored = 0  #: datagrams dropped from other addresses than the vehicle's
        self._sender: tuple[str, int] | None = None  #: the address of the datagram being handed over
        self._vouched_at = -math.inf

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]  # 3.11's selector transport is no subclass

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        if self.listening and addr != self.peer and self.clock() - self._vouched_at <= self.lost_after:
            self.ignored += 1
            return
        self._sender = addr
        try:
            self.on_data(data)
        finally:
            self._sender = None

    def vouch(self) -> None:
        """The datagram being handed over carries the vehicle's HEARTBEAT: answer its sender."""
        if self.listening and self._sender is not None:
            self.peer, self._vouched_at = self._sender, self.clock()

    def error_received(self, exc: Exception) -> None:
        log.debug("udp %s: %s", self.peer, exc)  # ICMP unreachable: nobody listens there yet

    def send(self, data: bytes) -> None:
        if self.transport is not None and self.peer is not None and not self.transport.is_closing():
            # udpout's socket is connected to its peer: no address (a host name given would not match it)
            self.transport.sendto(data, self.peer if self.listening else None)

    def close(self) -> None:
        if self.transport is not None:
            self.transport.close()


class _Stream(asyncio.Protocol):
    """TCP or serial: one byte stream; once lost, the link opens a new one (PymavlinkLink)."""

    def __init__(self, on_data: Callable[[bytes], None], on_lost: Callable[[str], None]) -> None:
        self.on_data, self.on_lost = on_data, on_lost
        self.transport: asyncio.Transport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def data_received(self, data: bytes) -> None:
        self.on_data(data)

    def vouch(self) -> None:
        """A stream has one peer: nothing to lock."""

    def connection_lost(self, exc: Exception | None) -> None:
        self.on_lost(f"connection lost: {exc}" if exc else "connection closed by the vehicle")

    def send(self, data: bytes) -> None:
        if self.transport is not None and not self.transport.is_closing():
            self.transport.write(data)

    def close(self) -> None:
        if self.transport is not None:
            self.transport.close()


Transport = _Datagrams | _Stream  #: both have ``send(bytes)``, ``vouch()`` and ``close()``


async def open_transport(url: LinkUrl, on_data: Callable[[bytes], None], on_lost: Callable[[str], None],
                         lost_after: float = 3.0, clock: Callable[[], float] = time.monotonic) -> Transport:
    """Open ``url``; OSError and a missing serial package become VehicleError. ``lost_after``: how
    long udpin's vehicle may be silent before another address may take its place (on ``clock``)."""
    loop = asyncio.get_running_loop()
    try:
        if url.scheme is Scheme.UDPIN:
            _, udp = await loop.create_datagram_endpoint(lambda: _Datagrams(on_data, None, lost_after, clock),
                                                         local_addr=(url.host, url.port))
            return udp
        if url.scheme is Scheme.UDPOUT:
            peer = (url.host, url.port)
            _, udp = await loop.create_datagram_endpoint(lambda: _Datagrams(on_data, peer, lost_after, clock),
                                                         remote_addr=peer)
            return udp
        if url.scheme is Scheme.TCP:
            _, stream = await loop.create_connection(lambda: _Stream(on_data, on_lost), url.host, url.port)
            return stream
        try:
            import serial_asyncio  # type: ignore[import-untyped]  # no stubs
        except ImportError as exc:
            raise VehicleError(f"{url}: serial links need pyserial-asyncio "
                               "(pip install 'drona-gcs[serial]', or pip install pyserial-asyncio)") from exc
        serial = _Stream(on_data, on_lost)
        await serial_asyncio.create_serial_connection(loop, lambda: serial, url.device, baudrate=url.baud)
        return serial
    except OSError as exc:
        raise VehicleError(f"cannot open {url}: {exc.strerror or exc}") from exc
