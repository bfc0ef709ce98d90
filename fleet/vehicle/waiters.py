"""How the links wait without polling, bounded by a timeout and by the link's health: futures the
pymavlink backend's incoming messages resolve (an ACK, a HEARTBEAT, a text, a telemetry condition),
and conditions the MAVSDK backend re-checks at each update."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable
from typing import Any

from drona_gcs.errors import VehicleError

Message = Any  # pymavlink's MAVLink_message: untyped
SETPOINT_SENT = "(setpoint sent)"  #: a pseudo message type: waiters on it are resolved as setpoints go out


def any_message(msg: Message) -> bool:
    return True


class Waiters:
    """Who waits for which message; ``check_alive`` raises the link's failure, if any; ``who`` names the
    vehicle in a timeout's error."""

    def __init__(self, check_alive: Callable[[], None], who: Callable[[], str]) -> None:
        self.check_alive, self.who = check_alive, who
        self._waiting: dict[asyncio.Future[Message], tuple[str | None, Callable[[Message], bool]]] = {}

    def expect(self, kind: str | None, predicate: Callable[[Message], bool] = any_message) -> asyncio.Future[Message]:
        """A future resolved by the first ``kind`` message (any message: None) for which ``predicate`` holds."""
        future: asyncio.Future[Message] = asyncio.get_running_loop().create_future()
        self._waiting[future] = (kind, predicate)
        return future

    def resolve(self, kind: str, msg: Message) -> None:
        """Hand ``msg`` to the waiters on ``kind`` whose predicate holds (a predicate's error goes to its waiter)."""
        for future, (wanted, predicate) in list(self._waiting.items()):
            if future.done() or (wanted != kind and (wanted is not None or kind == SETPOINT_SENT)):
                continue
            try:
                if predicate(msg):
                    future.set_result(msg)
            except Exception as exc:  # the waiter's own bug: it raises there, not in the protocol callback
                future.set_exception(exc)

    def fail(self, error: VehicleError) -> None:
        """Every wait under way raises ``error``."""
        for future in list(self._waiting):
            if not future.done():
                future.set_exception(error)

    async def wait(self, future: asyncio.Future[Message], timeout: float) -> Message:
        """The future's message; TimeoutError after ``timeout``; VehicleError if the link fails meanwhile."""
        try:
            self.check_alive()
            return await asyncio.wait_for(future, timeout)
        finally:
            self._waiting.pop(future, None)
            future.cancel()

    async def until(self, kind: str | None, predicate: Callable[[Message], bool], timeout: float, what: str,
                    detail: Callable[[], str] = str) -> Message:
        """The first ``kind`` message for which ``predicate`` holds (see :meth:`expect`), with a VehicleError
        naming ``what`` after ``timeout``."""
        try:
            return await self.wait(self.expect(kind, predicate), timeout)
        except TimeoutError:
            raise VehicleError(f"{self.who()}: waited {timeout} s for {what}{detail()}") from None


class Updates:
    """Conditions re-checked at each update: the MAVSDK backend's waits (its callbacks bring values,
    not messages to match). ``check_alive`` and ``who`` as for :class:`Waiters`."""

    def __init__(self, check_alive: Callable[[], None], who: Callable[[], str]) -> None:
        self.check_alive, self.who = check_alive, who
        self._tick = asyncio.Event()  #: replaced after each update; waiters re-check their condition

    def notify(self) -> None:
        self._tick.set()
        self._tick = asyncio.Event()

    async def until(self, condition: Callable[[], bool], timeout: float) -> bool:
        """Whether ``condition`` holds within ``timeout``, re-checked on each update; VehicleError if the link fails."""
        deadline = asyncio.get_running_loop().time() + timeout
        while True:
            self.check_alive()
            if condition():
                return True
            remaining = deadline - asyncio.get_running_loop().time()
            if remaining <= 0:
                return False
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._tick.wait(), remaining)

    async def wait_for(self, condition: Callable[[], bool], timeout: float, what: str,
                       detail: Callable[[], str] = str) -> None:
        """As :meth:`until`, with a VehicleError naming ``what`` after ``timeout``."""
        if not await self.until(condition, timeout):
            raise VehicleError(f"{self.who()}: waited {timeout} s for {what}{detail()}")
