"""The one place that imports pymavlink's MAVLink 2 ardupilotmega dialect (used to encode and decode only)."""

from __future__ import annotations

import os

os.environ.setdefault("MAVLINK20", "1")  # for any mavutil imported later in this process

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

Message = mavlink2.MAVLink_message

__all__ = ["Message", "mavlink2"]
