"""One drone's machines, wired: what each machine's action does to the others, and the motion tasks of
the drone's legs (see :mod:`drona_gcs.stack.drone`, whose :class:`DroneStack` adds the inputs)."""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Self

from drona_gcs.stack.battery import BatteryMonitor
from drona_gcs.stack.drone_config import ASKING, Arrival, DroneAction, StackConfig, leg_overhead
from drona_gcs.stack.drone_ways import _distance_function, own_parking, yield_spot
from drona_gcs.stack.executor import PlanExecutor
from drona_gcs.stack.mail import GoTo, MailPlanner, Phase
from drona_gcs.stack.messages import HybridClock, Task
from drona_gcs.stack.protocol import (
    Brake,
    Braked,
    CoordinationProtocol,
    Event,
    Reroute,
    RerouteFailed,
    StartExecuting,
    State,
    TaskFailed,
    Threatened,
)
from drona_gcs.workspace import Cell


class DroneCore:
    """The machines of one drone and their wiring; the drone's inputs are :class:`DroneStack`'s."""

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
                                             hover_lead_steps=config.hover_lead_steps,
                                             propose_at_once=config.propose_at_once, epoch=epoch)
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
        self.commanded: str | None = None  #: the operator's command in force (see :meth:`DroneStack.command`)
        #: in touch with most of the fleet at the last boundary (CoordinationProtocol.in_quorum); not before the
        #: first: a drone starting up meets its peers one by one, and hands back no mail meanwhile
        self.in_touch = False
        self.clock_off = False  #: my clock is beyond the fleet's bound (see :meth:`DroneStack.clock_bound`)
        self.late = False  #: my vehicle came to a cell later than lambda (see :meth:`DroneStack.tracking_bound`)

    def distance(self, a: Cell, b: Cell) -> int:
        """Steps from ``a`` to ``b``, around the drones resting now and never through a vehicle down or
        lost, nor where a peer whose clock is off rests, for as long as it is off (the task planner's
        distance; see :func:`_distance_function`). The rest of its plan is only passed through."""
        return self.ways(a, b, self.resting_now, self.walls())

    def walls(self) -> frozenset[Cell]:
        """Cells held for good, which no way crosses: vehicles down, where lost vehicles may be (until they
        are back; but where I am: had one stopped there, we would have met; not a late vehicle's cells,
        held only for now), and where peers whose clock is off rest. Where I am: my plan's cell, and the
        task planner's (a leg not flown left the vehicle at its start)."""
        protocol, here = self.protocol, {self.executor.cell, self.mail.cell}
        off = (protocol.known[p].last for p in protocol.outliers if p in protocol.known)
        lost = (cell for peer, cells in protocol.peers_lost.items() if peer not in protocol.peers_late
                for cell in cells if cell not in here)
        return frozenset((*protocol.peers_down.values(), *lost, *off))

    def copy(self) -> Self:
        """A copy whose task planner measures ways with the copy's state (the tester's clones)."""
        new = copy.copy(self)
        new.mail = copy.copy(self.mail)
        new.mail.distance = new.distance
        return new

    @property
    def now(self) -> int:
        return max(self.executor.step, 0)

    def _stop_here(self) -> list[DroneAction]:
        """A held drone flying a plan: plan its rest anew, to stay where the plan is once a new plan can
        start (see :meth:`DroneStack.land_here`). A round under way ends in a plan, which this stops in turn."""
        trajectory = self.protocol.trajectory
        if self.protocol.state is not State.EXECUTING or trajectory is None:
            return []
        stop = trajectory.at(self.now + self.protocol.airborne_lead)
        if stop == trajectory.last:
            return []
        self.stop_short, self.threat = stop, None
        task = self._hovering_task(stop)
        return self._protocol(Reroute(task))

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
        ones, and is decided anew from there (see :meth:`DroneStack._arrive`)."""
        trajectory = self.protocol.trajectory
        assert trajectory is not None
        goal, self.stop_short, self.threat = trajectory.last, None, threat
        if goal in threat.cells:
            goal = self._short_of(threat) or goal
        return self._hovering_task(goal)

    def _hovering_task(self, goal: Cell, entry: int | None = None) -> Task:
        """A new rest of the plan flown, to ``goal``: flown from now on, as far as budgets go, with what
        the battery affords now less what must remain there, and less the plan's first step (see
        :meth:`_task`). ``entry``: the step the plan flown enters a held cell, which the rest must
        start before (a stop short of it, past it, would leave the leg for nothing)."""
        flight = self.mail.flight_to(goal, self.level)
        return Task(self.clock.next_id(self.now), goal, None if flight is None else flight - 1,
                    hovering_since=self.now, start_by=None if entry is None else entry - 1)

    def _short_of(self, threat: Threatened) -> Cell | None:
        """Where the leg flown stops short of the cells ``threat`` holds: the nearest cell off them from
        where a new plan would start (that cell itself, if it can be held); None if there is none."""
        trajectory = self.protocol.trajectory
        assert trajectory is not None
        start = trajectory.at(self.now + self.protocol.airborne_lead)
        self.stop_short = yield_spot(self.config.workspace, start, frozenset(threat.cells), self.taken_cells())
        return self.stop_short

    def _stop_short_instead(self) -> list[DroneAction]:
        """The rerouted leg found no plan to its goal: stop short of the held cells instead (once), if the
        plan flown enters one after a new plan could start; the rest must start before it does. A cell
        crossed by then cannot be helped: a stop past it would leave the leg for nothing."""
        threat, self.threat = self.threat, None
        if self.braked is not None or self.protocol.state is not State.EXECUTING:
            self.stop_short = None
            return []
        if threat is None or self.stop_short is not None or (entry := self._entry_of(threat)) is None:
            self.stop_short = None
            return self._protocol(Brake())  # no rest planned: the plan stops short of the held cells now
        stop = self._short_of(threat)
        if stop is None:
            return self._protocol(Brake())
        return self._protocol(Reroute(self._hovering_task(stop, entry)))

    def _entry_of(self, threat: Threatened) -> int | None:
        """The first step after a new plan could start at which the plan flown enters a cell ``threat``
        holds (None: it is past them all by then, and no new plan can keep clear of them)."""
        trajectory = self.protocol.trajectory
        assert trajectory is not None
        start, held = self.now + self.protocol.airborne_lead, set(threat.cells)
        return next((t for t in range(start + 1, trajectory.end_step + 1) if trajectory.at(t) in held), None)

    def _way_to_clear(self, leg: GoTo) -> tuple[Cell, ...]:
        """The way a mail or charging leg (or one to park, from a charger) asks resting drones to leave: when
        its goal is taken, or its last try found no plan (the paper leaves MRMP incomplete: resting drones
        wall goals in). A shortest way around cells it asked before that stayed taken, and always around
        those no drone leaves when asked: vehicles down, and departed drones (until back; through them only
        if there is no other way). Those are not left to be learnt: what stayed taken is forgotten with every
        plan flown, and legs flown between tries had a drone ask a way through a vehicle down for good."""
        taken, here, ws = self.taken_cells(), self.protocol.location, self.config.workspace
        asking = leg.purpose in ASKING or (leg.purpose is Phase.TO_PARKING and here in ws.charging_stations)
        if not asking or (leg.goal not in taken and leg.goal not in self.unreached):
            return ()
        walls = self.walls() - {leg.goal}
        shut = (walls | {t.last for t in self.protocol.ghost_obstacles().values()}) - {leg.goal}
        self.stuck = self.stuck | (self.asked_clear & taken)
        way = ws.shortest_way(here, leg.goal, shut | (self.stuck - {leg.goal}))
        if not way:  # every way was asked once: ask them all again, in turn
            self.stuck = self.asked_clear & taken
            way = (ws.shortest_way(here, leg.goal, shut | (self.stuck - {leg.goal}))
                   or ws.shortest_way(here, leg.goal, walls))
        self.asked_clear = frozenset(way) & taken
        return way

    @property
    def landed(self) -> bool:
        return self.mail.landed(holding=not self.executor.flying)

    def passing_cells(self) -> set[Cell]:
        """Cells live peers hold only until they move on: where their plans under way end (they rest there
        until their next leg), and every cell of the plan under way of a peer whose clock is off (held for
        good only until it rests, and a few steps more)."""
        now, outliers = self.now, self.protocol.outliers
        return {cell for drone, traj in self.protocol.known.items()
                if drone != self.me and drone not in self.protocol.ghosts and traj.end_step > now
                for cell in (traj.cells if drone in outliers else (traj.last,))} | {
            cell for cell, until in self.protocol.left_behind.items() if until >= now}

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

