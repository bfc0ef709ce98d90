"""What the fleet's long-running processes run on: the event loop, and the cyclic GC kept off what lives for good."""

from __future__ import annotations

import asyncio
import gc
from collections.abc import Coroutine
from typing import Any, TypeVar

T = TypeVar("T")


def run(main: Coroutine[Any, Any, T]) -> T:
    """``main`` on uvloop where it is installed (a dependency where uvicorn[standard] has it), else on
    asyncio's own loop.

    It pays where a process wakes for many small messages: 32 agents in 2 processes on this 2-core
    machine coordinated with a median latency of 19-20 ms on asyncio's loop, 10-13 ms on uvloop
    (``drona bench coordination``).
    """
    try:
        import uvloop
    except ImportError:
        return asyncio.run(main)
    return uvloop.run(main)


#: Objects allocated (less those freed) between two collections of the youngest generation; CPython's
#: default is 700. Messages, trajectories and tasks are freed by reference counting, cycles are rare,
#: so the collector mostly walks objects that are still in use.
YOUNG_COLLECTION_EVERY = 20_000


def settle_gc() -> None:
    """Once a process has built what lives for good (the planner's tables, the workspace, FastAPI's
    routes, Zenoh's and pydantic's objects), collect once and keep the cyclic GC from walking it again
    and again: full collections took 40-60 ms in a 16-drone agent process, stalling every coordination
    under way, and 50+ ms in the service. Then collect the young less often: when the whole fleet of
    32 drones coordinated at once, collections took 1.7-5.0 ms of each agent process's 85-135 ms
    (CPython's default), none at all in it or the 5 s after it (every 20000; one then has more to walk)."""
    gc.collect()
    gc.freeze()
    gc.set_threshold(YOUNG_COLLECTION_EVERY)
