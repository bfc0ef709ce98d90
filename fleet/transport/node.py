"""One Zenoh session for asyncio: its declarations, what it sends and asks, and its orderly close.

zenoh-python calls back on its own threads. Every callback here only hands
the sample (key and bytes) to the event loop, through the loop's inbox
(:class:`~fleet.transport.inbox.Inbox`); the handlers run on the loop, one at a time, like
everything else in the process. A subscription may go *first*: its samples
are handed round before those of ordinary ones already waiting, and an *urgent*
one before those too. The agents' protocol messages go first (see fleet.agent.drone):
a drone that coordinates waits on them, while states and mail can wait their turn
when the whole fleet asks at once; a peer's brake, or its vehicle down, late or lost,
is urgent: a drone flying must act on it. Protocol messages are put with congestion control BLOCK: the
default, DROP, loses messages of a burst. They are batched (Zenoh's default), not express: an idle
ping-pong favours express puts, but under a fleet coordinating at once an express put holds the
event loop two to three times as long (``drona bench coordination`` ran no slower batched).

Drones hosted in one process with ``--shared-session`` share one session
(:meth:`ZenohNode.view`; by default each drone has a session of its own, and a
view of it): each has its own declarations, and subscriptions to one key share one Zenoh
subscriber, so a broadcast crosses into Python once per process. A put reaches the session's
own subscriptions straight through the loop's inbox, Zenoh carrying it only to other sessions.
A subscription may *gather* the puts its handlers make into one message per key
(:mod:`fleet.transport.gather`). The session's configuration is :mod:`fleet.transport.settings`.

Closing undeclares every declaration, newest first, before the session:
a callback subscriber still declared at interpreter exit hangs it.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import zenoh

from drona_gcs.errors import DronaError, mapped
from fleet.logs import Throttled
from fleet.transport.gather import FRAME_END, Gathered, in_runs
from fleet.transport.inbox import guarded, inbox_of

if TYPE_CHECKING:
    from fleet.transport.settings import ZenohSettings

log = logging.getLogger(__name__)


class TransportError(DronaError):
    """Zenoh failed: the message says what was being done (configure, open, declare, put, ask)."""


def zenoh_errors(what: str) -> contextlib.AbstractContextManager[None]:
    """Zenoh's errors as :class:`TransportError` saying ``what`` was being done: the one place they are mapped."""
    return mapped(zenoh.ZError, TransportError, what)


class Query(Protocol):
    """What a queryable's handler gets (a zenoh.Query, or a test double)."""

    @property
    def payload(self) -> Any: ...

    def reply(self, key_expr: str, payload: bytes) -> None: ...


@dataclass(frozen=True)
class Reply:
    key: str
    payload: bytes
    at: float  #: when it arrived (the caller's stamp)


SampleHandler = Callable[[str, bytes], None]
QueryHandler = Callable[[str, bytes, Query], None]


class Node(Protocol):
    """What a drone's agent needs of its Zenoh node (:class:`ZenohNode` is one; tests pass a fake)."""

    def subscribe(self, key: str, handler: SampleHandler, gather: bool = False, first: bool = False,
                  urgent: bool = False) -> None: ...

    def queryable(self, key: str, handler: QueryHandler) -> None: ...

    def watch_liveliness(self, key: str, on_change: Callable[[str, bool], None], first: bool = False) -> None: ...

    def token(self, key: str) -> None: ...

    def on_matching(self, key: str, on_change: Callable[[bool], None]) -> None: ...

    def put(self, key: str, payload: bytes, once: bool = False, now: bool = False) -> None: ...

    async def get(self, selector: str, payload: bytes, timeout_s: float,
                  stamp: Callable[[], float] | None = None, block: bool = False) -> list[Reply]: ...

    async def alive(self, key: str, timeout_s: float = 1.0) -> set[str]: ...


class ZenohNode:
    """A session and its declarations; callbacks delivered on ``loop``."""

    def __init__(self, session: zenoh.Session, loop: asyncio.AbstractEventLoop, name: str,
                 owner: ZenohNode | None = None) -> None:
        self.session, self.loop, self.name = session, loop, name
        self.owner = owner  #: the node that opened the session (None: this one)
        #: Subscriptions of the session's nodes, one Zenoh subscriber per key (kept by the owner).
        self._fanouts: dict[str, _Fanout] = owner._fanouts if owner is not None else {}
        #: put key -> the session's own subscriptions it reaches, handed its puts directly (shared too)
        self._local: dict[str, list[_Fanout]] = owner._local if owner is not None else {}
        self._inbox = inbox_of(loop)
        self._subscribed: list[tuple[str, SampleHandler]] = []
        self._declared: list[Any] = []
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._pending: set[asyncio.Future[None]] = set()  #: queries waiting for their last reply
        self._gathered: Gathered | None = None  #: puts held while a gathering sample is handed round
        self.closed = False
        self.max_frames: int | None = None  #: see ZenohSettings.max_frames
        self._refused = Throttled(log)

    def view(self, name: str) -> ZenohNode:
        """A node on the same session with declarations of its own: closing it undeclares them and
        leaves the session open. Drones hosted in one process can share a session this way: one set of
        links between processes instead of one per pair of drones, and a message between two of
        them never leaves the process: it is handed to the loop at once (see :meth:`_reached`)."""
        return ZenohNode(self.session, self.loop, name, owner=self.owner or self)

    @classmethod
    async def open(cls, settings: ZenohSettings, name: str) -> ZenohNode:
        """Open a session (in a thread: opening blocks while Zenoh tries the connect endpoints)."""
        config = settings.config()
        with zenoh_errors(f"{name}: cannot open a Zenoh session"):
            session = await asyncio.to_thread(zenoh.open, config)
        node = cls(session, asyncio.get_running_loop(), name)
        node.max_frames = settings.max_frames
        return node

    # ------------------------------------------------------ declarations
    def subscribe(self, key: str, handler: SampleHandler, gather: bool = False, first: bool = False,
                  urgent: bool = False) -> None:
        """``handler(key, payload)`` on the loop for every sample under ``key``.

        The nodes of one session that subscribe to the same key share one Zenoh subscriber: a
        message to every drone of a host crosses to Python once and wakes the loop once.
        ``gather``: the session's puts made while a sample is handed round go out together
        (see the module docstring). ``first``: its samples are handed round before the others
        waiting for the loop; ``urgent``: before those too. The first subscription to a key decides.
        """
        fanout = self._fanouts.get(key)
        if fanout is None:
            fanout = self._fanout(key, gather, first, urgent)
        fanout.handlers.append(handler)
        self._subscribed.append((key, handler))

    def _fanout(self, key: str, gather: bool, first: bool, urgent: bool) -> _Fanout:
        """A new Zenoh subscriber for ``key``, kept once declared."""
        fanout = _Fanout(self.name, gather=gather, first=first, urgent=urgent)
        root = self.owner or self  # open as long as the session is, whichever node subscribed first

        def on_sample(sample: zenoh.Sample) -> None:
            root._to_loop(root._hand_round, fanout, str(sample.key_expr), sample.payload.to_bytes(),
                          first=fanout.first, urgent=fanout.urgent)

        with zenoh_errors(f"{self.name}: subscribe to {key}"):
            fanout.subscriber = self.session.declare_subscriber(key, on_sample)
        self._fanouts[key] = fanout
        self._local.clear()
        return fanout

    def queryable(self, key: str, handler: QueryHandler) -> None:
        """``handler(key, payload, query)`` on the loop; it must reply (or not) at once."""

        def on_query(query: zenoh.Query) -> None:
            payload = query.payload.to_bytes() if query.payload is not None else b""
            self._to_loop(self._answer, handler, str(query.key_expr), payload, query)

        with zenoh_errors(f"{self.name}: answer on {key}"):
            self._declared.append(self.session.declare_queryable(key, on_query))

    def _answer(self, handler: QueryHandler, key: str, payload: bytes, query: zenoh.Query) -> None:
        try:
            with zenoh_errors(f"{self.name}: reply on {key}"):  # the handler's replies
                handler(key, payload, query)
        finally:
            query.drop()  # type: ignore[no-untyped-call]  # ends the query once every reply is sent

    def linked(self) -> bool:
        """Whether the session has a link to another Zenoh peer or router (an open session may have none:
        nobody listens where it connects yet, or every link was cut)."""
        if self.closed:
            return False
        try:
            with zenoh_errors(f"{self.name}: links"):
                info = self.session.info
                return any(True for _ in info.peers_zid()) or any(True for _ in info.routers_zid())
        except TransportError:  # closed under us
            return False

    def token(self, key: str) -> None:
        with zenoh_errors(f"{self.name}: declare token {key}"):
            self._declared.append(self.session.liveliness().declare_token(key))

    def on_matching(self, key: str, on_change: Callable[[bool], None]) -> None:
        """``on_change(matching)`` whenever whether a subscriber anywhere would get a put on ``key`` changes.

        The route itself, not its owner's liveliness: after a link heals, a peer's token can come
        before its subscriptions, and a put made between the two is lost."""

        def on_status(status: zenoh.MatchingStatus) -> None:
            self._to_loop(on_change, status.matching)

        with zenoh_errors(f"{self.name}: watch the subscribers of {key}"):
            publisher = self.session.declare_publisher(key)
            self._declared.append(publisher)
            self._declared.append(publisher.declare_matching_listener(on_status))

    def watch_liveliness(self, key: str, on_change: Callable[[str, bool], None], first: bool = False) -> None:
        """``on_change(key, alive)`` for every token under ``key``, those already alive first. ``first``:
        handed round with the first subscriptions' samples, in the order they all came (see subscribe)."""

        def on_sample(sample: zenoh.Sample) -> None:
            self._to_loop(on_change, str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT, first=first)

        with zenoh_errors(f"{self.name}: watch tokens {key}"):
            self._declared.append(self.session.liveliness().declare_subscriber(key, on_sample, history=True))

    def _hand_round(self, fanout: _Fanout, key: str, payload: bytes) -> None:
        """(On the session's root.) Each frame of a sample to the fanout's handlers; the puts they
        make meanwhile gathered if the fanout gathers (and not already gathering: one level)."""
        frames = [f for f in payload.split(FRAME_END) if f] if FRAME_END in payload else [payload]
        if self.max_frames is not None and len(frames) > self.max_frames:
            self._refused.warning(key, "%s: refused a sample of %d messages on %s (at most %d: one per drone)",
                                  self.name, len(frames), key, self.max_frames)
            return
        if not fanout.gather or self._gathered is not None:
            for frame in frames:
                fanout.deliver(key, frame)
            return
        self._gathered = Gathered()
        try:
            for frame in frames:
                fanout.deliver(key, frame)
        finally:
            gathered, self._gathered = self._gathered, None
            self._send_runs(gathered.due())

    def _send_runs(self, runs: list[tuple[str, list[bytes]]]) -> None:
        for to, parts in runs:
            for chunk in in_runs(parts, self.max_frames):  # a peer refuses a sample of more
                try:
                    self._put(to, FRAME_END.join(chunk))
                except TransportError as exc:  # one key's failure must not lose the others'
                    log.warning("could not send %d message(s): %s", len(chunk), exc)

    # -------------------------------------------------------------- send
    def put(self, key: str, payload: bytes, once: bool = False, now: bool = False) -> None:
        """Reliable; blocks rather than drop when the link is congested. ``once``: a key used
        once (a mail's status), put without declaring a publisher that would live on. While the
        session hands round a gathering sample, held and sent with the other puts to ``key``, unless
        ``now``: a key only this node puts to gathers nothing, and peers may wait on it (what this node
        put before goes first)."""
        if self.closed:
            return
        if FRAME_END in payload:
            raise ValueError(f"{self.name}: a payload for {key} holds a newline, the transport's frame end")
        root = self.owner or self
        if root._gathered is not None and not once:
            if not now:
                root._gathered.add(self.name, key, payload)
                return
            root._send_runs(root._gathered.due(self.name))
        self._put(key, payload, once)

    def _put(self, key: str, payload: bytes, once: bool = False) -> None:
        if self.closed:
            return
        with zenoh_errors(f"{self.name}: put on {key}"):
            self._put_now(key, payload, once)

    def _put_now(self, key: str, payload: bytes, once: bool) -> None:
        if once:
            self.session.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)
            return
        publisher = self._publishers.get(key)
        if publisher is None:
            publisher = self.session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK,
                                                       allowed_destination=zenoh.Locality.REMOTE)
            self._publishers[key] = publisher
            self._declared.append(publisher)
        publisher.put(payload)
        root = self.owner or self
        for fanout in self._reached(key):
            root._to_loop(root._hand_round, fanout, key, payload, first=fanout.first, urgent=fanout.urgent)

    def _reached(self, key: str) -> list[_Fanout]:
        """The session's own subscriptions a put on ``key`` reaches: handed it on the loop
        straight away, not through Zenoh's threads (which a busy process starves for milliseconds)."""
        reached = self._local.get(key)
        if reached is None:
            put = zenoh.KeyExpr(key)
            reached = self._local[key] = [f for k, f in self._fanouts.items() if zenoh.KeyExpr(k).intersects(put)]
        return reached

    async def get(self, selector: str, payload: bytes, timeout_s: float,
                  stamp: Callable[[], float] | None = None, block: bool = False) -> list[Reply]:
        """Every reply to a query, once all have come (or ``timeout_s`` passed).

        ``stamp()`` is read on Zenoh's thread as each reply arrives (for round trips).
        """
        replies: list[Reply] = []

        def on_reply(reply: zenoh.Reply) -> None:
            if reply.ok is not None:
                at = stamp() if stamp is not None else 0.0
                self._to_loop(replies.append, Reply(str(reply.ok.key_expr), reply.ok.payload.to_bytes(), at))

        # An agent's own queries (clocks, held mail) are not sent with BLOCK: a congested link (a
        # peer that stopped reading) would block this call, and the drone's event loop with it,
        # until the lease ran out; dropped, they are asked again. ``block``: a client's mail order.
        congestion = zenoh.CongestionControl.BLOCK if block else zenoh.CongestionControl.DROP
        await self._until_done(lambda handler: self.session.get(
            selector, handler, payload=payload, timeout=timeout_s, congestion_control=congestion), on_reply)
        return replies

    async def alive(self, key: str, timeout_s: float = 1.0) -> set[str]:
        """The keys of the liveliness tokens alive now under ``key``."""
        keys: list[str] = []

        def on_reply(reply: zenoh.Reply) -> None:
            if reply.ok is not None:
                self._to_loop(keys.append, str(reply.ok.key_expr))

        await self._until_done(lambda handler: self.session.liveliness().get(key, handler, timeout=timeout_s),
                               on_reply)
        return set(keys)

    async def _until_done(self, start: Callable[[zenoh.handlers.Callback[zenoh.Reply]], object],
                          on_reply: Callable[[zenoh.Reply], None]) -> None:
        done: asyncio.Future[None] = self.loop.create_future()

        def on_end() -> None:
            # Queued behind the replies' own hand-overs, so all are in when it resolves.
            self._to_loop(_finish, done)

        if self.closed:
            raise TransportError(f"{self.name}: the Zenoh session is closed")
        self._pending.add(done)
        try:
            with zenoh_errors(f"{self.name}: ask"):
                start(zenoh.handlers.Callback(on_reply, on_end))
            await done
        finally:
            self._pending.discard(done)

    # ------------------------------------------------------------- close
    async def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        for waiting in self._pending:  # queries under way end with what they got
            _finish(waiting)
        for key, handler in reversed(self._subscribed):
            self._unsubscribe(key, handler)
        self._subscribed.clear()
        for declaration in reversed(self._declared):
            _undeclare(declaration, self.name)
        self._declared.clear()
        if self.owner is None:
            for key in list(self._fanouts):  # views left open: their subscriptions go with the session
                self._fanouts.pop(key).undeclare(self.name)
            with zenoh_errors(f"{self.name}: close"):
                await asyncio.to_thread(self.session.close)

    def _unsubscribe(self, key: str, handler: SampleHandler) -> None:
        fanout = self._fanouts.get(key)
        if fanout is None:
            return
        with contextlib.suppress(ValueError):
            fanout.handlers.remove(handler)
        if not fanout.handlers:
            del self._fanouts[key]
            self._local.clear()
            fanout.undeclare(self.name)

    def _to_loop(self, callback: Callable[..., None], *args: Any, first: bool = False, urgent: bool = False) -> None:
        """From a Zenoh thread: run ``callback(*args)`` on the loop (dropped once the loop is gone),
        in arrival order; ``first``: before every ordinary one still waiting."""
        if self.closed:
            return
        self._inbox.put(first, self.name, callback, args, urgent)


@dataclass
class _Fanout:
    """One Zenoh subscriber and the handlers of every node of the session subscribed to its key."""

    name: str
    gather: bool = False  #: the puts made while its samples are handed round go out together
    first: bool = False  #: its samples go before the ordinary ones waiting for the loop
    urgent: bool = False  #: its samples go before every other waiting for the loop
    handlers: list[SampleHandler] = field(default_factory=list)
    subscriber: Any = None

    def deliver(self, key: str, payload: bytes) -> None:
        for handler in list(self.handlers):  # a handler may close its node (and unsubscribe)
            guarded(self.name, handler, (key, payload))

    def undeclare(self, name: str) -> None:
        _undeclare(self.subscriber, name)


def _undeclare(declaration: Any, name: str) -> None:
    try:
        with zenoh_errors(f"{name}: undeclare"):
            declaration.undeclare()
    except TransportError as exc:  # already gone with its link: nothing left to undeclare
        log.debug("%s", exc)


def _finish(done: asyncio.Future[None]) -> None:
    if not done.done():
        done.set_result(None)
