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


def settle_gc() -> None:
    """Once a process has built what lives for good (the planner's tables, the workspace, FastAPI's
    routes, Zenoh's and pydantic's objects), collect once and keep the cyclic GC from walking it again
    and again: full collections took 40-60 ms in a 16-drone agent process, stalling every coordination
    under way, and 50+ ms in the service."""
    gc.collect()
    gc.freeze()
