"""The event bus behind ``GET /v1/events`` (server-sent events).

Each subscriber has a bounded queue. A subscriber that falls ``queue_size``
events behind is dropped (its stream ends; EventSource reconnects by itself)
rather than letting it hold memory or slow the service. Payloads are built
lazily, once per event, and only when someone listens.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ServerEvent:
    kind: str  #: mail, drone, drone_lost
    data: str  #: JSON

    def encode(self) -> bytes:
        return f"event: {self.kind}\ndata: {self.data}\n\n".encode()


class Subscription:
    def __init__(self, size: int) -> None:
        self.queue: asyncio.Queue[ServerEvent | None] = asyncio.Queue(size + 1)
        self.size = size

    def offer(self, event: ServerEvent) -> bool:
        """Queue ``event``; False (and the stream is ended) if the subscriber is too far behind."""
        if self.queue.qsize() >= self.size:
            while not self.queue.empty():
                self.queue.get_nowait()
            self.queue.put_nowait(None)
            return False
        self.queue.put_nowait(event)
        return True


class EventBus:
    def __init__(self, queue_size: int = 10000) -> None:
        self.queue_size = queue_size
        self._subscribers: set[Subscription] = set()
        self.closed = False

    def publish(self, kind: str, data: Callable[[], str]) -> None:
        if not self._subscribers:
            return
        event = ServerEvent(kind, data())
        for sub in list(self._subscribers):
            if not sub.offer(event):
                log.warning("an /v1/events client fell %d events behind: dropped", self.queue_size)
                self._subscribers.discard(sub)

    def close(self) -> None:
        """End every stream (the service is stopping): each subscriber gets its end mark."""
        self.closed = True
        for sub in self._subscribers:
            while not sub.queue.empty():
                sub.queue.get_nowait()
            sub.queue.put_nowait(None)
        self._subscribers.clear()

    @contextmanager
    def subscribe(self) -> Iterator[Subscription]:
        sub = Subscription(self.queue_size)
        if self.closed:
            sub.queue.put_nowait(None)
        else:
            self._subscribers.add(sub)
        try:
            yield sub
        finally:
            self._subscribers.discard(sub)

    @property
    def subscribers(self) -> int:
        return len(self._subscribers)
