"""What the fleet's long-running processes run on: the event loop, and the cyclic GC kept off what lives for good."""

from __future__ import annotations

import asyncio
import gc
from collections.abc import Coroutine
from typing import Any, TypeVar

T = TypeVar("T")


def run(main: Coroutine[Any, Any, T]) -> T:
    """``main`` on uvloop where it is installed (a dependency where uvicorn[standard] has it), else on
    asyncio's own loop. It pays where a process wakes for many small messages (``drona bench
    coordination`` shows by how much)."""
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
    and again: a full collection stalls every coordination under way. Then collect the young less
    often, so that a fleet coordinating at once is not stopped for them."""
    gc.collect()
    gc.freeze()
    gc.set_threshold(YOUNG_COLLECTION_EVERY)
