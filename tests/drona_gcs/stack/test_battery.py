"""The battery model and the battery monitor's two events, with hysteresis."""

from __future__ import annotations

import math
from typing import Any

import pytest

from drona_gcs.errors import ProblemError
from drona_gcs.stack.battery import (
    BatteryEvent,
    BatteryLow,
    BatteryModel,
    BatteryMonitor,
    BatteryRecharged,
    BatteryState,
)


def feed(monitor: BatteryMonitor, levels: list[float]) -> list[tuple[float, list[BatteryEvent]]]:
    """Each reading with the events it caused, only where it caused some."""
    return [(level, events) for level in levels if (events := list(monitor.reading(level)))]


def test_low_once_when_crossing_below_the_low_mark() -> None:
    monitor = BatteryMonitor(low=40, recharged=95)
    assert feed(monitor, [100, 70, 40]) == []  # at the mark is not below it
    assert monitor.reading(39.5) == [BatteryLow(39.5)]
    assert monitor.state is BatteryState.LOW
    assert feed(monitor, [39, 30, 25.5, 20]) == []  # staying low says nothing more


def test_recharged_once_at_the_recharged_mark() -> None:
    monitor = BatteryMonitor(low=40, recharged=95)
    monitor.reading(30)
    assert feed(monitor, [50, 80, 94.9]) == []  # charging, not yet recharged
    assert monitor.reading(95) == [BatteryRecharged(95)]
    assert monitor.state is BatteryState.OK
    assert feed(monitor, [100, 96, 95]) == []


def test_hysteresis_no_chatter_around_the_low_mark() -> None:
    monitor = BatteryMonitor(low=40, recharged=95)
    wobble = [41, 39, 41, 39.9, 40, 38, 45, 39, 60, 39]
    assert feed(monitor, wobble) == [(39, [BatteryLow(39)])]
    # a full cycle later it can go low again
    assert feed(monitor, [99, 50, 20]) == [(99, [BatteryRecharged(99)]), (20, [BatteryLow(20)])]


def test_a_first_reading_already_low_is_reported() -> None:
    monitor = BatteryMonitor(low=40, recharged=95)
    assert monitor.reading(0) == [BatteryLow(0)]
    assert monitor.reading(100) == [BatteryRecharged(100)]


@pytest.mark.parametrize("level", [-0.1, 100.5, -50, math.nan, math.inf])
def test_bad_readings_are_errors(level: float) -> None:
    monitor = BatteryMonitor()
    with pytest.raises(ProblemError, match="percentage"):
        monitor.reading(level)
    assert monitor.state is BatteryState.OK


@pytest.mark.parametrize(("low", "recharged"), [(40, 40), (95, 40), (50, 49.9)])
def test_marks_must_leave_room_for_hysteresis(low: float, recharged: float) -> None:
    with pytest.raises(ProblemError, match="below"):
        BatteryMonitor(low=low, recharged=recharged)


@pytest.mark.parametrize(("kwargs", "problem"), [
    ({"drain_per_step": 0}, "rates"), ({"drain_per_step": -1}, "rates"), ({"charge_per_step": 0}, "rates"),
    ({"safe_threshold": -1}, "threshold"), ({"safe_threshold": 100}, "threshold"),
])
def test_bad_models_are_errors(kwargs: dict[str, Any], problem: str) -> None:
    with pytest.raises(ProblemError, match=problem):
        BatteryModel(**kwargs)


@pytest.mark.parametrize(("model", "level", "steps"), [
    (BatteryModel(), 100, 80),  # 1 % a step down to the 20 % floor
    (BatteryModel(), 20.9, 0),  # less than a whole step above the floor
    (BatteryModel(), 21, 1),
    (BatteryModel(), 20, 0),
    (BatteryModel(), 5, 0),  # below the floor: nothing, never negative
    (BatteryModel(drain_per_step=2.5, safe_threshold=10), 60, 20),
    (BatteryModel(drain_per_step=2.5, safe_threshold=10), 59, 19),  # whole steps only, rounded down
    (BatteryModel(safe_threshold=0), 0, 0),
])
def test_steps_affordable(model: BatteryModel, level: float, steps: int) -> None:
    assert model.steps_affordable(level) == steps
    # flying that many steps never takes the battery below the floor; one more would
    assert level - steps * model.drain_per_step >= min(level, model.safe_threshold)
    if level > model.safe_threshold:
        assert level - (steps + 1) * model.drain_per_step < model.safe_threshold
