"""What Zenoh's threads hand to one event loop, and the order the loop takes it in.

zenoh-python calls back on its own threads; :class:`Inbox` queues each callback for the loop, the
*urgent* ones (news a drone flying must act on: a peer's brake, its vehicle down, late or lost) before
all, then the *first* ones (protocol messages, which a coordinating drone waits on), then the
ordinary ones, one per turn of the loop. :func:`guarded` runs each: a handler's error is logged, never fatal.
"""

from __future__ import annotations

import asyncio
import collections
import logging
import threading
import time
import weakref
from collections.abc import Callable, Sequence
from typing import Any

log = logging.getLogger(__name__)

#: An ordinary item that has waited this long goes before the *first* ones: a process busy with
#: protocol messages for long (a fleet given mail at once) still takes mail orders, answers queries
#: and measures its clock.
ORDINARY_WAITS_AT_MOST_S = 0.05

_Item = tuple[float, str, Callable[..., None], Sequence[Any]]  #: (when handed in, node name, callback, args)


class Inbox:
    """What Zenoh's threads hand to one event loop: the *first* items, then the rest, each in
    arrival order (but an ordinary item never waits more than ``ORDINARY_WAITS_AT_MOST_S``). One
    item per turn of the loop, so that an item handed in while another is handled (an answer to
    a request being answered) is sorted in before the next is taken, and the loop's timers and
    tasks keep their turns."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = weakref.ref(loop)  # weak: the inbox is the loop's, and must not keep it alive
        self._lock = threading.Lock()  # Zenoh's threads put, the loop takes
        self._urgent: collections.deque[_Item] = collections.deque()
        self._first: collections.deque[_Item] = collections.deque()
        self._ordinary: collections.deque[_Item] = collections.deque()
        self._scheduled = False  #: a _take_one is queued on the loop

    def put(self, first: bool, name: str, callback: Callable[..., None], args: Sequence[Any],
            urgent: bool = False) -> None:
        loop = self._loop()
        if loop is None or loop.is_closed():
            return  # a session that outlived its loop: nobody is left to hand it to
        with self._lock:
            queue = self._urgent if urgent else self._first if first else self._ordinary
            queue.append((time.monotonic(), name, callback, args))
            if self._scheduled:
                return
            self._scheduled = True
        try:
            loop.call_soon_threadsafe(self._take_one)
        except RuntimeError:  # the loop closed under us during shutdown
            with self._lock:
                self._urgent.clear()
                self._first.clear()
                self._ordinary.clear()
                self._scheduled = False

    def backlog_s(self) -> float:
        """How long the oldest item still waiting for the loop has waited (0: none waits)."""
        with self._lock:
            oldest = min((q[0][0] for q in (self._urgent, self._first, self._ordinary) if q), default=None)
        return 0.0 if oldest is None else time.monotonic() - oldest

    def _take_one(self) -> None:
        with self._lock:
            ordinary = self._ordinary
            overdue = bool(ordinary) and time.monotonic() - ordinary[0][0] > ORDINARY_WAITS_AT_MOST_S
            queue = self._urgent or (ordinary if overdue or not self._first else self._first)
            _, name, callback, args = queue.popleft()
            more = self._scheduled = bool(self._urgent or self._first or ordinary)
        try:
            guarded(name, callback, args)
        finally:
            loop = self._loop()
            if more and loop is not None:  # else a put meanwhile has queued a new turn itself
                loop.call_soon(self._take_one)


#: One inbox per event loop, shared by every session the process has on it.
_INBOXES: weakref.WeakKeyDictionary[asyncio.AbstractEventLoop, Inbox] = weakref.WeakKeyDictionary()


def inbox_of(loop: asyncio.AbstractEventLoop) -> Inbox:
    """The loop's inbox (made on the loop's thread, as a node is: never raced for)."""
    found = _INBOXES.get(loop)
    if found is None:
        found = _INBOXES[loop] = Inbox(loop)
    return found


def guarded(name: str, callback: Callable[..., None], args: Sequence[Any]) -> None:
    """A handler's error is logged, never fatal: one bad message must not stop a drone."""
    try:
        callback(*args)
    except Exception:
        log.exception("%s: handler %s failed", name, getattr(callback, "__qualname__", callback))
