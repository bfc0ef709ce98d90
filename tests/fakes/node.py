"""The node seam: :class:`FakeNode`, a :class:`~fleet.transport.node.Node` on an in-memory network.

In the style of httpx's ``MockTransport``: a real implementation of the port, small, that the test
programs. Every put is recorded, in order, and handed to the subscriptions whose key expression it
matches (Zenoh's ``*``, one chunk, and ``**``, any number), on the event loop as Zenoh's callbacks
are; a query is answered by the queryables it matches, then by ``answer``, the test's own
handler; tokens are alive until :meth:`FakeNetwork.drop` and watched as Zenoh's liveliness is.
Nodes on one :class:`FakeNetwork` see each other's; a node made alone has a network of its own.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from dataclasses import dataclass, field

from fleet.transport.node import QueryHandler, Reply, SampleHandler
from fleet.transport.wire import Body, decode

#: A test's answer to a query: (selector, payload) -> the replies, (key, payload) each.
Answer = Callable[[str, bytes], list[tuple[str, bytes]]]


def intersects(a: str, b: str) -> bool:
    """Whether two key expressions name a key in common (``*`` and ``**`` chunks; no partial wildcards)."""
    return _intersects(a.split("/"), b.split("/"))


def _intersects(a: list[str], b: list[str]) -> bool:
    if not a or not b:
        return all(chunk == "**" for chunk in a + b)
    if a[0] == "**":
        return _intersects(a[1:], b) or _intersects(a, b[1:])
    if b[0] == "**":
        return _intersects(a, b[1:]) or _intersects(a[1:], b)
    return (a[0] == b[0] or "*" in (a[0], b[0])) and _intersects(a[1:], b[1:])


@dataclass
class FakeQuery:
    """A query as a queryable's handler gets it: its payload, and the replies it was given."""

    payload: bytes = b""
    replies: list[tuple[str, bytes]] = field(default_factory=list)

    def reply(self, key_expr: str, payload: bytes) -> None:
        self.replies.append((key_expr, payload))


@dataclass
class FakeNetwork:
    """What the nodes on it declared: subscriptions, queryables, tokens and liveliness watchers."""

    subscriptions: list[tuple[str, SampleHandler]] = field(default_factory=list)
    queryables: list[tuple[str, QueryHandler]] = field(default_factory=list)
    tokens: list[str] = field(default_factory=list)
    watchers: list[tuple[str, Callable[[str, bool], None]]] = field(default_factory=list)
    #: keys watched for subscribers: each with its callback and whether a subscription matches it
    matching: list[tuple[str, Callable[[bool], None], list[bool]]] = field(default_factory=list)

    def deliver(self, key: str, payload: bytes) -> None:
        for expr, handler in list(self.subscriptions):
            if intersects(expr, key):
                asyncio.get_running_loop().call_soon(handler, key, payload)

    def announce(self, key: str, alive: bool) -> None:
        for expr, on_change in list(self.watchers):
            if intersects(expr, key):
                asyncio.get_running_loop().call_soon(on_change, key, alive)

    def subscribed(self, key: str, handler: SampleHandler) -> None:
        self.subscriptions.append((key, handler))
        for watched, on_change, matched in self.matching:
            if not matched[0] and intersects(key, watched):
                matched[0] = True
                asyncio.get_running_loop().call_soon(on_change, True)

    def drop(self, key: str) -> None:
        """The token ``key`` goes (its node left, or its lease ran out)."""
        self.tokens.remove(key)
        self.announce(key, False)


class FakeNode:
    """A node whose puts the test reads (``puts``) and whose queries it may answer (``answer``)."""

    def __init__(self, network: FakeNetwork | None = None, answer: Answer | None = None) -> None:
        self.network = network or FakeNetwork()
        self.answer = answer
        self.puts: list[tuple[str, bytes]] = []  #: (key, payload), in the order put

    def bodies(self, key: str) -> list[Body]:
        """The bodies of the messages put on ``key`` (a key expression), in order."""
        return [decode(payload).body for put, payload in self.puts if intersects(key, put)]

    # ------------------------------------------------------------ the port
    def subscribe(self, key: str, handler: SampleHandler, gather: bool = False, first: bool = False,
                  urgent: bool = False) -> None:
        self.network.subscribed(key, handler)

    def queryable(self, key: str, handler: QueryHandler) -> None:
        self.network.queryables.append((key, handler))

    def watch_liveliness(self, key: str, on_change: Callable[[str, bool], None], first: bool = False) -> None:
        self.network.watchers.append((key, on_change))
        for token in self.network.tokens:  # those already alive first, as with history=True
            if intersects(key, token):
                asyncio.get_running_loop().call_soon(on_change, token, True)

    def token(self, key: str) -> None:
        self.network.tokens.append(key)
        self.network.announce(key, True)

    def on_matching(self, key: str, on_change: Callable[[bool], None]) -> None:
        matched = any(intersects(expr, key) for expr, _ in self.network.subscriptions)
        self.network.matching.append((key, on_change, [matched]))
        if matched:  # as Zenoh's listener, which tells the status it finds
            asyncio.get_running_loop().call_soon(on_change, True)

    def put(self, key: str, payload: bytes, once: bool = False, now: bool = False) -> None:
        self.puts.append((key, payload))
        self.network.deliver(key, payload)

    async def get(self, selector: str, payload: bytes, timeout_s: float,
                  stamp: Callable[[], float] | None = None, block: bool = False) -> list[Reply]:
        query = FakeQuery(payload)
        for expr, handler in list(self.network.queryables):
            if intersects(expr, selector):
                handler(selector, payload, query)
        if self.answer is not None:
            query.replies.extend(self.answer(selector, payload))
        at = stamp() if stamp is not None else 0.0
        return [Reply(key, reply, at) for key, reply in query.replies]

    async def alive(self, key: str, timeout_s: float = 1.0) -> set[str]:
        return {token for token in self.network.tokens if intersects(key, token)}
