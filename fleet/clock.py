"""Clock helpers for the edges (the core never reads a clock)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import threading
import time
from collections.abc import AsyncIterator, Callable
from typing import Any

log = logging.getLogger(__name__)

#: How fast the fleet clock takes up a step of the system clock, seconds a second: ntpd's bound on
#: slewing. The system clock's own drift, which NTP corrects within it, is followed exactly.
MAX_SLEW = 0.0005
STEP_NOTICED_S = 0.01  #: a step of the system clock this large is logged


class FleetClock:
    """The system clock as a drone's schedule reads it: it never steps.

    A plan is a timed trajectory; a system clock stepped in flight (NTP, GPS time, an operator) would
    fly it early or stall it, by more than the fleet's window. So the step is taken up at most
    ``max_slew`` seconds a second, on the monotonic clock; meanwhile the fleet's clock check measures
    what is left, against beta, as it measures any skew.
    """

    def __init__(self, wall: Callable[[], float] = time.time, monotonic: Callable[[], float] = time.monotonic,
                 max_slew: float = MAX_SLEW) -> None:
        self._wall, self._monotonic, self._max_slew = wall, monotonic, max_slew
        self._at, self._now = monotonic(), wall()
        self._behind = 0.0  #: what is left of the steps being taken up
        self._lock = threading.Lock()  # Zenoh's threads stamp queries with it too

    def __call__(self) -> float:
        with self._lock:
            at, wall = max(self._at, self._monotonic()), self._wall()
            free = self._now + (at - self._at)
            room, gap = self._max_slew * (at - self._at), wall - free
            if abs(gap - self._behind) > STEP_NOTICED_S:
                log.warning("the system clock stepped by %+.3f s: the fleet clock takes it up at %g ms a second",
                            gap - self._behind, self._max_slew * 1000)
            taken = max(-room, min(room, gap))
            self._at, self._now, self._behind = at, free + taken, gap - taken
            return self._now


def step_at(t: float, epoch: float, tau: float) -> int:
    """The step under way at time ``t``: step k starts at ``epoch + k * tau``."""
    return math.floor((t - epoch) / tau)


async def periodic(period: float) -> AsyncIterator[None]:
    """Yield every ``period`` seconds of the event loop's clock, skipping ticks that were missed."""
    loop = asyncio.get_running_loop()
    next_at = loop.time()
    while True:
        yield
        next_at = max(next_at + period, loop.time())
        await asyncio.sleep(next_at - loop.time())


async def cancel_all(tasks: list[asyncio.Task[Any]]) -> None:
    """Cancel ``tasks`` and wait until each has finished; the list is emptied."""
    for task in tasks:
        task.cancel()
    for task in tasks:
        with contextlib.suppress(asyncio.CancelledError):
            await task
    tasks.clear()
