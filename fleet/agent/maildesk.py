"""A drone's mail desk: orders and cancellations taken, progress reported, holdings published,
and the mail of a departed peer adopted by its heir.

Orders are Zenoh queries on ``mail/assign/<me>``, answered accepted (a repeated
order too: it is not a second mail) or refused with the reason; cancellations
on ``mail/cancel/<me>`` drop a mail still waiting. What the drone holds goes out
on ``held/<me>`` whenever it changes, so that when a drone leaves, the live
drone with the smallest name (its *heir*) can take over what it had not picked
up. One owner per mail: the heir adopts only in touch with most of the fleet, and a
lease after the leave, by when a drone that was cut off (not gone) has handed back
all it had not picked up (see DroneStack). What it carried stays its own: cut off,
it may yet deliver it; once the operator releases it (out of the air), that mail is
reported failed. Never failed and then delivered.

A drone that hands back mail it cannot fly now (its vehicle lost, down or late) goes
on listing it, ``handed_back``, until a peer lists it: with no service to reassign it,
its heir (the smallest live name but its own) takes it over at once, by the same rule
of a majority, since the drone gave it up.
"""

from __future__ import annotations

import collections
import heapq
import logging
from collections.abc import Callable, Collection

from drona_gcs.errors import ProblemError
from drona_gcs.stack.drone import DroneStack
from drona_gcs.stack.mail import (
    MailDelivered,
    MailLost,
    MailPickedUp,
    MailProgress,
    MailRejected,
    MailRequest,
    MailStarted,
    mail_cell_problem,
)
from drona_gcs.workspace import Cell
from fleet.transport.keys import FleetKeys
from fleet.transport.node import Node, Query
from fleet.transport.wire import (
    HeldMail,
    MailAck,
    MailCancel,
    MailClear,
    MailOrder,
    MailStatus,
    MailStatusReport,
    MailView,
    WireError,
    decode,
    decode_as,
    encode,
)

log = logging.getLogger(__name__)

KEPT_REPORTS = 256  #: mails whose last report a drone keeps, to send again to a service back
PROGRESS = {MailStarted: MailStatus.STARTED, MailPickedUp: MailStatus.PICKED_UP,
            MailDelivered: MailStatus.DELIVERED, MailRejected: MailStatus.REJECTED, MailLost: MailStatus.FAILED}


class MailDesk:
    def __init__(self, stack: DroneStack, node: Node, keys: FleetKeys, clock: Callable[[], float],
                 on_change: Callable[[], None]) -> None:
        self.me, self.stack, self.node, self.keys, self.clock = stack.me, stack, node, keys, clock
        self.on_change = on_change  #: the drone's state changed (a mail taken)
        self.accepting = True  #: False once shutting down: no new mail
        self.refusal: str | None = None  #: why this drone takes no mail for now (its vehicle is down)
        #: the refusal ends only with a restart (its vehicle down, out of service): an heir does not wait it out
        self.refusing_for_good = False
        self.adopt = True  #: off when a service dispatches the mail (it reassigns a lost drone's)
        self.seq = 0
        self.delivered: set[str] = set()  #: a repeated order for one of these is acknowledged, not flown again
        self.peer_mail: dict[str, list[MailView]] = {}  #: what each peer last said it holds
        self.listing: dict[str, set[str]] = {}  #: mail id -> the peers whose last list holds it
        #: mail nobody took over yet: of departed drones, or handed back; whose, and from which step on
        self.orphans: dict[str, tuple[str, MailView, int]] = {}
        self.handed: dict[str, MailView] = {}  #: mail I handed back that no peer lists yet
        self.stranded: dict[str, tuple[str, MailView]] = {}  #: mail on board departed drones
        self.published: list[MailView] | None = None
        #: the last report on each mail, newest last: sent again when the service comes back (it may have
        #: missed any of them, made before either side saw the link go)
        self.latest: collections.OrderedDict[str, MailStatusReport] = collections.OrderedDict()

    def declare(self) -> None:
        node, keys = self.node, self.keys
        node.subscribe(keys.held(), self._on_peer_mail)
        node.queryable(keys.held(self.me), self._on_held_query)
        node.queryable(keys.assign(self.me), self._on_order)
        node.queryable(keys.cancel(self.me), self._on_cancel)
        node.queryable(keys.clear(self.me), self._on_clear)

    async def catch_up(self) -> None:
        """What the peers already hold (they published it before we subscribed)."""
        for reply in await self.node.get(self.keys.held(), b"", 1.0):
            self._on_peer_mail(reply.key, reply.payload)

    # ------------------------------------------------------------ orders
    def _on_order(self, key: str, payload: bytes, query: Query) -> None:
        order_id = "?"
        try:
            body = decode_as(payload, MailOrder, "a mail order")
            order_id = body.id
            taken = self.take(body)
            ack = MailAck(id=body.id, drone=self.me, accepted=True, reason="" if taken else "already held")
        except (WireError, ProblemError) as exc:
            ack = MailAck(id=order_id, drone=self.me, accepted=False, reason=str(exc))
        query.reply(self.keys.assign(self.me), encode(self.me, self.clock(), ack))

    def _on_cancel(self, key: str, payload: bytes, query: Query) -> None:
        try:
            body = decode_as(payload, MailCancel, "a mail cancel")
        except WireError as exc:
            log.warning("%s: dropped a cancel on %s: %s", self.me, key, exc)
            return
        dropped = self.stack.cancel(body.id)
        if dropped:  # not remembered: ordered again, it is a new order
            self.report(body.id, MailStatus.CANCELLED)
            self.publish_held()
        ack = MailAck(id=body.id, drone=self.me, accepted=dropped, reason="" if dropped else "under way or unknown")
        query.reply(self.keys.cancel(self.me), encode(self.me, self.clock(), ack))

    def _on_clear(self, key: str, payload: bytes, query: Query) -> None:
        """The service holds a mail I started as mine from now on: I may take it on board."""
        try:
            body = decode_as(payload, MailClear, "a mail clearance")
        except WireError as exc:
            log.warning("%s: dropped a clearance on %s: %s", self.me, key, exc)
            return
        ack = MailAck(id=body.id, drone=self.me, accepted=self.stack.mail.clear(body.id))
        query.reply(self.keys.clear(self.me), encode(self.me, self.clock(), ack))

    def take(self, order: MailOrder) -> bool:
        """Queue ``order``; False if this drone already has it (a repeated order). ProblemError if unusable."""
        if not self.accepting:
            raise ProblemError(f"drone {self.me} is shutting down")
        if self.refusal is not None:
            raise ProblemError(f"drone {self.me} takes no mail: {self.refusal}")
        if self.stack.mail.why_spent is not None:
            raise ProblemError(f"drone {self.me} takes no mail: {self.stack.mail.why_spent}")
        if self.stack.commanded is not None:  # an order sent before the command may come after it
            raise ProblemError(f"drone {self.me} takes no mail: the operator's {self.stack.commanded} is in force")
        if order.id in self.delivered or any(m.id == order.id for m in self.held()):
            return False
        pickup, dropoff = self._cell("pickup", order.pickup), self._cell("dropoff", order.dropoff)
        self.handed.pop(order.id, None)  # given back to me: mine again
        self.seq += 1
        self.stack.assign(MailRequest(order.id, pickup, dropoff, order.priority, seq=self.seq))
        self.report(order.id, MailStatus.ACCEPTED)
        self.publish_held()
        self.on_change()
        return True

    def _cell(self, name: str, values: list[int]) -> Cell:
        cell: Cell = (values[0], values[1], values[2])
        found = mail_cell_problem(self.stack.config.workspace, cell)
        if found is not None:
            raise ProblemError(f"{name}: {found[1]}")
        return cell

    # ---------------------------------------------------------- progress
    def progress(self, action: MailProgress) -> None:
        status = PROGRESS[type(action)]
        if isinstance(action, MailRejected) and action.handed_back and self.adopt:
            self.handed[action.request.id] = _view(action.request, "handed_back")
            status = MailStatus.HANDED_BACK
        if status is MailStatus.DELIVERED:
            self.delivered.add(action.request.id)
        self.stack.mail.reported(action)
        self.report(action.request.id, status, action.reason if isinstance(action, (MailRejected, MailLost)) else "")
        self.publish_held()

    def report(self, mail_id: str, status: MailStatus, reason: str = "", drone: str | None = None) -> None:
        report = MailStatusReport(id=mail_id, drone=drone or self.me, status=status, step=self.stack.now,
                                  reason=reason)
        self._put_report(report)
        self.latest.pop(mail_id, None)
        self.latest[mail_id] = report
        if len(self.latest) > KEPT_REPORTS:
            self.latest.popitem(last=False)
        log.info("%s: mail %s %s%s", self.me, mail_id, status.value, f" ({reason})" if reason else "")

    def _put_report(self, report: MailStatusReport) -> None:
        self.node.put(self.keys.status(self.me, report.id), encode(self.me, self.clock(), report), once=True)

    def service_back(self) -> None:
        """The service hears my reports again: the last word on each mail again, in order, since it may
        have missed it (a delivery made meanwhile is not failed for want of news; it ignores what it knew)."""
        for report in self.latest.values():
            self._put_report(report)
        if self.latest:
            log.info("%s: the last report on %d mail(s) sent again to the service", self.me, len(self.latest))

    # ---------------------------------------------------------- holdings
    def held(self) -> list[MailView]:
        planner = self.stack.mail
        views = []
        if planner.current is not None:
            views.append(_view(planner.current, "carrying" if planner.carrying else "current"))
        return views + [_view(r, "queued") for r in sorted(planner.queue, key=lambda r: r.rank)]

    def listed(self) -> list[MailView]:
        """What I say I hold: what I fly, and what I handed back that no peer took over yet."""
        return self.held() + list(self.handed.values())

    def publish_held(self) -> None:
        """Say what mail I hold, when it changed: my heir needs it if I go."""
        held = self.listed()
        if held != self.published:
            self.published = held
            self.node.put(self.keys.held(self.me), encode(self.me, self.clock(), HeldMail(drone=self.me, mail=held)))

    def _on_held_query(self, key: str, payload: bytes, query: Query) -> None:
        query.reply(self.keys.held(self.me), encode(self.me, self.clock(), HeldMail(drone=self.me, mail=self.listed())))

    def _on_peer_mail(self, key: str, payload: bytes) -> None:
        try:
            body = decode(payload).body
        except WireError as exc:
            log.warning("%s: dropped a mail list on %s: %s", self.me, key, exc)
            return
        writer = self.keys.writer(key)
        if isinstance(body, HeldMail) and body.drone == writer != self.me and writer in self.stack.protocol.peers:
            held = [m for m in body.mail if m.stage != "handed_back"]
            self._peer_holds(writer, held)
            taken_over = False
            for mail in held:  # taken over by that drone (or its own again)
                self.orphans.pop(mail.id, None)
                self.stranded.pop(mail.id, None)
                taken_over |= self.handed.pop(mail.id, None) is not None
            if taken_over:  # what I list changed (every drone of a host hears every list: most change nothing)
                self.publish_held()
            for mail in body.mail:
                if mail.stage == "handed_back" and not self._listed_by_other(mail.id, writer):
                    self.orphans.setdefault(mail.id, (writer, mail, self.stack.now))

    def _peer_holds(self, peer: str, held: list[MailView] | None) -> None:
        """``peer``'s list of mail held is now ``held`` (None: it has none any more, it left)."""
        for mail in self.peer_mail.pop(peer, []):
            holders = self.listing.get(mail.id, set())
            holders.discard(peer)
            if not holders:
                self.listing.pop(mail.id, None)
        if held is not None:
            self.peer_mail[peer] = held
            for mail in held:
                self.listing.setdefault(mail.id, set()).add(peer)

    def _listed_by_other(self, mail_id: str, than: str) -> bool:
        """Whether a drone other than ``than`` (me too) holds the mail: it took it over already."""
        mine = any(m.id == mail_id for m in self.held())
        return mine or bool(self.listing.get(mail_id, set()) - {than})

    # ---------------------------------------------------------- adoption
    def orphan(self, peer: str, due: int) -> None:
        """``peer`` left: what it had not picked up is orphaned, to be taken over from step ``due`` on
        (see :meth:`adopt_due`); what it carried stays its own."""
        gone = self.peer_mail.get(peer, [])
        self._peer_holds(peer, None)
        for mail in gone:
            if mail.stage == "carrying":
                self.stranded[mail.id] = (peer, mail)
            else:
                self.orphans[mail.id] = (peer, mail, due)

    def rejoined(self, peer: str) -> None:
        """``peer`` is back: what it held is its own again (it says what, see :meth:`publish_held`), and
        what I hold goes to it too at the next boundary (it may have missed what changed): once for
        every peer back by then, not to every peer for each (a fleet starting up sent N^2 lists)."""
        for mail_id in [m for m, v in self.orphans.items() if v[0] == peer]:
            del self.orphans[mail_id]
        for mail_id in [m for m, v in self.stranded.items() if v[0] == peer]:
            del self.stranded[mail_id]
        self.published = None

    def released(self, drone: str, alive: Collection[str]) -> None:
        """The operator took ``drone``, gone, out of the fleet: what it carried is lost with it (said by
        its heir, once)."""
        if min({*alive, self.me}) != self.me:
            self.stranded = {m: v for m, v in self.stranded.items() if v[0] != drone}
            return
        for mail_id, (peer, _) in list(self.stranded.items()):
            if peer == drone:
                del self.stranded[mail_id]
                self.report(mail_id, MailStatus.FAILED, f"on board drone {drone}, released by the operator",
                            drone=drone)

    def adopt_due(self, step: int, alive: Collection[str], in_touch: bool) -> None:
        """In touch with most of the fleet, I take over every orphan due by ``step`` whose heir I am (the
        smallest live name but its drone's). Orphans stay known until some drone says it holds them, so
        drones leaving together, heirs first, lose nothing."""
        if not self.adopt or not in_touch or not self.orphans:
            return
        first_two = heapq.nsmallest(2, {*alive, self.me})  # the heir of any drone is one of these
        if self.me not in first_two:
            return
        due = {k: v for k, v in self.orphans.items()
               if v[2] <= step and next((name for name in first_two if name != v[0]), None) == self.me}
        if due and self.refusal is not None and not self.refusing_for_good:
            return  # late, or not ready, for now: taken over once I may, not rejected (no drone else would)
        for mail_id in due:
            del self.orphans[mail_id]
        for owner, mail, _ in due.values():
            why = f"drone {owner} {'handed it back' if mail.stage == 'handed_back' else 'left'}"
            order = MailOrder(id=mail.id, pickup=mail.pickup, dropoff=mail.dropoff, priority=mail.priority)
            try:
                if self.take(order):
                    self.report(mail.id, MailStatus.REASSIGNED, why)
            except ProblemError as exc:  # handed back, it is whole: back to whoever gave it
                lost = MailStatus.REJECTED if mail.stage == "handed_back" else MailStatus.FAILED
                self.report(mail.id, lost, f"{why}; cannot take it over: {exc}")


def _view(request: MailRequest, stage: str) -> MailView:
    return MailView(id=request.id, pickup=list(request.pickup), dropoff=list(request.dropoff),
                    priority=request.priority, stage=stage)  # type: ignore[arg-type]
