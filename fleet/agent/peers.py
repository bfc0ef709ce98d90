"""What a drone's agent takes from its peers: their protocol messages and plans (checked: a peer of this
fleet, on its own key, within bounds), their comings and goings (Zenoh liveliness), and their clocks.

A mixin of :class:`~fleet.agent.drone.DroneAgent`, which holds the state named below. Each message is
handed to the stack on the event loop, one at a time, as the systematic tester hands it.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

from drona_gcs.stack.drone import DroneAction, DroneStack
from drona_gcs.stack.messages import CurrentTraj, PlanDecision
from drona_gcs.workspace import Workspace
from fleet.agent.admission import TaskBudget
from fleet.agent.clocksync import ClockCheck, OffsetSample
from fleet.agent.maildesk import MailDesk
from fleet.clock import step_at
from fleet.logs import Throttled
from fleet.transport.identity import Speakers
from fleet.transport.keys import FleetKeys
from fleet.transport.node import Node, Query
from fleet.transport.wire import (
    ClockPing,
    ClockPong,
    CurTrajTo,
    Decide,
    PeerBounds,
    PlanAnnounce,
    Propose,
    WireError,
    answer_in,
    decode,
    encode,
    to_core,
)

log = logging.getLogger("fleet.agent.drone")  # the agent's logger: its lines keep their name


class PeerSide:
    """The peers' side of a drone's agent (see the module docstring)."""

    me: str
    stack: DroneStack
    node: Node
    keys: FleetKeys
    speakers: Speakers
    clock: Callable[[], float]
    epoch_s: float
    ws: Workspace
    bounds: PeerBounds
    dropped: Throttled
    alive: set[str]
    heard_at: dict[str, int]
    lease_steps: int
    clocks: ClockCheck
    alarms: dict[str, str]
    may_plan: bool
    mail: MailDesk
    budget: TaskBudget

    if TYPE_CHECKING:  # the agent's own
        def _carry_out(self, actions: Sequence[DroneAction]) -> None: ...
        def _alarm(self, kind: str, text: str | None) -> None: ...
        def _refusal(self) -> str | None: ...

    def _on_protocol(self, key: str, payload: bytes) -> None:
        began = time.perf_counter()
        self._take_protocol(key, payload)
        self.budget.handled(time.perf_counter() - began)

    def _take_protocol(self, key: str, payload: bytes) -> None:
        try:
            envelope = decode(payload)
            if envelope.sender == self.me:
                return  # my own request to everyone (proto/all) comes back to me too
            self._check_sender(key, envelope.sender)
            self.bounds.check(envelope.body, self._step_now())
            message = to_core(envelope, self.me)
            answer = answer_in(envelope, self.me) if isinstance(envelope.body, (Decide, Propose)) else None
        except WireError as exc:
            self.dropped.warning(key, "%s: dropped a message on %s: %s", self.me, key, exc)
            return
        self.heard_at[envelope.sender] = self.stack.now
        body = envelope.body
        if isinstance(body, CurTrajTo) or (isinstance(body, Decide) and body.replies):
            # The sender's new plan, whoever it answers (a drone whose round is over too): heard now, so
            # the plan it flies must be known now too (if it leaves, it is held along this plan, not the
            # one before); and it comes with no announcement of its own (see _started).
            known = message.trajectory if isinstance(message, (CurrentTraj, PlanDecision)) else body.trajectory.core()
            self._carry_out(self.stack.heard(envelope.sender, known))
        for each in (message, answer):  # a decision first, then the answer it carries (as they were sent)
            if each is not None and (actions := self.stack.receive(each)):
                self._carry_out(actions)

    def _on_plan(self, key: str, payload: bytes) -> None:
        try:
            envelope = decode(payload)
            if envelope.sender == self.me:
                return
            self._check_sender(key, envelope.sender)
            self.bounds.check(envelope.body, self._step_now())
        except WireError as exc:
            self.dropped.warning(key, "%s: dropped a plan on %s: %s", self.me, key, exc)
            return
        body, sender = envelope.body, envelope.sender
        if isinstance(body, PlanAnnounce):
            self.heard_at[sender] = self.stack.now
            if body.grounded:
                self._carry_out(self.stack.peer_down(sender, body.trajectory.core().last))
            elif body.lost:
                self._carry_out(self.stack.peer_lost(sender, body.holds, body.for_now, body.holds_seq))
            elif body.braked:
                self._carry_out(self.stack.peer_braked(sender, body.trajectory.core()))
            else:
                self._carry_out(self.stack.heard(sender, body.trajectory.core()))

    def _step_now(self) -> int:
        """The step on this clock, also before the first boundary is stepped."""
        return max(self.stack.now, step_at(self.clock(), self.epoch_s, self.ws.tau_s))

    def _check_sender(self, key: str, sender: str) -> None:
        """A peer of this fleet, speaking on its own key, or on its host's protocol key (the access control
        lets only it, or that host, write there)."""
        writer = self.keys.writer(key)
        if sender != writer and not (FleetKeys.is_proto(key) and self.speakers.flies(writer, sender)):
            unknown = writer not in self.stack.protocol.peers and writer not in self.speakers.hosts
            raise WireError(f"sender {sender!r} is not the key's writer {writer!r}" + (
                f" (no host {writer!r} in the hosts.json beside this drone's certificates)" if unknown else ""))
        if sender not in self.stack.protocol.peers:
            raise WireError(f"sender {sender!r} is not a peer of this fleet")

    def _on_liveliness(self, key: str, alive: bool) -> None:
        peer = self.keys.last_chunk(key)
        if peer == self.me:
            return
        if peer not in self.stack.protocol.peers:
            log.warning("%s: drone %r is alive on the fleet's keys but not in the workspace: ignored", self.me, peer)
            return
        if alive:
            self.alive.add(peer)
            self._joined(peer)
        else:
            self.alive.discard(peer)
            self.clocks.forget(peer)
            self._carry_out(self.stack.peer_left(peer, self._silent_since(peer)))
            self.mail.orphan(peer, self.stack.now + self.lease_steps)

    def _on_service(self, key: str, alive: bool) -> None:
        if alive:
            log.info("%s: the service is there", self.me)
            self.mail.service_back()  # a client's subscription may have kept the match up meanwhile
            return
        log.warning("%s: the service is gone: mail not on board is handed back", self.me)
        self._carry_out(self.stack.service_lost())

    def _on_reports_heard(self, heard: bool) -> None:
        """A subscription to my reports reaches me again, the service's maybe: what I reported while
        none did may be lost. (Its token may come first, after a partition heals: a report sent then
        was lost. The token still counts: a client's subscription may have kept the match up.)"""
        if heard:
            self.mail.service_back()

    def _silent_since(self, peer: str) -> int:
        """The earliest step ``peer`` may have gone silent at. A lost link is noticed only when the
        lease runs out, so that long ago; but not before it was last heard from (the core holds its
        plan from ``lead_steps`` before that, which covers the skew and a message's way here). Held for
        good are the cells of its plan from then on: too early a guess holds cells it flew through
        long ago, and a mail there is never delivered."""
        return max(self.stack.now - self.lease_steps, self.heard_at.get(peer, -self.lease_steps))

    def _joined(self, peer: str) -> None:
        """A peer (re)joined: take it where it was last heard of (its start, if never). A coordinating
        drone asks it at once, and its answer is what any plan is made with."""
        last = self.stack.protocol.known.get(peer)
        cell = last.last if last is not None else self.stack.protocol.peers[peer]
        self._carry_out(self.stack.peer_joined(peer, cell, last))
        self.mail.rejoined(peer)

    # ----------------------------------------------------------------- clock
    def _on_clock_query(self, key: str, payload: bytes, query: Query) -> None:
        query.reply(self.keys.clock(self.me), encode(self.me, self.clock(), ClockPong()))

    async def measure_clocks(self) -> dict[str, OffsetSample]:
        """One offset measurement against every drone that answers (this host's clock against theirs)."""
        sent = self.clock()
        replies = await self.node.get(self.keys.clock(), encode(self.me, sent, ClockPing()), 1.0, self.clock)
        samples = {}
        for reply in replies:
            try:
                envelope = decode(reply.payload)
            except WireError as exc:
                log.warning("%s: dropped a clock reply: %s", self.me, exc)
                continue
            samples[envelope.sender] = OffsetSample.measure(sent, envelope.sent_at, reply.at)
        return samples

    def judge_clocks(self, samples: dict[str, OffsetSample]) -> None:
        """Keep the samples of live peers; alarm and hold beyond beta."""
        for peer, sample in samples.items():
            if peer != self.me and peer in self.alive:
                self.clocks.observe(peer, sample)
                self.heard_at[peer] = self.stack.now
        fleet = len(set(self.stack.protocol.peers) - {self.me})  # not just who answered first
        alarm, mine_off = self.clocks.alarm(fleet), self.clocks.mine_is_off(fleet)
        if alarm != self.alarms.get("clock"):
            log.warning("%s: %s", self.me, alarm or "clock skew back within beta")
        self.may_plan = not mine_off
        outliers = frozenset() if mine_off else frozenset(self.clocks.violations())
        reason = f"drone {self.me}'s clock is beyond the fleet's bound"
        self._carry_out(self.stack.clock_bound(mine_off, outliers, reason))
        self.mail.refusal = self._refusal()  # now, not at the next boundary: mail may come meanwhile
        self._alarm("clock", alarm)
