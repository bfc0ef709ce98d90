"""One log line per kind of trouble and period, however often it comes: a flood of bad messages
must not become a flood of log lines."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Hashable

PERIOD_S = 10.0


class Throttled:
    """``warning(kind, ...)`` logs at most once per ``period_s`` for each ``kind``, saying how many it
    left out since."""

    def __init__(self, log: logging.Logger, period_s: float = PERIOD_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.log, self.period_s, self.clock = log, period_s, clock
        self._last: dict[Hashable, float] = {}
        self._left_out: dict[Hashable, int] = {}

    def warning(self, kind: Hashable, message: str, *args: object) -> None:
        now = self.clock()
        last = self._last.get(kind)
        if last is not None and now - last < self.period_s:
            self._left_out[kind] = self._left_out.get(kind, 0) + 1
            return
        self._last[kind] = now
        left_out = self._left_out.pop(kind, 0)
        if left_out and last is not None:
            message += f" (and {left_out} more like it in the last {now - last:.0f} s)"
        self.log.warning(message, *args)
