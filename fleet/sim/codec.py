"""pymavlink as a codec only: ``MAVLink(None, srcSystem=...)`` packs, ``parse_buffer(data) or ()`` unpacks.

One :class:`Codec` per vehicle encodes (and signs) everything it sends. Each link end
(the UDP socket, each TCP connection) gets its own decoder from :meth:`Codec.decoder`, since
a decoder keeps a partial-frame buffer. With a signing key, decoders accept unsigned
HEARTBEAT and RADIO_STATUS only (as ArduPilot does for RADIO_STATUS); anything else that is
unsigned or badly signed decodes as ``BAD_DATA``, which the model ignores.
"""

from __future__ import annotations

from fleet.sim.mav import Message, mavlink2
from fleet.vehicle.signing import signing_timestamp

#: Unsigned messages still accepted when signing is on.
UNSIGNED_OK = frozenset({mavlink2.MAVLINK_MSG_ID_HEARTBEAT, mavlink2.MAVLINK_MSG_ID_RADIO_STATUS})


def _allow_unsigned(mav: mavlink2.MAVLink, msg_id: int) -> bool:
    return msg_id in UNSIGNED_OK


class Codec:
    def __init__(self, system_id: int, component_id: int = mavlink2.MAV_COMP_ID_AUTOPILOT1,
                 signing_key: bytes | None = None, link_id: int = 0) -> None:
        self.key = signing_key
        self._enc = mavlink2.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        if signing_key is not None:
            self._sign(self._enc, link_id)
            self._enc.signing.sign_outgoing = True

    def encode(self, msg: Message) -> bytes:
        data: bytes = msg.pack(self._enc)
        self._enc.seq = (self._enc.seq + 1) % 256
        return data

    def decoder(self) -> mavlink2.MAVLink:
        dec = mavlink2.MAVLink(None)
        dec.robust_parsing = True  # bad bytes become BAD_DATA messages instead of exceptions
        if self.key is not None:
            self._sign(dec, 0)
            dec.signing.allow_unsigned_callback = _allow_unsigned
        return dec

    def _sign(self, mav: mavlink2.MAVLink, link_id: int) -> None:
        mav.signing.secret_key = self.key
        mav.signing.link_id = link_id
        mav.signing.timestamp = signing_timestamp()


def decode(decoder: mavlink2.MAVLink, data: bytes) -> list[Message]:
    return list(decoder.parse_buffer(data) or ())
