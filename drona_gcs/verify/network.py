"""The in-memory network the tester's world and the tests' ``ProtocolCluster`` run the agents over.

Sans-I/O like the machines it joins: it holds what is in flight and hands it out when told to, so a
caller (the tester's scheduler, or a test) decides the order of delivery. Its semantics:

* a bag, not a queue: any message in flight may come next, but for the liveliness notices;
* each message gets a number as it is posted; a duplicate is a new message, that came in the same
  session as its original (so it keeps its original's place before a leave);
* liveliness changes (:class:`Left`, :class:`Joined`) come in order, and a leave only after all that
  its sender sent the same drone before it (its lease outlasted them); a message sent after a leave
  comes after it;
* a message is lost only when its caller drops it (a crashed receiver, a cut across a partition).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from typing import Generic, TypeVar

_M = TypeVar("_M")


@dataclass(frozen=True)
class Left:
    """Liveliness: the sender's agent is gone, silent since its step ``since``."""

    since: int


@dataclass(frozen=True)
class Joined:
    """Liveliness: the sender's agent is back."""


@dataclass(frozen=True)
class InFlight(Generic[_M]):
    seq: int
    sender: str
    to: str
    message: _M
    deadline: int  #: the step by which it must be delivered (0 where the caller bounds no delay)
    sent: int = -1  #: the seq it was sent as (a duplicate keeps its original's); -1: ``seq``

    @property
    def sent_as(self) -> int:
        return self.seq if self.sent < 0 else self.sent

    @functools.cached_property
    def key(self) -> tuple[str, str, str, int]:
        """What it is in a state's key: not its number. Worked out once, as copies of a world share it."""
        return (self.sender, self.to, repr(self.message), self.deadline)


class Network(Generic[_M]):
    """The messages in flight, oldest first, and how many were ever posted (the last one's number)."""

    def __init__(self) -> None:
        self.inflight: list[InFlight[_M]] = []
        self.sent = 0

    def __len__(self) -> int:
        return len(self.inflight)

    def __iter__(self) -> Iterator[InFlight[_M]]:
        return iter(self.inflight)

    def copy(self) -> Network[_M]:
        """An independent copy (the messages themselves are immutable, and shared)."""
        new: Network[_M] = Network()
        new.inflight, new.sent = list(self.inflight), self.sent
        return new

    def key(self) -> tuple[tuple[str, str, str, int], ...]:
        """What is in flight, whatever the messages' numbers and the order they were posted in."""
        return tuple(sorted(m.key for m in self.inflight))

    def post(self, sender: str, to: str, message: _M, deadline: int = 0) -> InFlight[_M]:
        self.sent += 1
        posted = InFlight(self.sent, sender, to, message, deadline)
        self.inflight.append(posted)
        return posted

    def find(self, seq: int) -> InFlight[_M]:
        return next(m for m in self.inflight if m.seq == seq)

    def take(self, seq: int) -> InFlight[_M]:
        """Hand out message ``seq``: it is in flight no more."""
        return self.inflight.pop(next(i for i, m in enumerate(self.inflight) if m.seq == seq))

    def duplicate(self, seq: int) -> InFlight[_M]:
        """A second copy of message ``seq``, sent in its original's session."""
        original = self.find(seq)
        self.sent += 1
        # A copy of what was sent before a leave still comes before it (one session, in order).
        copy = replace(original, seq=self.sent, sent=original.sent_as)
        self.inflight.append(copy)
        return copy

    def drop(self, lost: Callable[[InFlight[_M]], bool]) -> list[InFlight[_M]]:
        """Lose every message in flight that ``lost`` says is lost; return them."""
        verdicts = [(m, lost(m)) for m in self.inflight]
        self.inflight = [m for m, gone in verdicts if not gone]
        return [m for m, gone in verdicts if gone]

    def deliverable(self) -> list[InFlight[_M]]:
        """The messages that may come next, oldest first (see the module's docstring)."""
        return [m for m in self.inflight if self.in_order(m)]

    def in_order(self, message: InFlight[_M]) -> bool:
        """Liveliness changes come in order, and a leave only once the lease outlasted every message
        its agent sent before: after all that went earlier from the same sender to the same drone.
        A message sent after a leave comes after it: the lease ran out while nothing came through
        (one sent after a join may come before it: the join is news of its own)."""
        same_way = [m for m in self.inflight if m.sender == message.sender and m.to == message.to]
        if not isinstance(message.message, (Left, Joined)):
            return not any(isinstance(m.message, Left) and m.seq < message.sent_as for m in same_way)
        return not any(m.sent_as < message.seq for m in same_way)
