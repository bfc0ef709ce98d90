"""Clock helpers for the edges (the core never reads a clock)."""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import AsyncIterator
from typing import Any


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
