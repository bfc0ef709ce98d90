"""The fleet clock: a step of the system clock is taken up slowly, its drift followed."""

from __future__ import annotations

import pytest

from fleet.clock import MAX_SLEW, FleetClock


class _Clocks:
    def __init__(self) -> None:
        self.wall, self.monotonic = 1_000_000.0, 50.0

    def tick(self, seconds: float, drift: float = 0.0) -> None:
        self.monotonic += seconds
        self.wall += seconds * (1 + drift)


def test_a_step_of_the_system_clock_is_taken_up_at_the_slew_rate_only(caplog: pytest.LogCaptureFixture) -> None:
    clocks = _Clocks()
    clock = FleetClock(lambda: clocks.wall, lambda: clocks.monotonic)
    start = clock()
    clocks.tick(10.0)
    assert clock() == pytest.approx(start + 10.0)
    clocks.wall += 3.0  # stepped ahead in flight
    clocks.tick(0.05)
    assert clock() == pytest.approx(start + 10.05 + 0.05 * MAX_SLEW)
    assert "the system clock stepped by +3.000 s" in caplog.text
    for _ in range(100):
        clocks.tick(1.0)
        clock()
    assert clock() == pytest.approx(start + 110.05 + 100.05 * MAX_SLEW)  # 50 ms of the 3 s taken up
    assert caplog.text.count("stepped") == 1  # taken up, not stepped again
    clocks.wall -= 6.0  # and back, past where it was
    clocks.tick(1.0)
    assert clock() == pytest.approx(start + 111.05 + 99.05 * MAX_SLEW)
    assert "the system clock stepped by -6.000 s" in caplog.text


def test_the_system_clocks_drift_within_the_slew_rate_is_followed() -> None:
    clocks = _Clocks()
    clock = FleetClock(lambda: clocks.wall, lambda: clocks.monotonic)
    for _ in range(1000):
        clocks.tick(0.05, drift=MAX_SLEW / 2)
        now = clock()
    assert now == pytest.approx(clocks.wall, abs=1e-9)


def test_a_monotonic_clock_that_goes_back_counts_no_time_twice() -> None:
    clocks = _Clocks()
    clock = FleetClock(lambda: clocks.wall, lambda: clocks.monotonic)
    start = clock()
    clocks.monotonic -= 1.0  # never, for time.monotonic: a test's clock may
    assert clock() == pytest.approx(start, abs=1e-9)  # not a second back
    clocks.tick(2.0)
    clocks.wall -= 1.0  # 1 s went by since the clock was read: the wall clock says so too
    assert clock() == pytest.approx(start + 1.0, abs=1e-9)
