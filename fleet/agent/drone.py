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
vehicle (ready, lost, back) in :mod:`fleet.agent.watch`, and what it does about it at each
boundary in :mod:`fleet.agent.tracking`; what it takes from its peers (messages, plans,
liveliness, clocks) in :mod:`fleet.agent.peers`. A drone takes tasks only
while its vehicle is ready, answering, and placed where the stack holds it.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TextIO

from drona_gcs.errors import ProblemError
from drona_gcs.geo import GeoFrame
from drona_gcs.motion import Trajectory
from drona_gcs.stack.battery import BatteryLow, BatteryRecharged
from drona_gcs.stack.drone import DroneAction, DroneStack, LegNotFlown
from drona_gcs.stack.mail import GoTo, MailDelivered, MailLost, MailPickedUp, MailRejected, MailStarted
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
from fleet.agent.admission import TaskBudget
from fleet.agent.clocksync import ClockCheck
from fleet.agent.maildesk import MailDesk
from fleet.agent.outbox import Answers, Decided, Proposed, coalesced, urgency
from fleet.agent.peers import PeerSide
from fleet.agent.tracking import Tracking
from fleet.agent.vehicle import VehicleSupervisor
from fleet.agent.watch import VehicleWatch
from fleet.logs import Throttled
from fleet.setpoint_loop import SetpointLoop
from fleet.transport.identity import Speakers
from fleet.transport.keys import FleetKeys
from fleet.transport.node import Node, Query
from fleet.transport.wire import (
    CommandAck,
    CommandAction,
    CurTrajTo,
    DroneState,
    FleetCommand,
    Health,
    PeerBounds,
    PlanAnnounce,
    ProtocolBody,
    TaskView,
    WireError,
    WireTrajectory,
    answering,
    answers,
    decode_as,
    encode,
    from_core,
    proposing,
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


class DroneAgent(Tracking, PeerSide):
    """One drone's agent: its stack, carried out over Zenoh and its vehicle (see the module docstring)."""

    def __init__(self, stack: DroneStack, node: Node, keys: FleetKeys, link: VehicleLink,
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
        self.recorded: Cell | None = None  #: the cell of the last record written
        self.passing: tuple[Cell, ...] = ()  #: the cells telemetry saw since (see Tracking._record)
        self.battery_pct = 100.0
        self.may_plan = True
        #: why the vehicle is out of its lateness bound (None: within it; see on_sample)
        self.late: str | None = None
        #: how its autopilot's limits, set in flight, fall short of the workspace's (None: they do not)
        self.limits_short: str | None = None
        self.on_time_at: int | None = None  #: the last step the vehicle was seen in its cell within lambda
        #: the vehicle came down by itself: its mail is handed back and it starts no task, for good (a
        #: vehicle may be anywhere once down: it rejoins the fleet when its agent is restarted)
        self.down = False
        self.task_since: float | None = None
        #: how late this drone's last boundary was taken, and how long peers' news waits for the loop
        self.boundary_late_s = 0.0
        self.backlog_s: Callable[[], float] = lambda: 0.0  #: (set by the host: its inbox's)
        #: the tasks this host's drones may start at a boundary (set by the host: one for all its drones)
        self.budget = TaskBudget.of_period(self.ws.tau_s)
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
        # those before it in line), while states, mail and clocks can wait their turn.
        # With only the answers first, the requests of the drones later in line waited while those before
        # them planned, when the whole fleet coordinated at once.
        node.subscribe(keys.proto(self.me), self._on_protocol, first=True)
        node.subscribe(keys.answers(), self._on_protocol, first=True)
        # A request to everyone: this host's drones answer it in one message (see ZenohNode.subscribe).
        node.subscribe(keys.proto(BROADCAST), self._on_protocol, gather=True, first=True)
        # News on plan/ goes before all: a drone flying must act on a peer's brake, or its vehicle down, late
        # or lost (found over 128 agents: read seconds late, behind the protocol's messages).
        node.subscribe(keys.plan(), self._on_plan, urgent=True)
        node.queryable(keys.state(self.me), self._on_state_query)
        node.queryable(keys.clock(self.me), self._on_clock_query)
        node.queryable(keys.command(self.me), self._on_command)
        self.mail.declare()
        # With the protocol's messages, in the order they came: a peer that left and came back must not have
        # its new request handled before its leaving (which would drop the request, held for an answer).
        node.watch_liveliness(keys.alive(), self._on_liveliness, first=True)
        if not self.mail.adopt:  # a service dispatches the mail
            node.watch_liveliness(keys.service(), self._on_service, first=True)
            # Any key of my reports: the service subscribes to them all.
            node.on_matching(keys.status(self.me, "any"), self._on_reports_heard)
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
        actions = self.stack.step(step, level, self.watch.flown(), may_plan=self._may_plan(step))
        if any(isinstance(action, GoTo) for action in actions):
            self.budget.started(step)
        self._carry_out(actions)
        # A lease of grace: a drone cut off (not gone) has seen it too by then, and handed its mail back.
        self.mail.adopt_due(step, self.alive, self.stack.in_touch)
        self.mail.publish_held()
        return actions

    def _may_plan(self, step: int) -> bool:
        self.mail.refusal = self._refusal()
        return (self.may_plan and self.mail.accepting and self.mail.refusal is None and self._keeping_up()
                and self._within_budget(step))

    def _within_budget(self, step: int) -> bool:
        """Whether the host may start one more task at this boundary (see fleet.agent.admission). Else the
        task waits for the next boundary, its mail this drone's, as a busy host's does."""
        peers = len(self.alive - {self.me})
        waiting = self.stack.protocol.state is State.WAIT_FOR_TASK and bool(self.mail.listed())
        if self.budget.may_start(step, peers, self.me, waiting):
            return True
        if waiting:
            self.dropped.warning("budget", "%s: the host started %s task(s) at this boundary, all it may with %d "
                                 "peers: no task starts", self.me, self.budget.per_boundary(peers), peers)
        return False

    def _keeping_up(self) -> bool:
        """Whether this host takes its boundaries, and its peers' news, in time: a task started while it
        does not makes it later still, and a brake of a peer reaches a drone flying only as fast as the
        inbox (found over 128 agents on 2 cores: news seconds old, vehicles late, two braked into one
        cell). A task waits for the next boundary instead; its mail stays this drone's. No alarm: the
        drone is healthy, and the service must not give its mail to another for a moment's load."""
        bound = self.budget.bound_s
        behind = max(self.boundary_late_s, self.backlog_s())
        if behind > bound:
            self.dropped.warning("busy", "%s: the host is %.0f ms behind (bound %.0f ms): no task starts", self.me,
                                 behind * 1000, bound * 1000)
        return behind <= bound

    def _refusal(self) -> str | None:
        """Why this drone takes no mail and starts no task now (None: it may)."""
        self.mail.refusing_for_good = self.down or self.out_of_service is not None
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

    # -------------------------------------------------------------- actions
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
            elif isinstance(action, Proposed):
                proposed = proposing(action.proposal, action.replies, action.current, action.holds)
                self._send(self.keys.proto(BROADCAST, self.me), proposed, copies=len(self.stack.protocol.members),
                           now=True)
            elif isinstance(action, GoTo):
                self.task_since = self.clock()
            elif isinstance(action, StartExecuting):
                self._alarm("leg", None)  # trying again (or a new leg)
                self._started(action)
            elif isinstance(action, TaskFailed):
                self._round_ended()
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
                told = PlanAnnounce(trajectory=WireTrajectory.of(flies), lost=True, holds=action.cells,
                                    for_now=action.for_now, holds_seq=action.seq)
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

    def _round_ended(self) -> float | None:
        """How long the task's round took (None: no round was under way)."""
        if self.task_since is None:
            return None
        took, self.task_since = self.clock() - self.task_since, None
        self.budget.round_ended(took)
        return took

    def _started(self, action: StartExecuting) -> None:
        """A new plan, flown: every drone is told by its ``decide``."""
        took = self._round_ended()
        if took is not None:
            self.metrics.latencies_s.append(took)
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
            clock_offset_s=self.clocks.offsets_s(),
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
