"""MAVLink frames out of bytes that may hold noise, truncated frames or forgeries.

pymavlink's own parser, even with ``robust_parsing``, trusts a frame's header: it takes the
length from it and consumes that many bytes, whatever they turn out to be. A truncated frame, or
a stray 0xFD in noise, then swallows the real frames behind it (up to 280 bytes), and a frame
whose message id it does not know passes with no CRC check at all. :class:`Deframer` uses
pymavlink only to decode one candidate frame at a time: a candidate that does not decode (bad
CRC or signature, unknown id: nothing vouches for it) costs one byte, and the scan goes on from
the next, so a real frame inside or behind it is still found. Nothing raises on bad bytes.

A datagram holds whole frames (MAVLink never splits one across datagrams): with ``whole``, the
bytes left at the end of a datagram are dropped, never joined to the next one.
"""

from __future__ import annotations

import re
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

Message = Any  # pymavlink's MAVLink_message: untyped

_MAGIC = re.compile(b"[\xfd\xfe]")  #: MAVLink 2 and MAVLink 1 start bytes
_V2 = 0xFD
_HEADER = {_V2: 10, 0xFE: 6}  #: start byte -> header length
_CRC = 2
_SIGNATURE = 13
_SIGNED = mavlink2.MAVLINK_IFLAG_SIGNED


class Deframer:
    """Turns bytes into the messages ``mav`` (a pymavlink MAVLink, maybe set up to check signatures)
    decodes; see the module docstring."""

    def __init__(self, mav: Any, whole: bool) -> None:
        self.mav, self.whole = mav, whole
        self.skipped = 0  #: bytes that began no frame
        self._rest = b""  #: a stream's incomplete frame, completed by the next bytes

    def feed(self, data: bytes) -> list[Message]:
        buf, self._rest = self._rest + data, b""
        out: list[Message] = []
        at = 0
        while (found := _MAGIC.search(buf, at)) is not None:
            start = found.start()
            self.skipped += start - at
            size = _frame_size(buf, start)
            if size is None or start + size > len(buf):
                if not self.whole:  # the rest of the frame is still on its way
                    self._rest = buf[start:]
                    return out
                size = 0
            msg = self._decode(bytearray(buf[start:start + size])) if size else None
            if msg is None:
                self.skipped += 1
                at = start + 1
                continue
            out.append(msg)
            at = start + size
        self.skipped += len(buf) - at
        return out

    def _decode(self, frame: bytearray) -> Message | None:
        """The frame's message, or None if nothing vouches for it."""
        stamps = self.mav.signing.stream_timestamps
        before = dict(stamps) if frame[0] == _V2 and frame[2] & _SIGNED else None
        try:
            msg = self.mav.decode(frame)
        except mavlink2.MAVError:
            if before is not None:  # pymavlink records a stream's timestamp before it checks the signature
                stamps.clear()
                stamps.update(before)
            return None
        return None if isinstance(msg, mavlink2.MAVLink_unknown) else msg


def _frame_size(buf: bytes, start: int) -> int | None:
    """The length of the frame starting at ``start`` as its header says (0: no frame can start
    there; None: the header is not all there yet)."""
    magic = buf[start]
    if len(buf) < start + 3:
        return None
    if magic != _V2:
        return _HEADER[magic] + buf[start + 1] + _CRC
    flags = buf[start + 2]
    if flags & ~_SIGNED:
        return 0
    return _HEADER[magic] + buf[start + 1] + _CRC + (_SIGNATURE if flags & _SIGNED else 0)
