"""The one place that imports pymavlink's MAVLink 2 ardupilotmega dialect (used to encode and decode only)."""

from __future__ import annotations

import os
from typing import Any

os.environ.setdefault("MAVLINK20", "1")  # for any mavutil imported later in this process

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

Message = mavlink2.MAVLink_message

#: Encodes message objects only (its ``*_encode`` methods touch no state): the vehicle's builders share it.
ENC = mavlink2.MAVLink(None)


def source(msg: Any) -> tuple[int, int]:
    """The sender's (system, component) of a message: where an answer to it is addressed."""
    return msg.get_srcSystem(), msg.get_srcComponent()


__all__ = ["ENC", "Message", "mavlink2", "source"]
