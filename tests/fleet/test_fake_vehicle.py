"""The vehicle seam's fake (tests.fakes.vehicle): it refuses what ArduCopter refuses, unless programmed."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable

import pytest

from drona_gcs.errors import VehicleCommandRejected
from fleet.vehicle.link import Autopilot, LandedState
from tests.fakes.vehicle import FakeVehicle

FAILED = 4  #: MAV_RESULT_FAILED


def on_the_ground(**state: object) -> FakeVehicle:
    """An ArduCopter armed in GUIDED on the ground (it may take off), then ``state`` set on it."""
    vehicle = FakeVehicle()
    vehicle.landed = LandedState.ON_GROUND
    for name, value in state.items():
        setattr(vehicle, name, value)
    return vehicle


def refusal(command: Callable[[], Awaitable[None]]) -> VehicleCommandRejected | None:
    try:
        asyncio.run(command())  # type: ignore[arg-type]
    except VehicleCommandRejected as refused:
        return refused
    return None


@pytest.mark.parametrize("state", [{"armed": False}, {"mode": "STABILIZE"}, {"landed": LandedState.IN_AIR},
                                   {"landed": LandedState.LANDING}])
def test_a_takeoff_arducopter_refuses_is_refused_with_failed(state: dict[str, object]) -> None:
    vehicle = on_the_ground(**state)
    refused = refusal(lambda: vehicle.takeoff(5.0))
    assert refused is not None and refused.result == FAILED
    assert vehicle.landed is not LandedState.TAKEOFF and vehicle.commands == ["NAV_TAKEOFF"]


def test_a_takeoff_arducopter_takes_is_taken_unless_programmed() -> None:
    vehicle = on_the_ground()
    assert refusal(lambda: vehicle.takeoff(5.0)) is None and vehicle.landed is LandedState.TAKEOFF
    programmed = on_the_ground()
    programmed.refuse["NAV_TAKEOFF"] = 2  # MAV_RESULT_DENIED
    refused = refusal(lambda: programmed.takeoff(5.0))
    assert refused is not None and refused.result == 2


def test_arming_in_guided_needs_a_position_estimate() -> None:
    vehicle = on_the_ground(armed=False, estimate=False)
    refused = refusal(vehicle.arm)
    assert refused is not None and refused.result == FAILED and refused.reason == "Arm: Need Position Estimate"
    assert not vehicle.armed
    for state in ({"estimate": True}, {"mode": "STABILIZE"}, {"autopilot": Autopilot.PX4, "mode": "OFFBOARD"}):
        other = on_the_ground(**{"armed": False, "estimate": False, **state})
        assert refusal(other.arm) is None and other.armed, state
