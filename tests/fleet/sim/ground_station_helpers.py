"""Shared harness of the fake vehicle's ground-station tests (``test_ground_station_*.py``): the
sans-I/O model in either personality, and what it answers.
"""

from __future__ import annotations

from typing import Any

import pytest

from fleet.sim.config import VehicleConfig
from fleet.sim.fleet import placements
from fleet.sim.mav import mavlink2
from fleet.sim.model import VehicleModel
from fleet.sim.personality import ARDUPILOT, PX4, Personality
from tests.fleet.sim.vehicle_helpers import GCS, deliver

ML = mavlink2
BOTH = pytest.mark.parametrize("personality", [ARDUPILOT, PX4], ids=lambda p: p.name)
SENDER = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)


# ------------------------------------------------------------------ harness
def vehicle(personality: Personality, **settings: Any) -> VehicleModel:
    (place,) = placements(None, 1)
    settings.setdefault("ready_after_s", 0.001)
    return VehicleModel(VehicleConfig(personality=personality, **settings), place, 0.0)


def answers(model: VehicleModel, msg: Any, now: float = 1.0) -> list[Any]:
    """What the vehicle answers to ``msg``; every answer must encode (its fields within their types)."""
    out = deliver(model, msg, now)
    for reply in out:
        reply.pack(SENDER)
    return out


def param_set(model: VehicleModel, name: str, value: float, now: float = 1.0) -> list[Any]:
    return answers(model, GCS.param_set_encode(1, 1, name.encode(), value, ML.MAV_PARAM_TYPE_REAL32), now)
