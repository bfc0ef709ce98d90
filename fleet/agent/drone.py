"""One drone's agent: the core stack wired to Zenoh, to its vehicle and to the local clock.

Everything the stack decides comes back as actions, carried out here:
protocol messages go out on ``proto/<me>/<peer>`` (``proto/<host>/<peer>`` when a host flies
several drones in one session), requests to everyone on ``proto/<me>/all``
(one put that Zenoh fans out; a round is 2(N-1) messages, fewer when drones
coordinate at once: a request is its sender's answer to
those before it in line), a plan made to everyone (``propose``), each member's ``ack``, whether
it is flown to everyone (``decide``), then its answers to the drones that waited for it on
``answers`` (one put, each of them takes its own), mail progress on
``mail/status/<id>``, the mail held on ``held/<me>`` when it changes, the
drone's state on ``state/<me>`` at every step boundary. What comes in — peers' messages, mail orders, membership
changes — is handed to the stack on the event loop, one event at a time,
exactly as the systematic tester hands it.

Membership is Zenoh liveliness: a peer whose token goes is the protocol's
``PeerLeft`` (it stays in Psi as an obstacle), one whose token appears is
``PeerJoined`` where it was last heard of. At start-up,
peers not alive are marked left, so nobody waits for a drone that never came.

Mail orders, cancellations, progress and the heir's adoption of a departed
peer's mail live in :mod:`fleet.agent.maildesk`; what the agent knows of its
vehicle (ready, lost, back) in :mod:`fleet.agent.watch`. A drone takes tasks only
while its vehicle is ready, answering, and placed where the stack holds it.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TextIO

from drona_gcs.errors import ProblemError
from drona_gcs.geo import GeoFrame
from drona_gcs.motion import Trajectory
from drona_gcs.stack.battery import BatteryLow, BatteryRecharged
from drona_gcs.stack.drone import DroneAction, DroneStack, LegNotFlown
from drona_gcs.stack.mail import GoTo, MailDelivered, MailLost, MailPickedUp, MailRejected, MailStarted
from drona_gcs.stack.messages import CurrentTraj, PlanDecision
from drona_gcs.stack.protocol import (
    Braked,
    Broadcast,
    Grounded,
    Holding,
    Present,
    RerouteFailed,
    Send,
    StartExecuting,
    State,
    TaskFailed,
    Threatened,
)
from drona_gcs.workspace import Cell, Workspace
from fleet.agent.clocksync import ClockCheck, OffsetSample
from fleet.agent.maildesk import MailDesk
from fleet.agent.outbox import Answers, Decided, coalesced, urgency
from fleet.agent.vehicle import VehicleSupervisor
from fleet.agent.watch import Seen, VehicleWatch, Verdict, record_line
from fleet.logs import Throttled
from fleet.setpoint_loop import Sample, SetpointLoop, StepReport
from fleet.transport.identity import Speakers
from fleet.transport.keys import FleetKeys
from fleet.transport.node import Query, ZenohNode
from fleet.transport.wire import (
    ClockPing,
    ClockPong,
    CommandAck,
    CommandAction,
    CurTrajTo,
    Decide,
    DroneState,
    FleetCommand,
    Health,
    PeerBounds,
    PlanAnnounce,
    ProtocolBody,
    TaskView,
    WireError,
    WireTrajectory,
    answer_in,
    answering,
    answers,
    decode,
    decode_as,
    encode,
    from_core,
    to_core,
)
from fleet.vehicle.link import Readiness, VehicleLink, not_ready
from fleet.vehicle.policy import DEFAULT_TIMEOUTS, Timeouts

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
                 frame: GeoFrame, clock: Callable[[], float], record: TextIO | None = None,
                 timeouts: Timeouts = DEFAULT_TIMEOUTS, epoch_s: float = 0.0, *, host: str | None = None,
                 speakers: Speakers | None = None) -> None:
        self.me, self.stack, self.node, self.keys = stack.me, stack, node, keys
        #: who its messages to one drone go out as: its host (joined with the host's other drones'), or itself
        self.speaks_as = host or self.me
        self.speakers = speakers or Speakers()
        self.epoch_s = epoch_s  #: the fleet epoch: step k starts at epoch + k tau
        self.link, self.frame, self.clock, self.record = link, frame, clock, record
        self.ws: Workspace = stack.config.workspace
        self.delta = stack.config.planner.delta
        self.clocks = ClockCheck(self.ws.beta_s)
        self.alarms: dict[str, str] = {}
        self.vehicle = VehicleSupervisor(
            self.me, link, frame.layer_height_m(stack.executor.cell[2]), lambda text: self._alarm("vehicle", text),
            target=lambda: frame.cell_to_ned(stack.executor.cell), arrival_m=ARRIVAL_FRACTION * self.ws.cell_size_m,
            timeouts=timeouts)
        self.watch = VehicleWatch(link, frame)
        self.setpoints: SetpointLoop | None = None  #: this drone's setpoint loop (set by the host)
        #: why the drone takes no task until its agent is restarted (its vehicle is not where it is held)
        self.out_of_service: str | None = None
        self.placed = False  #: its vehicle was seen at its start cell (checked once it has a position)
        self.alive: set[str] = set()
        self.actual: Cell | None = None
        self.battery_pct = 100.0
        self.may_plan = True
        #: why the vehicle is out of its lateness bound (None: within it; see on_sample)
        self.late: str | None = None
        #: the vehicle came down by itself: its mail is handed back and it starts no task, for good (a
        #: vehicle may be anywhere once down: it rejoins the fleet when its agent is restarted)
        self.down = False
        self.task_since: float | None = None
        self.metrics = Metrics()
        self.lease_steps = 0  #: the Zenoh lease in steps (set by the host)
        #: the step at which each peer was last heard from (a protocol message, a plan, a clock reply)
        self.heard_at: dict[str, int] = {}
        self.mail = MailDesk(stack, node, keys, clock, on_change=self.publish_state_soon)
        ws = stack.config.workspace
        self.bounds = PeerBounds.of(ws.size, ws.plan_length_limit)
        self.dropped = Throttled(log)  #: one line per key and period for what peers send that is refused
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
        node.queryable(keys.command(self.me), self._on_command)
        self.mail.declare()
        # With the protocol's messages, in the order they came: a peer that left and came back must not have
        # its new request handled before its leaving (which would drop the request, held for an answer).
        node.watch_liveliness(keys.alive(), self._on_liveliness, first=True)
        if not self.mail.adopt:  # a service dispatches the mail
            node.watch_liveliness(keys.service(), self._on_service, first=True)
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
        """The setpoint loop's boundary: the vehicle judged, then the whole stack steps (executor, battery,
        task planner) with the cell telemetry puts the vehicle in."""
        self._watch_vehicle(step)
        level = self._battery()
        actions = self.stack.step(step, level, self.watch.flown(), may_plan=self._may_plan())
        self._carry_out(actions)
        # A lease of grace: a drone cut off (not gone) has seen it too by then, and handed its mail back.
        self.mail.adopt_due(step, self.alive, self.stack.in_touch)
        return actions

    def _may_plan(self) -> bool:
        self.mail.refusal = self._refusal()
        return self.may_plan and self.mail.accepting and self.mail.refusal is None

    def _refusal(self) -> str | None:
        """Why this drone takes no mail and starts no task now (None: it may)."""
        if self.down:
            return "its vehicle came down by itself"
        if self.out_of_service is not None:
            return self.out_of_service
        if not self.may_plan:
            return "its clock is beyond the fleet's bound"
        if self.late is not None:
            return self.late
        readiness = self.watch.readiness()
        if readiness is Readiness.LOST:
            return "its vehicle is lost"
        if readiness is not Readiness.READY:
            return f"its vehicle is not ready: {not_ready(self.link.telemetry())}"
        return None if self.placed else "its vehicle has not been placed yet"

    # ------------------------------------------------------------- vehicle
    def _watch_vehicle(self, step: int) -> None:
        """Lost, back, placed: what the vehicle did since the last boundary, and what the drone does about it."""
        protocol = self.stack.protocol
        verdict = self.watch.boundary(step, protocol.holds(), placeable=not protocol.coordinating)
        if verdict.seen is Seen.LOST:
            self._lost(step, verdict)
        elif verdict.seen is Seen.BACK:
            self._back(verdict)
        elif verdict.seen is Seen.BACK_ELSEWHERE:
            self.out_of_service = f"{verdict.reason}: land it by hand, then restart its agent"
            log.error("%s: %s", self.me, self.out_of_service)
            self._alarm("vehicle_lost", f"vehicle_lost: {self.out_of_service}")
        if not self.placed and not self.watch.lost and self.watch.readiness() is Readiness.READY:
            self._place()

    def _lost(self, step: int, verdict: Verdict) -> None:
        seen = self.watch.last_seen or self.stack.executor.cell
        log.warning("%s: vehicle lost (%s): holding every cell it may be in, taking no task", self.me, verdict.reason)
        self._alarm("vehicle_lost", f"vehicle_lost: {verdict.reason}")
        self.vehicle.pause(True)
        if self.setpoints is not None:
            self.setpoints.suspend(True)
        self._carry_out(self.stack.vehicle_lost(step, seen, f"drone {self.me}'s vehicle is lost"))

    def _back(self, verdict: Verdict) -> None:
        assert verdict.cell is not None
        where = "landed below" if verdict.landed else "in"
        log.warning("%s: vehicle back, %s %s: it rests there", self.me, where, list(verdict.cell))
        self._alarm("vehicle_lost", None)
        self._carry_out(self.stack.vehicle_back(verdict.cell, verdict.landed))
        self.vehicle.pause(False, airborne=not verdict.landed)
        if self.setpoints is not None:
            self.setpoints.suspend(False)

    def _place(self) -> None:
        """Checked once the vehicle is located (see VehicleWatch.misplaced): judged once, for good."""
        self.placed = True
        self.out_of_service = self.watch.misplaced(self.stack.executor.cell)
        if self.out_of_service is not None:
            log.error("%s: %s", self.me, self.out_of_service)
            self._alarm("placement", f"placement: {self.out_of_service}")

    def on_step(self, report: StepReport, actions: Sequence[object]) -> None:
        """After the boundary's setpoints went out: judge the vehicle, record it, publish the state."""
        self.actual = self.watch.seen_cell()
        if self.actual is None:
            log.debug("%s: no cell at step %d: position %s", self.me, report.step, self.link.last_position())
        if not self.down and not self.watch.lost and self.vehicle.grounded_by_itself():
            self.down = True
            self.mail.refusal = "its vehicle came down by itself"
            below = self.watch.recorded_cell()
            where = f"in {list(below)}" if below is not None else "outside the grid"
            log.warning("%s: the vehicle came down by itself %s: its mail is handed back", self.me, where)
            cell = below if below is not None else self.stack.executor.cell
            self._carry_out(self.stack.vehicle_down(f"drone {self.me}'s vehicle came down by itself {where}", cell))
        self._alarm("lag", self._lag(report))
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

    def on_sample(self, sample: Sample) -> None:
        """Lambda after a boundary: record where the vehicle was, and judge how late it came."""
        seen = self.watch.seen_cell("sample")  # None: no fresh position, a gap in the record
        flown = sample.planned if sample.late_s is not None else seen
        if self.record is not None and seen is not None and flown is not None:
            self.record.write(record_line(sample.step, self.me, flown, sample.planned, self.delta))
        if self.down or self.watch.lost:
            return
        if self.late is not None and seen == self.stack.executor.cell and self.stack.executor.trajectory is None:
            self._on_time_again()  # in the air or landed below it: its vehicle is where its plan ended
        elif self.late is None and sample.late_s is None and self.vehicle.settled:
            self._late(sample)
        self.mail.refusal = self._refusal()
        self._alarm("late", None if self.late is None else f"late: {self.late}")

    def _on_time_again(self) -> None:
        log.warning("%s: its vehicle is where its plan ended: it takes tasks again", self.me)
        self.late = None
        self._carry_out(self.stack.tracking_bound(False, ""))

    def _late(self, sample: Sample) -> None:
        """Later than lambda, the margin peers planned with is gone: hold where the plan ends, until the
        vehicle is there."""
        self.late = (f"its vehicle was not in {list(sample.planned)} {self.ws.lateness_s:g} s (lambda) after "
                     f"step {sample.step} began")
        log.warning("%s: %s: it holds where its plan ends, and takes no task until it is on time", self.me, self.late)
        self._carry_out(self.stack.tracking_bound(True, f"drone {self.me}'s vehicle is later than lambda"))

    def _held_for_good(self) -> str:
        """What walls a goal off, for the operator: cells departed drones may hold, and where drones rest."""
        ghosts = self.stack.protocol.ghost_obstacles()
        return f"departed {sorted(ghosts)} at {sorted(t.last for t in ghosts.values())}, resting at " \
               f"{sorted(self.stack.taken_cells())}"

    def _resting_at(self, goal: Cell) -> str:
        """Which peers' plans end at ``goal``, and when, for the operator: they rest there from then on."""
        ending = sorted((traj.end_step, drone) for drone, traj in self.stack.protocol.known.items()
                        if drone != self.me and traj.last == goal)
        plans = ", ".join(f"{drone}'s at step {step}" for step, drone in ending)
        return f" (plans that end there: {plans})" if plans else ""

    def _lag(self, report: StepReport) -> str | None:
        """Trailing its timed trajectory, or on the ground while its plan flies: the separation argument
        assumes every drone is where its plan says."""
        if self.down or self.watch.lost:
            return None
        if self.stack.executor.flying and not self.vehicle.settled:
            return "lag: vehicle not in the air while its plan flies"
        return f"lag: vehicle {report.error_m:.1f} m from its cell" if report.lagging and self.vehicle.settled else None

    def _battery(self) -> float:
        pct = self.link.telemetry().battery_pct
        if pct is not None:
            self.battery_pct = float(pct)
        return self.battery_pct

    # -------------------------------------------------------------- actions
    def _carry_out(self, actions: Sequence[DroneAction]) -> None:
        # Protocol messages first: peers wait on them (the Sends after a StartExecuting are answers
        # to peers that waited for this plan). What only informs (mail progress, the plan's
        # announcement) goes out once the work at hand is done: at a step boundary the process's
        # other drones send their requests first.
        # Mostly one answer, or nothing: a process hands every request of a burst to each of its drones.
        ordered = coalesced(sorted(actions, key=urgency)) if len(actions) > 1 else actions
        presented: Trajectory | None = None  # one put on plan/<me> reaches every peer
        for action in ordered:
            if isinstance(action, Send):
                self._send(self.keys.proto(action.to, self.speaks_as), from_core(action.message))
            elif isinstance(action, Broadcast):
                # One put that Zenoh fans out to every peer (N - 1 messages on the wire, one call here),
                # at once: a plan proposed while a decision is handed round is the next in line's.
                self._send(self.keys.proto(BROADCAST, self.me), from_core(action.message),
                           copies=len(self.stack.protocol.members), now=True)
            elif isinstance(action, Answers):
                self._send(self.keys.answers(self.me), answers(action.trajectory, action.replies, action.holds),
                           copies=len(action.replies))
            elif isinstance(action, Decided):
                decided = answering(action.decision, action.replies, action.holds)
                self._send(self.keys.proto(BROADCAST, self.me), decided, copies=len(self.stack.protocol.members),
                           now=True)
            elif isinstance(action, GoTo):
                self.task_since = self.clock()
            elif isinstance(action, StartExecuting):
                self._alarm("leg", None)  # trying again (or a new leg)
                self._started(action)
            elif isinstance(action, TaskFailed):
                walls = f" (held for good: {self._held_for_good()})" if action.cut_off else ""
                log.warning("%s: no plan for task %s to %s: %s%s%s", self.me, action.task.id, list(action.task.goal),
                            action.reason, self._resting_at(action.task.goal), walls)
            elif isinstance(action, Threatened):
                log.warning("%s: %s may hold %s of my plan for good: planning its rest anew", self.me,
                            action.departed, [list(c) for c in action.cells])
            elif isinstance(action, Grounded):
                grounded = PlanAnnounce(trajectory=WireTrajectory.of(action.trajectory), grounded=True)
                self.node.put(self.keys.plan(self.me), encode(self.me, self.clock(), grounded))
            elif isinstance(action, Holding):
                flies = self.stack.protocol.current_trajectory(self.stack.now)
                told = PlanAnnounce(trajectory=WireTrajectory.of(flies), lost=True, holds=action.cells)
                self.node.put(self.keys.plan(self.me), encode(self.me, self.clock(), told))
            elif isinstance(action, Present) and action.trajectory != presented:
                presented = action.trajectory
                told = PlanAnnounce(trajectory=WireTrajectory.of(action.trajectory), braked=action.braked)
                self.node.put(self.keys.plan(self.me), encode(self.me, self.clock(), told))
            elif isinstance(action, Braked):
                log.warning("%s: braked short of %s, held for good: holding %s", self.me, list(action.held),
                            list(action.trajectory.last))
                cut = PlanAnnounce(trajectory=WireTrajectory.of(action.trajectory), braked=True)
                self.node.put(self.keys.plan(self.me), encode(self.me, self.clock(), cut))
            elif isinstance(action, RerouteFailed):
                log.warning("%s: no new plan for the rest of mine (task %s): %s", self.me, action.task.id,
                            action.reason)
            elif isinstance(action, LegNotFlown):
                seen = "in no cell" if action.seen is None else f"in {list(action.seen)}"
                text = f"leg_not_flown: the plan ended at {list(action.goal)}, telemetry put the vehicle {seen}"
                log.warning("%s: %s", self.me, text)
                self._alarm("leg", text)
            elif isinstance(action, (MailStarted, MailPickedUp, MailDelivered, MailRejected, MailLost)):
                asyncio.get_running_loop().call_soon(self.mail.progress, action)
            elif isinstance(action, (BatteryLow, BatteryRecharged)):
                log.info("%s: battery %s", self.me, type(action).__name__)

    def _send(self, key: str, body: ProtocolBody | CurTrajTo, copies: int = 1, now: bool = False) -> None:
        payload = encode(self.me, self.clock(), body)
        self.node.put(key, payload, now=now)
        self.metrics.messages_sent += copies

    def _started(self, action: StartExecuting) -> None:
        """A new plan, flown: every drone is told by its ``decide``."""
        if self.task_since is not None:
            self.metrics.latencies_s.append(self.clock() - self.task_since)
            self.task_since = None
        self.metrics.plans += 1
        self.vehicle.want_airborne(True)
        self.publish_state_soon()  # after the answers to the peers that waited for this plan
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
            self._check_sender(key, envelope.sender)
            self.bounds.check(envelope.body, self._step_now())
            message = to_core(envelope, self.me)
            answer = answer_in(envelope, self.me) if isinstance(envelope.body, Decide) else None
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
                self._carry_out(self.stack.peer_lost(sender, body.holds))
            elif body.braked:
                self._carry_out(self.stack.peer_braked(sender, body.trajectory.core()))
            else:
                self._carry_out(self.stack.heard(sender, body.trajectory.core()))

    def _step_now(self) -> int:
        """The step on this clock, also before the first boundary is stepped."""
        return max(self.stack.now, math.floor((self.clock() - self.epoch_s) / self.ws.tau_s))

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
            self.mail.service_back()
            return
        log.warning("%s: the service is gone: mail not on board is handed back", self.me)
        self._carry_out(self.stack.service_lost())

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
            coordination_ms=round(self.metrics.latencies_s[-1] * 1000, 3) if self.metrics.latencies_s else None,
            vehicle=self.watch.view(), command=stack.commanded)

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

    def _on_command(self, key: str, payload: bytes, query: Query) -> None:
        """An operator's command (only the service may ask: see fleet.transport.identity)."""
        try:
            body = decode_as(payload, FleetCommand, "a command")
        except WireError as exc:
            self.dropped.warning(key, "%s: dropped a command on %s: %s", self.me, key, exc)
            return
        log.warning("%s: %s%s, by %s", self.me, body.action.value, f" {body.about}" if body.about else "", body.by)
        try:
            if body.action is CommandAction.RELEASE:
                self._carry_out(self.stack.release(body.about or ""))
                self.mail.released(body.about or "", self.alive)
            else:
                self._carry_out(self.stack.command(body.action.value, f"{body.action.value} by {body.by}"))
        except ProblemError as exc:
            ack = CommandAck(drone=self.me, action=body.action, accepted=False, reason=str(exc))
        else:
            ack = CommandAck(drone=self.me, action=body.action, accepted=True)
        self.publish_state_soon()
        query.reply(self.keys.command(self.me), encode(self.me, self.clock(), ack))

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
