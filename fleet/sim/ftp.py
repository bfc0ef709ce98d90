"""MAVLink FTP (FILE_TRANSFER_PROTOCOL) for a fake vehicle that has no files.

Ground stations try FTP before the message protocols: MAVProxy asks for ``@PARAM/param.pck`` before
it sends PARAM_REQUEST_LIST, and waits about 10 s for an answer that never comes before it falls back.
The fake answers at once, as an autopilot does for a file it does not have: every request is refused
(NAK, ERR_FileNotFound) but the end of a session, which is acknowledged. (Real ArduPilot would serve
its parameters this way; the fake serves them by PARAM_VALUE only, see :mod:`fleet.sim.params`.)
"""

from __future__ import annotations

import struct
from typing import TYPE_CHECKING

from fleet.sim.mav import ENC, Message, source

if TYPE_CHECKING:
    from fleet.sim.model import VehicleModel

#: The header of the payload: seq, session, opcode, size, req_opcode, burst_complete, padding, offset.
HEADER = struct.Struct("<HBBBBBBI")
PAYLOAD_BYTES = 251
ACK, NAK = 128, 129
TERMINATE_SESSION, RESET_SESSIONS = 1, 2
ERR_FILE_NOT_FOUND = 10


def on_request(m: VehicleModel, msg: Message, now: float) -> list[Message]:
    seq, session, opcode = HEADER.unpack_from(bytes(msg.payload))[:3]
    if opcode in (ACK, NAK):
        return []  # a reply, not a request
    refused = opcode not in (TERMINATE_SESSION, RESET_SESSIONS)
    data = bytes([ERR_FILE_NOT_FOUND]) if refused else b""
    reply = HEADER.pack((seq + 1) % 0x10000, session, NAK if refused else ACK, len(data), opcode, 0, 0, 0) + data
    return [ENC.file_transfer_protocol_encode(0, *source(msg), reply.ljust(PAYLOAD_BYTES, b"\0"))]
