"""One drone's stack: task planner, coordination protocol, plan executor and battery monitor, wired.

The modules talk through events (paper Fig. 2). Inside one drone those are
handed over at once, in one call, as they would be in one event loop; only
messages between drones travel through the network, where the runtime (the
agent daemon or the systematic tester) may delay and reorder them.

Inputs: :meth:`DroneStack.receive` (a peer's message), :meth:`assign`
(mail), :meth:`peer_left` / :meth:`peer_joined` (membership), :meth:`vehicle_lost`
/ :meth:`vehicle_back`, and :meth:`step` (a step boundary of the local clock, with
the battery level and the cell telemetry puts the vehicle in). Outputs are the
actions below, which the runtime carries out.

Only physical truth counts: a leg is over (a mail picked up, delivered) when
telemetry puts the vehicle in the leg's goal cell, not when its plan ends. The
plan's last step ends at the boundary after it; by :func:`confirm_steps` more,
the vehicle must have been seen there (in the cell: cells are what separation is
judged in), or the leg did not happen (:class:`LegNotFlown`) and is tried again.

Making way. A leg to a pickup, drop-off or charger whose goal is taken, or whose last try
found no plan, names a shortest way to its goal in its request (``clear``). A drone
resting on that way, with nothing under way, leaves for the nearest free cell off it
(:func:`yield_spot`). A vehicle down cannot: cells asked once that stay taken are
gone around at the next try, and when no way is left every way is asked again.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field
from functools import lru_cache

from drona_gcs.errors import ProblemError
from drona_gcs.motion import Trajectory
from drona_gcs.planner import SafePlanner
from drona_gcs.planner.heuristic import UNREACHABLE, GoalDistance
from drona_gcs.stack.battery import BatteryLow, BatteryModel, BatteryMonitor, BatteryRecharged
from drona_gcs.stack.executor import Completed, PlanExecutor, Setpoint
from drona_gcs.stack.mail import DRAINED, NO_WAY, GoTo, MailAction, MailPlanner, MailRequest, Phase
from drona_gcs.stack.messages import HybridClock, Message, ReqForCurrentTraj, Task, task_of
from drona_gcs.stack.protocol import Action as ProtocolAction
from drona_gcs.stack.protocol import (
    Braked,
    ClockBound,
    CoordinationProtocol,
    Event,
    NewTask,
    NextStep,
    PeerAnnounced,
    PeerBraked,
    PeerDown,
    PeerJoined,
    PeerLeft,
    PeerLost,
    PlanCompleted,
    Released,
    Relocated,
    Reroute,
    RerouteFailed,
    StartExecuting,
    State,
    TaskFailed,
    Threatened,
    VehicleDown,
    VehicleLost,
)
from drona_gcs.workspace import Cell, Workspace


def confirm_steps(workspace: Workspace) -> int:
    """Boundaries after a plan's end by which the vehicle must have been seen in its goal: it may
    enter it up to lambda late, and one more for a vehicle that trails by a cell (the lag alarm's)."""
    return math.ceil(workspace.lateness_s / workspace.tau_s) + 1


@dataclass(frozen=True)
class Arrival:
    """A plan ended at ``goal``; the leg counts once telemetry puts the vehicle there, by ``deadline``."""

    goal: Cell
    deadline: int


@dataclass(frozen=True)
class LegNotFlown:
    """A plan ended, yet telemetry never put the vehicle in its goal: the leg did not happen."""

    goal: Cell
    seen: Cell | None  #: where telemetry put the vehicle last (None: in no cell)


DroneAction = (ProtocolAction | Setpoint | Completed | MailAction | BatteryLow | BatteryRecharged
               | LegNotFlown)


CLIMB_RATE_M_S = 1.5  #: a cautious take-off climb rate, for the default lead time
ARM_AND_MODE_S = 2.0  #: mode change, arming and take-off command acknowledged
SPOOL_UP_S = 4.0  #: an accepted take-off to leaving the ground (ArduCopter SITL: about 3.5 s)


def default_lead_steps(workspace: Workspace, speedup: float = 1.0) -> int:
    """Delta + 1, plus the steps a landed drone needs to take off and climb into the grid (``speedup``: a
    fake vehicle's simulated seconds per second)."""
    climb_s = ARM_AND_MODE_S + SPOOL_UP_S + workspace.geo.layer0_alt_m / CLIMB_RATE_M_S
    return workspace.delta + 1 + math.ceil(climb_s / speedup / workspace.tau_s)


ROUND_S = 1.0  #: a coordination round, from the request to the last ack, with room (LAN p99: tenths of a second)


def default_hover_lead_steps(workspace: Workspace) -> int:
    """Delta + 1, plus the steps a round takes: a drone in the air climbs no more before its plan."""
    return workspace.delta + 1 + math.ceil(ROUND_S / workspace.tau_s)


def leg_overhead(lead_steps: int) -> int:
    """Steps of flight a leg takes besides its moves: the lead steps before its plan starts
    (climbing, or hovering) and the plan's first step, held in the start cell."""
    return lead_steps + 1


@dataclass(frozen=True)
class StackConfig:
    """What every drone of a fleet shares (immutable: copies of a simulated fleet share it)."""

    workspace: Workspace
    planner: SafePlanner
    battery: BatteryModel = field(default_factory=BatteryModel)
    low_mark: float = 40.0
    recharged_mark: float = 95.0
    lead_steps: int | None = None  #: steps between planning and a plan's start; default Delta + 1
    hover_lead_steps: int | None = None  #: the same for a drone in the air (at most ``lead_steps``); default that

    def __deepcopy__(self, memo: dict[int, object]) -> StackConfig:
        return self


class DroneStack:
    def __init__(self, me: str, config: StackConfig, peers: Mapping[str, Cell], epoch: int = 0) -> None:
        """``epoch``: this agent's incarnation, larger at each restart (the runtime's boot time)."""
        ws = config.workspace
        self.me = me
        self.config = config
        start = peers[me]
        self.clock = HybridClock(me, epoch)
        planner = config.planner
        lead = config.lead_steps if config.lead_steps is not None else config.planner.delta + 1
        self.protocol = CoordinationProtocol(me, start, dict(peers), planner.plan, lead, planner.delta,
                                             hover_lead_steps=config.hover_lead_steps)
        self.executor = PlanExecutor(start)
        self.monitor = BatteryMonitor(config.low_mark, config.recharged_mark)
        parking = own_parking(ws.parking, list(peers), me)
        mine = set(parking) if len(ws.parking) >= len(peers) else set()
        resting = {*ws.charging_stations, *(c for c in ws.parking if c not in mine)}  # others may rest there
        self.resting_now: frozenset[Cell] = frozenset()  #: cells other drones rest on, at the last decision
        self.level = 100.0  #: the battery level at the last step boundary
        self.ways = _distance_function(planner, resting)
        self.mail = MailPlanner(start, ws.charging_stations, parking, self.distance,
                                config.battery, recharged_level=config.recharged_mark, leg_overhead=leg_overhead(lead),
                                spare_parking=[c for c in ws.parking if c not in parking])
        self.mail_cells = frozenset(ws.pickups) | frozenset(ws.dropoffs)  #: the workspace's mail stops
        self.arrival: Arrival | None = None  #: a plan ended; waiting to see the vehicle at its goal
        #: goals whose last try found no plan, until a plan reaches one (legs elsewhere come between:
        #: a charger walled in, tried between legs to parking, never asked its way clear)
        self.unreached: frozenset[Cell] = frozenset()
        self.asked_clear: frozenset[Cell] = frozenset()  #: resting cells the last leg asked to leave
        self.stuck: frozenset[Cell] = frozenset()  #: of those, cells still taken at the next failure
        self.stop_short: Cell | None = None  #: where a rerouted leg ends instead of its goal, held for good
        self.braked: Cell | None = None  #: where the plan flown was cut short of a cell held for good
        self.threat: Threatened | None = None  #: what the reroute under way goes around
        self.commanded: str | None = None  #: the operator's command in force (see :meth:`command`)
        #: in touch with most of the fleet at the last boundary (CoordinationProtocol.in_quorum); not before the
        #: first: a drone starting up meets its peers one by one, and hands back no mail meanwhile
        self.in_touch = False
        self.clock_off = False  #: my clock is beyond the fleet's bound (see :meth:`clock_bound`)
        self.late = False  #: my vehicle came to a cell later than lambda (see :meth:`tracking_bound`)

    def distance(self, a: Cell, b: Cell) -> int:
        """Steps from ``a`` to ``b``, around the drones resting now and never through a vehicle down, nor
        where a peer whose clock is off rests, for as long as it is off (the task planner's distance; see
        :func:`_distance_function`). The rest of its plan is only passed through."""
        protocol = self.protocol
        off = (protocol.known[p].last for p in protocol.outliers if p in protocol.known)
        return self.ways(a, b, self.resting_now, frozenset((*protocol.peers_down.values(), *off)))

    def copy(self) -> DroneStack:
        """A copy whose task planner measures ways with the copy's state (the tester's clones)."""
        new = copy.copy(self)
        new.mail = copy.copy(self.mail)
        new.mail.distance = new.distance
        return new

    # ------------------------------------------------------------ inputs
    @property
    def now(self) -> int:
        return max(self.executor.step, 0)

    def receive(self, message: Message) -> list[DroneAction]:
        self.clock.observe(task_of(message).stamp)
        if isinstance(message, ReqForCurrentTraj) and message.clear:
            self._make_way(message.clear)
        return self._protocol(message)

    def _make_way(self, way: tuple[Cell, ...]) -> None:
        """A peer's leg found no plan and asks drones resting on ``way`` to leave it: if we rest
        there, leave for the nearest cell off it (see MailPlanner.make_way)."""
        here = self.protocol.location
        if self.protocol.state is not State.WAIT_FOR_TASK or here not in way:
            return
        spot = yield_spot(self.config.workspace, here, frozenset(way), self.taken_cells())
        if spot is not None:  # out while the peer flies there, a detour to park on the way included
            self.mail.make_way(spot, 2 * len(way))

    def assign(self, request: MailRequest) -> list[DroneAction]:
        self.mail.assign(request)
        return []

    def cancel(self, mail_id: str) -> bool:
        """Drop a mail that waits in the queue (False if it is under way or unknown)."""
        return self.mail.cancel(mail_id)

    # ------------------------------------------------------ operator's commands
    def command(self, action: str, reason: str) -> list[DroneAction]:
        """An operator's command by name: pause, resume, recall or land (ProblemError for another)."""
        if action == "pause":
            self.pause()
            actions: list[DroneAction] = []
        elif action == "resume":
            self.resume()
            actions = []
        elif action == "recall":
            actions = self.recall(reason)
        elif action == "land":
            actions = self.land_here(reason)
        else:
            raise ProblemError(f"no such command {action!r}: pause, resume, recall or land")
        self.commanded = None if action == "resume" else action
        return actions

    def pause(self) -> None:
        """No mail starts: legs under way are flown to their end, mail on board is delivered, then the
        drone parks (at its parking cell, or a charger) as an idle one does."""
        self.mail.pause()

    def resume(self) -> None:
        """Undo :meth:`pause`, :meth:`recall` and :meth:`land_here`: the drone takes mail again."""
        self.mail.resume()

    def recall(self, reason: str) -> list[DroneAction]:
        """Finish the leg under way, hand back every mail not on board (mail on board is delivered
        first), then park, paused."""
        self.pause()
        return list(self.mail.release(reason))

    def land_here(self, reason: str) -> list[DroneAction]:
        """Stop where the drone is, through the protocol: a drone flying a plan plans its rest anew,
        to stay at the cell its plan reaches once a new plan can start (a round, as any reroute: every
        peer learns it stays there before it stops); at rest it lands where it is. Mail not on board is
        handed back; then no leg at all until :meth:`resume`. Should the round find no plan, the drone
        flies its plan to the end and stays there, as its peers planned."""
        actions = self.recall(reason)
        self.mail.hold()
        return [*actions, *self._stop_here()]

    def _stop_here(self) -> list[DroneAction]:
        """A held drone flying a plan: plan its rest anew, to stay where the plan is once a new plan can
        start (see :meth:`land_here`). A round under way ends in a plan, which this stops in turn."""
        trajectory = self.protocol.trajectory
        if self.protocol.state is not State.EXECUTING or trajectory is None:
            return []
        stop = trajectory.at(self.now + self.protocol.airborne_lead)
        if stop == trajectory.last:
            return []
        self.stop_short, self.threat = stop, None
        task = self._hovering_task(stop)
        return self._protocol(Reroute(task))

    def vehicle_down(self, reason: str, cell: Cell) -> list[DroneAction]:
        """The vehicle came down by itself in ``cell``: hand every mail back (see MailPlanner.abandon),
        hold there, and tell every peer it stays there for good (``Grounded``). The runtime starts no
        new task meanwhile (``may_plan`` False at :meth:`step`)."""
        actions: list[DroneAction] = list(self.mail.abandon(reason))
        self.executor.relocate(cell)
        self.arrival = None
        return [*actions, *self._protocol(VehicleDown(cell))]

    def _ground_if_drained(self) -> list[DroneAction]:
        """A drone at rest whose battery affords no move off a charger stays there for good: as for a
        vehicle down, its mail goes back and every peer holds its cell (a pickup or drop-off it rests
        on is handed back by those who need it, not waited for)."""
        if self.protocol.down is not None or self.protocol.state is not State.WAIT_FOR_TASK \
                or self.mail.busy or not self.mail.drained(self.level):
            return []
        self.mail.land()
        return self.vehicle_down(f"drone {self.me}: {DRAINED}", self.protocol.location)

    def release(self, drone: str) -> list[DroneAction]:
        """The operator saw ``drone``, gone from the fleet, out of the air for good: hold none of its
        cells (ProblemError if it is no departed drone)."""
        return self._protocol(Released(drone))

    def peer_braked(self, drone: str, trajectory: Trajectory) -> list[DroneAction]:
        """``drone`` announced it cut its plan short, to ``trajectory``: it holds at its end."""
        return self._protocol(PeerBraked(drone, trajectory))

    def peer_lost(self, drone: str, cells: tuple[Cell, ...]) -> list[DroneAction]:
        """``drone`` announced its vehicle is lost and may be in ``cells`` for good (none: it is back)."""
        return self._protocol(PeerLost(drone, cells))

    def peer_down(self, drone: str, cell: Cell) -> list[DroneAction]:
        """``drone`` announced its vehicle came down in ``cell``: an obstacle for good, and a new plan
        for the rest of ours if that crosses it."""
        return self._protocol(PeerDown(drone, cell))

    def vehicle_lost(self, since: int, seen: Cell, reason: str) -> list[DroneAction]:
        """The vehicle stopped answering at step ``since``, last seen in ``seen``: the protocol holds
        every cell it may be in (see CoordinationProtocol.holds), and the mail not on board is handed
        back for other drones to fly. The runtime starts no task meanwhile."""
        return [*self._protocol(VehicleLost(since, seen)), *self.mail.release(reason)]

    def clock_bound(self, mine_off: bool, outliers: frozenset[str], reason: str) -> list[DroneAction]:
        """The clock check's verdict (see ClockBound): my clock off, I hold where my plan ends and hand the
        mail not on board back; the runtime starts no task meanwhile (``may_plan`` False)."""
        self.clock_off = mine_off
        return self._out_of_bounds(outliers, reason)

    def tracking_bound(self, late: bool, reason: str) -> list[DroneAction]:
        """The lateness check's verdict: my vehicle came to a cell later than lambda, so the margin
        peers planned with is gone. As with a clock off, I hold where my plan ends, hand back the mail
        not on board, and every peer holds that for good, until the vehicle is back on time."""
        self.late = late
        return self._out_of_bounds(self.protocol.outliers, reason)

    def _out_of_bounds(self, outliers: frozenset[str], reason: str) -> list[DroneAction]:
        off = self.clock_off or self.late
        newly_off = off and self.protocol.off_since is None
        actions = self._protocol(ClockBound(off, outliers))
        return [*actions, *(self.mail.release(reason) if newly_off else ())]

    def vehicle_back(self, cell: Cell, landed: bool) -> list[DroneAction]:
        """The lost vehicle is back, seen in ``cell`` (``landed``: on the ground below it): the drone
        rests there, with no plan; the mail stays as it was. Not while coordinating (the runtime waits)."""
        actions = self._protocol(Relocated(cell))
        self.executor.relocate(cell)
        self.mail.relocate(cell, landed)
        self.arrival = None
        return actions

    def peer_left(self, drone: str, silent_since: int | None = None) -> list[DroneAction]:
        return self._protocol(PeerLeft(drone, silent_since))

    def heard(self, drone: str, trajectory: Trajectory) -> list[DroneAction]:
        """A peer announced its new plan (see CoordinationProtocol.heard): one held as gone is back."""
        return self._protocol(PeerAnnounced(drone, trajectory))

    def peer_joined(self, drone: str, cell: Cell, trajectory: Trajectory | None = None) -> list[DroneAction]:
        return self._protocol(PeerJoined(drone, cell, trajectory))

    def step(self, step: int, battery_level: float, flown: Cell | None, physical_time: int = 0,
             may_plan: bool = True) -> list[DroneAction]:
        """Step boundary ``step``: move, feel the battery, then let the task planner decide.

        ``flown``: the cell telemetry puts the vehicle in now (None: in none), which ends the
        last step. With ``may_plan`` False (the runtime found the clock-skew bound broken, or the
        vehicle is not ready) no new task starts: the drone finishes what it flies and holds.
        """
        actions: list[DroneAction] = self._protocol(NextStep()) if step > 0 else []
        for done in self.executor.tick(step):
            actions.append(done)
            if isinstance(done, Completed):
                actions += self._protocol(PlanCompleted())
                self.arrival = Arrival(done.trajectory.last, step + confirm_steps(self.config.workspace))
        actions += self._arrive(step, flown)
        for event in self.monitor.reading(battery_level):
            actions.append(event)
            if isinstance(event, BatteryLow):
                self.mail.battery_low()
            else:
                self.mail.battery_recharged()
        self.level = battery_level
        actions += self._cut_off()
        actions += self._ground_if_drained()
        self._land_if_spent(step)
        if not may_plan and self.protocol.off_since is not None and self.protocol.state is State.WAIT_FOR_TASK:
            self.mail.land()  # out of bounds, it holds where its plan ended for long: on the ground, for free
        if may_plan and self.protocol.state is State.WAIT_FOR_TASK:
            taken = self.taken_cells()
            self.resting_now = frozenset(taken)
            self._off_mail_cells(taken)
            for decided in self.mail.decide(step, battery_level, taken, self.passing_cells()):
                actions.append(decided)
                if isinstance(decided, GoTo):
                    actions += self._protocol(NewTask(self._task(decided, step, physical_time)))
        return actions

    def _off_mail_cells(self, taken: set[Cell]) -> None:
        """A drone with nothing to do and nowhere to park leaves a workspace's pickup or drop-off cell for
        the nearest cell off them: waiting there, it would wall in the next mail that needs it."""
        here = self.protocol.location
        if here not in self.mail_cells or not self.mail.homeless:
            return
        spot = yield_spot(self.config.workspace, here, self.mail_cells, taken)
        if spot is not None:
            self.mail.make_way(spot)

    def service_lost(self) -> list[DroneAction]:
        """Out of touch with the service that dispatches the mail, a drone hands back every mail it was
        not cleared to pick up: the service requeues a lost drone's mail not cleared a lease after it saw
        it go, by when the drone, only cut off, has seen the service go too; cleared mail it holds as the
        drone's until it is back. So no mail has two owners."""
        return list(self.mail.release(SERVICE_LOST, keep_cleared=True))

    def _cut_off(self) -> list[DroneAction]:
        """Out of touch with most of the fleet, a drone plans nothing, and the other side may take its mail
        over: it hands back every mail not on board, once, so that no mail has two owners."""
        was, self.in_touch = self.in_touch, self.protocol.in_quorum()
        return list(self.mail.release(CUT_OFF)) if was and not self.in_touch else []

    def _task(self, leg: GoTo, step: int, physical_time: int) -> Task:
        """The motion task of a leg. The leg's flight budget pays for more than the plan's moves:
        the plan's first step, held in the start cell, and the lead steps before it, which a drone
        on the ground flies climbing once its plan is made, and a drone in the air hovers, from
        ``step`` on while it coordinates (the protocol counts those steps when it plans)."""
        hovering = None if self.landed else step
        flight = leg.flight_steps
        if flight is not None:
            flight -= 1 if hovering is not None else 1 + self.protocol.lead_steps
        return Task(self.clock.next_id(max(physical_time, step)), leg.goal, flight, hovering, self._way_to_clear(leg))

    def _reroute_task(self, threat: Threatened) -> Task:
        """A new plan for the rest of the leg flown: same goal, with what the battery affords now
        less what must remain there; it is flown from now on (hovering, as far as budgets go). When
        the goal itself may be held for good, the leg stops short, at the nearest cell off the held
        ones, and is decided anew from there (see :meth:`_arrive`)."""
        trajectory = self.protocol.trajectory
        assert trajectory is not None
        goal, self.stop_short, self.threat = trajectory.last, None, threat
        if goal in threat.cells:
            goal = self._short_of(threat) or goal
        return self._hovering_task(goal)

    def _hovering_task(self, goal: Cell) -> Task:
        """A new rest of the plan flown, to ``goal``: flown from now on, as far as budgets go, with what
        the battery affords now less what must remain there, and less the plan's first step (see
        :meth:`_task`)."""
        flight = self.mail.flight_to(goal, self.level)
        return Task(self.clock.next_id(self.now), goal, None if flight is None else flight - 1,
                    hovering_since=self.now)

    def _short_of(self, threat: Threatened) -> Cell | None:
        """Where the leg flown stops short of the cells ``threat`` holds: the nearest cell off them from
        where a new plan would start (that cell itself, if it can be held); None if there is none."""
        trajectory = self.protocol.trajectory
        assert trajectory is not None
        start = trajectory.at(self.now + self.protocol.airborne_lead)
        self.stop_short = yield_spot(self.config.workspace, start, frozenset(threat.cells), self.taken_cells())
        return self.stop_short

    def _stop_short_instead(self) -> list[DroneAction]:
        """The rerouted leg found no plan to its goal: stop short of the held cells instead (once)."""
        threat, self.threat = self.threat, None
        if (threat is None or self.stop_short is not None or self.braked is not None
                or self.protocol.state is not State.EXECUTING):
            self.stop_short = None
            return []
        stop = self._short_of(threat)
        if stop is None:
            return []
        task = self._hovering_task(stop)
        return self._protocol(Reroute(task))

    def _way_to_clear(self, leg: GoTo) -> tuple[Cell, ...]:
        """The way a mail or charging leg asks resting drones to leave: when its goal is taken, or
        its last try found no plan (the paper leaves MRMP incomplete: resting drones wall goals in).
        A shortest way, around cells it asked before that stayed taken (a vehicle down cannot move)."""
        taken = self.taken_cells()
        if leg.purpose not in ASKING or (leg.goal not in taken and leg.goal not in self.unreached):
            return ()
        self.stuck = self.stuck | (self.asked_clear & taken)
        here, ws = self.protocol.location, self.config.workspace
        way = ws.shortest_way(here, leg.goal, self.stuck - {leg.goal})
        if not way:  # every way was asked once: ask them all again, in turn
            self.stuck = self.asked_clear & taken
            way = ws.shortest_way(here, leg.goal, self.stuck - {leg.goal}) or ws.shortest_way(here, leg.goal)
        self.asked_clear = frozenset(way) & taken
        return way

    def _arrive(self, step: int, flown: Cell | None) -> list[DroneAction]:
        """A leg is over when the vehicle is seen at its goal; past the deadline it did not happen."""
        arrival = self.arrival
        if arrival is None:
            return []
        if flown == arrival.goal:
            self.arrival = None
            if arrival.goal != self.mail.goal:  # stopped short of it: not done, decided anew here
                self.stop_short = self.braked = None
                self.mail.relocate(arrival.goal, landed=True)
                return []
            return list(self.mail.leg_done())
        if step < arrival.deadline:
            return []
        self.arrival = None
        return [LegNotFlown(arrival.goal, flown), *self.mail.leg_not_flown(step)]

    def _land_if_spent(self, step: int) -> None:
        """A drone that hovers while it coordinates pays for it from its leg's flight budget (see
        Task.max_length). Once what is left no longer affords the shortest way to the goal, it
        lands: the round's plan will be refused and the leg tried again from the ground, so a round
        that ends late, or never, does not drain the battery below what must remain."""
        task = self.protocol.task
        if self.protocol.state is not State.COORDINATING or task is None or self.landed:
            return
        left = task.max_length(step + self.protocol.lead_for(task))
        if left is not None and left < self.mail.distance(self.protocol.location, task.goal):
            self.mail.land()

    @property
    def landed(self) -> bool:
        return self.mail.landed(holding=not self.executor.flying)

    def passing_cells(self) -> set[Cell]:
        """Cells live peers hold only until they move on: where their plans under way end (they rest there
        until their next leg), and every cell of the plan under way of a peer whose clock is off (held for
        good only until it rests)."""
        now, outliers = self.now, self.protocol.outliers
        return {cell for drone, traj in self.protocol.known.items()
                if drone != self.me and drone not in self.protocol.ghosts and traj.end_step > now
                for cell in (traj.cells if drone in outliers else (traj.last,))}

    def taken_cells(self) -> set[Cell]:
        """Cells where other drones rest, as far as this drone knows."""
        resting = {traj.last for drone, traj in self.protocol.known.items()
                   if drone != self.me and drone not in self.protocol.ghosts}
        return resting | {traj.last for traj in self.protocol.ghost_obstacles().values()}

    # ---------------------------------------------------------- wiring
    def _protocol(self, event: Event) -> list[DroneAction]:
        actions: list[DroneAction] = []
        for action in self.protocol.handle(event, self.now):
            actions.append(action)
            if isinstance(action, StartExecuting):
                self.executor.start(action.trajectory)
                if action.trajectory.last != self.braked:
                    self.braked = None  # a rerouted rest replaced the cut plan
                self.mail.took_off()
                self.unreached -= {action.trajectory.last}
                self.asked_clear, self.stuck = frozenset(), frozenset()
                if self.mail.held and self.stop_short is None:
                    actions += self._stop_here()  # landed by the operator while this round went on
            elif isinstance(action, TaskFailed):
                self.unreached |= {action.task.goal}
                actions += self.mail.leg_failed(self.now, cut_off=action.cut_off)
            elif isinstance(action, Threatened):
                actions += self._protocol(Reroute(self._reroute_task(action)))
            elif isinstance(action, RerouteFailed):
                actions += self._stop_short_instead()
            elif isinstance(action, Braked):
                self.executor.start(action.trajectory)
                self.braked = action.trajectory.last
        return actions


CUT_OFF = "cut off from most of the fleet"  #: why a drone out of touch with a majority hands its mail back
SERVICE_LOST = "out of touch with the service"  #: why a drone the service dispatches to hands its mail back

#: Legs that ask drones resting on their way to leave it; a drone going to park waits instead.
ASKING = frozenset({Phase.TO_PICKUP, Phase.TO_DROPOFF, Phase.TO_CHARGER})


def yield_spot(workspace: Workspace, here: Cell, way: frozenset[Cell], taken: Collection[Cell]) -> Cell | None:
    """The nearest cell off ``way`` a drone resting in ``here`` can make way to: free, reachable
    around other resting drones, and no charger or parking cell (where drones come to rest) unless
    only those are left (boxed in, a drone would otherwise stay on the way)."""
    rest_spots = {*workspace.charging_stations, *workspace.parking}
    reach = workspace.distances_from(here, frozenset(taken) - {here})
    spots = [(cell in rest_spots, steps, cell) for cell, steps in reach.items()
             if cell not in way and cell not in taken]
    return min(spots)[2] if spots else None


def own_parking(parking: Sequence[Cell], drones: Sequence[str], me: str) -> Sequence[Cell]:
    """With a parking cell for every drone, each has its own (the i-th drone the i-th cell): idle
    drones never race for one, which would cost whole coordination rounds that end in no plan."""
    if len(parking) >= len(drones):
        return (parking[drones.index(me)],)
    return parking


#: ways(a, b, resting_now, walls): steps from a to b (see _distance_function)
Ways = Callable[[Cell, Cell, frozenset[Cell], frozenset[Cell]], int]


def _distance_function(planner: SafePlanner, resting: Collection[Cell] = ()) -> Ways:
    """Steps of the shortest static path between cells, one cached BFS per target cell.

    ``resting``: cells other drones may rest on for good (chargers, their parking cells), and
    ``resting_now`` those they rest on now. The way goes around them, where it can: a budget
    that counted the way through a parked drone left a drone without the battery for the way
    around, stranded for good (found by the systematic tester). Either end may be such a cell.
    Where they wall the goal in, the way is through them: a drone at rest makes way. It never is
    through ``walls``, cells held for good (vehicles down), which nothing moves out of, nor to one.
    """
    ws, graph, grid = planner.workspace, planner.graph, planner.grid
    always = frozenset(ws.cell_id(c) for c in resting)

    @lru_cache(maxsize=256)
    def to(goal: Cell, avoid: frozenset[int]) -> GoalDistance:
        return graph.distances(ws.cell_id(goal), avoid)

    @lru_cache(maxsize=8)
    def ids(cells: frozenset[Cell]) -> frozenset[int]:
        return frozenset(ws.cell_id(c) for c in cells)

    def steps(a: Cell, b: Cell, around: bool, resting_now: frozenset[Cell], walls_now: frozenset[Cell]) -> float:
        walls = ids(walls_now)
        avoid = always | ids(resting_now) | walls if around else walls
        tree, start = to(b, avoid), ws.cell_id(a)
        if around and start in avoid and a != b:  # out of a resting cell: by its first move
            return min((cost + tree.get(cell) for cell, cost in grid.moves_only[start]), default=UNREACHABLE)
        return tree.get(start)

    def distance(a: Cell, b: Cell, resting_now: frozenset[Cell], walls: frozenset[Cell]) -> int:
        if a in walls or b in walls:
            return NO_WAY  # nothing gets into a vehicle down's cell (a pickup it sits on, a charger)
        d = steps(a, b, True, resting_now, walls)
        if d >= UNREACHABLE:
            d = steps(a, b, False, resting_now, walls)
        return int(d) if d < UNREACHABLE else NO_WAY

    return distance
