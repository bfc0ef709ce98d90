"""One drone's agent: the core stack wired to Zenoh, to its vehicle and to the local clock.

Everything the stack decides comes back as actions, carried out here:
protocol messages go out on ``proto/<peer>``, requests to everyone on
``proto/all`` (one put that Zenoh fans out; a round is 2(N-1) messages,
fewer when drones coordinate at once: a request is its sender's answer to
those before it in line), a new plan's answers to the drones that waited for it on
``answers`` (one put, each of them takes its own; every drone reads it, so
the plan needs no announcement on ``plan/<me>``), mail progress on
``mail/status/<id>``, the mail held on ``held/<me>`` when it changes, the
drone's state on ``state/<me>`` at every step boundary. What comes in — peers' messages, mail orders, membership
changes — is handed to the stack on the event loop, one event at a time,
exactly as the systematic tester hands it.

Membership is Zenoh liveliness: a peer whose token goes is the protocol's
``PeerLeft`` (it stays in Psi as an obstacle), one whose token appears is
``PeerJoined`` where it was last heard of. At start-up,
peers not alive are marked left, so nobody waits for a drone that never came.

Mail orders, cancellations, progress and the heir's adoption of a departed
peer's mail live in :mod:`fleet.agent.maildesk`.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TextIO

from drona_gcs.geo import GeoFrame
from drona_gcs.motion import Trajectory
from drona_gcs.stack.battery import BatteryLow, BatteryRecharged
from drona_gcs.stack.drone import DroneAction, DroneStack
from drona_gcs.stack.mail import GoTo, MailDelivered, MailLost, MailPickedUp, MailRejected, MailStarted
from drona_gcs.stack.messages import CurrentTraj, TaskId
from drona_gcs.stack.protocol import Broadcast, Send, StartExecuting, State, TaskFailed
from drona_gcs.workspace import Cell, Workspace
from fleet.agent.clocksync import ClockCheck, OffsetSample
from fleet.agent.maildesk import MailDesk
from fleet.agent.vehicle import VehicleSupervisor
from fleet.executor import StepReport
from fleet.transport.keys import FleetKeys
from fleet.transport.node import Query, ZenohNode
from fleet.transport.wire import (
    ClockPing,
    ClockPong,
    CurTraj,
    CurTrajTo,
    DroneState,
    Health,
    PlanAnnounce,
    ReqTraj,
    TaskView,
    WireError,
    WireTrajectory,
    answers,
    decode,
    encode,
    from_core,
    to_core,
)
from fleet.vehicle.link import VehicleLink

log = logging.getLogger(__name__)

BROADCAST = "all"  #: proto/all: a message to every drone of the fleet (no drone may be called "all")
ARRIVAL_FRACTION = 0.2  #: over a cell: within this fraction of a cell of its centre (before landing)


@dataclass
class Metrics:
    """What the coordination benchmark reads: task arrival to plan scheduled, per plan."""

    latencies_s: list[float] = field(default_factory=list)
    messages_sent: int = 0
    plans: int = 0


class DroneAgent:
    def __init__(self, stack: DroneStack, node: ZenohNode, keys: FleetKeys, link: VehicleLink,
                 frame: GeoFrame, clock: Callable[[], float], record: TextIO | None = None) -> None:
        self.me, self.stack, self.node, self.keys = stack.me, stack, node, keys
        self.link, self.frame, self.clock, self.record = link, frame, clock, record
        self.ws: Workspace = stack.config.workspace
        self.delta = stack.config.planner.delta
        self.clocks = ClockCheck(self.ws.beta_s)
        self.alarms: dict[str, str] = {}
        self.vehicle = VehicleSupervisor(
            self.me, link, frame.layer_height_m(stack.executor.cell[2]), lambda text: self._alarm("vehicle", text),
            target=lambda: frame.cell_to_ned(stack.executor.cell), arrival_m=ARRIVAL_FRACTION * self.ws.cell_size_m)
        self.alive: set[str] = set()
        self.actual: Cell | None = None
        self.battery_pct = 100.0
        self.may_plan = True
        #: the vehicle came down by itself: its mail is handed back and it starts no task, for good (a
        #: vehicle may be anywhere once down: it rejoins the fleet when its agent is restarted)
        self.down = False
        self.task_since: float | None = None
        self.metrics = Metrics()
        self.lease_steps = 0  #: the Zenoh lease in steps (set by the host)
        #: the step at which each peer was last heard from (a protocol message, a plan, a clock reply)
        self.heard_at: dict[str, int] = {}
        self.mail = MailDesk(stack, node, keys, clock, on_change=self.publish_state_soon)
        self._state_scheduled = False

    # ------------------------------------------------------------ start-up
    async def start(self) -> None:
        """Declare everything, then join: answer before anyone can ask."""
        node, keys = self.node, self.keys
        # Protocol messages first (see fleet.transport.node), requests and answers alike, in the order they
        # came: a drone that coordinates waits on both (every peer's answer to its request, then the plans of
        # those before it in line), while announced plans, states, mail and clocks can wait their turn.
        # With only the answers first, the requests of the drones later in line waited while those before
        # them planned, when the whole fleet coordinated at once.
        node.subscribe(keys.proto(self.me), self._on_protocol, first=True)
        node.subscribe(keys.answers(), self._on_protocol, first=True)
        # A request to everyone: this host's drones answer it in one message (see ZenohNode.subscribe).
        node.subscribe(keys.proto(BROADCAST), self._on_protocol, gather=True, first=True)
        node.subscribe(keys.plan(), self._on_plan)
        node.queryable(keys.state(self.me), self._on_state_query)
        node.queryable(keys.clock(self.me), self._on_clock_query)
        self.mail.declare()
        # With the protocol's messages, in the order they came: a peer that left and came back must not have
        # its new request handled before its leaving (which would drop the request, held for an answer).
        node.watch_liveliness(keys.alive(), self._on_liveliness, first=True)
        # The token last: whoever sees us alive finds every queryable already declared (the
        # declarations reach a peer in order), so a mail order sent at once is answered.
        node.token(keys.alive(self.me))
        await self.mail.catch_up()
        present = {keys.last_chunk(k) for k in await node.alive(keys.alive())}
        for peer in self.stack.protocol.peers:
            if peer != self.me and peer not in present | self.alive:
                self.stack.peer_left(peer)  # not running: kept where it stands, not waited for
        self.publish_state()

    # ------------------------------------------------------ step boundary
    def tick(self, step: int) -> Sequence[object]:
        """The setpoint loop's boundary: the whole stack steps (executor, battery, task planner)."""
        level = self._battery()
        actions = self.stack.step(step, level, may_plan=self.may_plan and self.mail.accepting and not self.down)
        self._carry_out(actions)
        return actions

    def on_step(self, report: StepReport, actions: Sequence[object]) -> None:
        """After the boundary's setpoints went out: judge the vehicle, record it, publish the state."""
        self.actual = self.actual_cell()
        if self.actual is None:
            log.debug("%s: no cell at step %d: position %s", self.me, report.step, self.link.last_position())
        if self.record is not None and self.actual is not None:
            # At boundary k the vehicle should be where step k - 1 took it.
            self.record.write(f'{{"step": {report.step - 1}, "drone": "{self.me}", '
                              f'"cell": [{self.actual[0]}, {self.actual[1]}, {self.actual[2]}], '
                              f'"delta": {self.delta}}}\n')
        if not self.down and self.vehicle.grounded_by_itself():
            self.down = True
            self.mail.refusal = "its vehicle came down by itself"
            where = f"in {list(self.actual)}" if self.actual is not None else "outside the grid"
            log.warning("%s: the vehicle came down by itself %s: its mail is handed back", self.me, where)
            self._carry_out(self.stack.vehicle_down(f"drone {self.me}'s vehicle came down by itself {where}"))
        lagging = report.lagging and self.vehicle.settled and not self.down
        self._alarm("lag", f"vehicle {report.error_m:.1f} m from its cell" if lagging else None)
        self._alarm("down", "vehicle: came down while its plan flew (a failsafe or a pilot?); its mail was handed "
                    "back and it starts no task; restart its agent once it is back in service" if self.down else None)
        self._alarm("behind", f"catching up (a stall, or a vehicle too slow at a turn): {report.behind} "
                    "cells of its plan still to fly through" if report.behind else None)
        # A plan scheduled but not begun still needs the climb: the lead steps are for it.
        # Landing crosses only its own column when the cell is on the lowest layer; higher up it hovers.
        grounded = self.stack.landed and self.stack.executor.cell[2] == 0
        self.vehicle.want_airborne(not grounded or self.stack.protocol.state is State.EXECUTING)
        # Half a period later: at the boundary every drone of the fleet is busy, and answers come first.
        self.publish_state_soon(self.ws.tau_s / 2)

    def _battery(self) -> float:
        pct = self.link.telemetry().battery_pct
        if pct is not None:
            self.battery_pct = float(pct)
        return self.battery_pct

    def actual_cell(self) -> Cell | None:
        """Where telemetry puts the vehicle; landed (below the grid) it is in its cell's column."""
        position = self.link.last_position()
        if position is None:
            return None
        fix = self.frame.locate(position.ned)
        if fix.cell is not None:
            return fix.cell
        east, north = position.ned.east, position.ned.north
        size = self.ws.cell_size_m
        cell = (math.floor(east / size), math.floor(north / size), 0)
        below = -position.ned.down < self.ws.geo.layer0_alt_m
        return cell if below and self.ws.in_bounds(cell) else None

    # -------------------------------------------------------------- actions
    def _carry_out(self, actions: Sequence[DroneAction]) -> None:
        # Protocol messages first: peers wait on them (the Sends after a StartExecuting are answers
        # to peers that waited for this plan). What only informs (mail progress, the plan's
        # announcement) goes out once the work at hand is done: at a step boundary the process's
        # other drones send their requests first.
        # Mostly one answer, or nothing: a process hands every request of a burst to each of its drones.
        ordered = _coalesced(sorted(actions, key=_urgency)) if len(actions) > 1 else actions
        told_everyone = False  # a new plan went to every drone with its answers: no announcement needed
        for action in ordered:
            if isinstance(action, Send):
                self._send(self.keys.proto(action.to), from_core(action.message))
            elif isinstance(action, Broadcast):
                # One put that Zenoh fans out to every peer (N - 1 messages on the wire, one call here).
                self._send(self.keys.proto(BROADCAST), from_core(action.message),
                           copies=len(self.stack.protocol.members))
            elif isinstance(action, Answers):
                self._send(self.keys.answers(), answers(action.trajectory, action.replies),
                           copies=len(action.replies))
                told_everyone = True
            elif isinstance(action, GoTo):
                self.task_since = self.clock()
            elif isinstance(action, StartExecuting):
                self._started(action, announce=not told_everyone)
            elif isinstance(action, TaskFailed):
                log.warning("%s: no plan for task %s: %s", self.me, action.task.id, action.reason)
            elif isinstance(action, (MailStarted, MailPickedUp, MailDelivered, MailRejected, MailLost)):
                asyncio.get_running_loop().call_soon(self.mail.progress, action)
            elif isinstance(action, (BatteryLow, BatteryRecharged)):
                log.info("%s: battery %s", self.me, type(action).__name__)

    def _send(self, key: str, body: ReqTraj | CurTraj | CurTrajTo, copies: int = 1) -> None:
        payload = encode(self.me, self.clock(), body)
        self.node.put(key, payload)
        self.metrics.messages_sent += copies

    def _started(self, action: StartExecuting, announce: bool = True) -> None:
        """A new plan. ``announce``: tell every drone where it goes (not if its answers, on the answers
        key, already did: all drones read those, which saves a message per drone and plan when the
        whole fleet coordinates at once)."""
        if self.task_since is not None:
            self.metrics.latencies_s.append(self.clock() - self.task_since)
            self.task_since = None
        self.metrics.plans += 1
        self.vehicle.want_airborne(True)
        self.publish_state_soon()  # after the answers to the peers that waited for this plan
        if announce:
            message = encode(self.me, self.clock(), PlanAnnounce(trajectory=WireTrajectory.of(action.trajectory)))
            asyncio.get_running_loop().call_soon(self.node.put, self.keys.plan(self.me), message)
        if not log.isEnabledFor(logging.INFO):
            return  # the line below formats every trajectory avoided
        t = action.trajectory
        log.info("%s: task %s to %s planned from step %d: %s; avoided %s", self.me, action.task.id,
                 list(action.task.goal), t.start_step, " ".join(f"{c[0]},{c[1]},{c[2]}" for c in t.cells),
                 "; ".join(f"{d}@{p.start_step}:{' '.join(f'{c[0]},{c[1]}' for c in p.cells)}"
                           for d, p in sorted(action.psi.items())))

    # ------------------------------------------------------------- inbound
    def _on_protocol(self, key: str, payload: bytes) -> None:
        try:
            envelope = decode(payload)
            if envelope.sender == self.me:
                return  # my own request to everyone (proto/all) comes back to me too
            message = to_core(envelope, self.me)
        except WireError as exc:
            log.warning("%s: dropped a message on %s: %s", self.me, key, exc)
            return
        if envelope.sender not in self.stack.protocol.peers:
            log.warning("%s: dropped a message from %r, not a peer of this fleet", self.me, envelope.sender)
            return
        self.heard_at[envelope.sender] = self.stack.now
        if isinstance(envelope.body, CurTrajTo):
            # The sender's new plan, whoever it answers (a drone whose round is over too): heard now, so
            # the plan it flies must be known now too (if it leaves, it is held along this plan, not the
            # one before); and it comes with no announcement of its own (see _started).
            known = message.trajectory if isinstance(message, CurrentTraj) else envelope.body.trajectory.core()
            self.stack.heard(envelope.sender, known)
        if message is not None:
            actions = self.stack.receive(message)
            if actions:
                self._carry_out(actions)

    def _on_plan(self, key: str, payload: bytes) -> None:
        try:
            envelope = decode(payload)
        except WireError as exc:
            log.warning("%s: dropped a plan on %s: %s", self.me, key, exc)
            return
        body, sender = envelope.body, envelope.sender
        if isinstance(body, PlanAnnounce) and sender != self.me and sender in self.stack.protocol.peers:
            self.heard_at[sender] = self.stack.now
            self.stack.heard(sender, body.trajectory.core())

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
            self.mail.adopt_from(peer, self.alive)

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

    # ----------------------------------------------------------------- state
    def state(self) -> DroneState:
        stack = self.stack
        protocol, planner = stack.protocol, stack.mail
        task = None
        if planner.goal is not None:
            current = planner.current.id if planner.current is not None else None
            task = TaskView(goal=list(planner.goal), purpose=planner.phase.value, mail_id=current)
        trajectory = protocol.trajectory if protocol.state is State.EXECUTING else None
        geo = self.link.last_global()
        alarms = sorted(self.alarms.values())
        return DroneState(
            drone=self.me, step=stack.now, cell=list(stack.executor.cell),
            actual=list(self.actual) if self.actual else None,
            position=(geo.lat, geo.lon, geo.alt_m) if geo else None, battery_pct=self.battery_pct,
            mode=protocol.state.value, phase=planner.phase.value, landed=stack.landed, task=task,
            trajectory=WireTrajectory.of(trajectory) if trajectory else None, mail=self.mail.held(),
            health=Health(ok=not alarms, alarms=alarms),
            clock_offset_s={p: round(s.offset_s, 6) for p, s in sorted(self.clocks.peers.items())},
            plans=self.metrics.plans, messages_sent=self.metrics.messages_sent,
            coordination_ms=round(self.metrics.latencies_s[-1] * 1000, 3) if self.metrics.latencies_s else None)

    def publish_state(self) -> None:
        self._state_scheduled = False
        self.node.put(self.keys.state(self.me), encode(self.me, self.clock(), self.state()))

    def publish_state_soon(self, delay_s: float = 0.0) -> None:
        """Publish the state once the work at hand is done (once, however often asked meanwhile)."""
        if not self._state_scheduled:
            self._state_scheduled = True
            asyncio.get_running_loop().call_later(delay_s, self.publish_state)

    def _on_state_query(self, key: str, payload: bytes, query: Query) -> None:
        query.reply(self.keys.state(self.me), encode(self.me, self.clock(), self.state()))

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
        alarm = self.clocks.alarm()
        if (alarm is None) != self.may_plan:
            log.warning("%s: %s", self.me, alarm or "clock skew back within beta: planning again")
        self.may_plan = alarm is None
        self._alarm("clock", alarm)

    def _alarm(self, kind: str, text: str | None) -> None:
        if text is None:
            self.alarms.pop(kind, None)
        else:
            self.alarms[kind] = text

    # -------------------------------------------------------------- shutdown
    @property
    def busy(self) -> bool:
        """Flying a plan or coordinating one: not yet safe to leave."""
        return self.stack.protocol.state is not State.WAIT_FOR_TASK or self.stack.executor.flying


@dataclass(frozen=True)
class Answers:
    """Several ``Send(CurrentTraj)`` with one trajectory, sent as one message on the fleet's
    ``answers`` key (each drone answered takes its own)."""

    trajectory: Trajectory
    replies: dict[str, TaskId]  #: drone answered -> the request it answers


#: Answers with one trajectory to at least this many drones go as one message to every drone.
#: A new plan answers every drone that waited for it: when many coordinate at once (a fleet
#: given mail together), one put instead of one per drone, and with drones sharing a session
#: (``--shared-session``) one delivery per host. Drones that did not wait get it too (one decode
#: each): it is the plan's announcement, and no other goes out.
COALESCE_FROM = 2


def _coalesced(actions: Sequence[DroneAction]) -> list[DroneAction | Answers]:
    """``actions`` with the answers that share a trajectory joined into one :class:`Answers`, in
    the place of the first of them (a drone answered twice, to two requests, keeps the second apart)."""
    groups: dict[Trajectory, dict[str, TaskId]] = {}
    for action in actions:
        if isinstance(action, Send) and isinstance(action.message, CurrentTraj):
            groups.setdefault(action.message.trajectory, {}).setdefault(action.to, action.message.in_reply_to)
    if all(len(replies) < COALESCE_FROM for replies in groups.values()):
        return list(actions)  # mostly: one answer, or none
    out: list[DroneAction | Answers] = []
    joined: set[Trajectory] = set()
    for action in actions:
        if isinstance(action, Send) and isinstance(action.message, CurrentTraj):
            trajectory = action.message.trajectory
            replies = groups[trajectory]
            if len(replies) >= COALESCE_FROM and replies[action.to] == action.message.in_reply_to:
                if trajectory not in joined:
                    joined.add(trajectory)
                    out.append(Answers(trajectory, replies))
                continue
        out.append(action)
    return out


def _urgency(action: DroneAction) -> int:
    """Protocol messages (and the task's arrival time, which comes before its request), then a new
    plan's bookkeeping, then the rest; a stable sort keeps the order within each."""
    if isinstance(action, (GoTo, Send, Broadcast)):
        return 0
    return 1 if isinstance(action, StartExecuting) else 2
