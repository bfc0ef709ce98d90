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

The stack's other modules: :mod:`~drona_gcs.stack.drone_config` (the fleet's configuration, lead times,
the end of a leg), :mod:`~drona_gcs.stack.drone_ways` (distances, making way, parking) and
:mod:`~drona_gcs.stack.drone_core` (the machines wired, the legs' motion tasks).
"""

from __future__ import annotations

from drona_gcs.errors import ProblemError
from drona_gcs.motion import Trajectory
from drona_gcs.stack.battery import BatteryLow
from drona_gcs.stack.drone_config import (
    ARM_AND_MODE_S,
    ASKING,
    CLIMB_RATE_M_S,
    CUT_OFF,
    ROUND_S,
    SERVICE_LOST,
    SPOOL_UP_S,
    Arrival,
    DroneAction,
    LegNotFlown,
    StackConfig,
    confirm_steps,
    default_hover_lead_steps,
    default_lead_steps,
    leg_overhead,
)
from drona_gcs.stack.drone_core import DroneCore
from drona_gcs.stack.drone_ways import Ways, _distance_function, own_parking, walled_behind, yield_spot
from drona_gcs.stack.executor import Completed
from drona_gcs.stack.mail import DRAINED, GoTo, MailRequest
from drona_gcs.stack.messages import Message, ReqForCurrentTraj, task_of
from drona_gcs.stack.protocol import (
    ClockBound,
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
    State,
    VehicleDown,
    VehicleLost,
)
from drona_gcs.workspace import Cell

__all__ = ["ARM_AND_MODE_S", "ASKING", "CLIMB_RATE_M_S", "CUT_OFF", "ROUND_S", "SERVICE_LOST", "SPOOL_UP_S",
           "Arrival", "DroneAction", "DroneCore", "DroneStack", "LegNotFlown", "StackConfig", "Ways",
           "_distance_function", "confirm_steps", "default_hover_lead_steps", "default_lead_steps",
           "leg_overhead", "own_parking", "walled_behind", "yield_spot"]


class DroneStack(DroneCore):
    """One drone's stack: its machines (:class:`DroneCore`) and the inputs the runtime feeds it."""

    def receive(self, message: Message) -> list[DroneAction]:
        self.clock.observe(task_of(message))
        if isinstance(message, ReqForCurrentTraj) and message.clear:
            self._make_way(message.clear, message.trajectory.last)
        return self._protocol(message)

    def _make_way(self, way: tuple[Cell, ...], asker: Cell) -> None:
        """A peer's leg found no plan and asks drones resting on ``way`` to leave it: if we rest
        there, leave for the nearest cell off it (see MailPlanner.make_way). The peer rests in
        ``asker``; a charger only it leads to is out of our reach until we have left."""
        here = self.protocol.location
        if self.protocol.state is not State.WAIT_FOR_TASK or here not in way:
            return
        taken = self.taken_cells()
        spot = yield_spot(self.config.workspace, here, frozenset(way), taken)
        if spot is not None:  # out while the peer flies there, a detour to park on the way included
            behind = walled_behind(self.config.workspace, here, asker, taken, self.walls())
            self.mail.make_way(spot, 2 * len(way), behind)

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

    def peer_lost(self, drone: str, cells: tuple[Cell, ...], for_now: bool = False,
                  seq: tuple[int, int] = (0, 0)) -> list[DroneAction]:
        """``drone`` announced its vehicle is lost and may be in ``cells`` for good (none: it is back);
        ``for_now``: late or its clock off; ``seq``: which of its holds (see PeerLost)."""
        return self._protocol(PeerLost(drone, cells, for_now, seq))

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

    def tracking_bound(self, late: bool, reason: str, on_time_at: int | None = None) -> list[DroneAction]:
        """The lateness check's verdict: my vehicle came to a cell later than lambda, so the margin
        peers planned with is gone. As with a clock off, I hold where my plan ends, hand back the mail
        not on board, and every peer holds that for good (from ``on_time_at``, the last step the vehicle
        was seen on time), until the vehicle is back on time."""
        self.late = late
        return self._out_of_bounds(self.protocol.outliers, reason, on_time_at)

    def _out_of_bounds(self, outliers: frozenset[str], reason: str, on_time_at: int | None = None) -> list[DroneAction]:
        off = self.clock_off or self.late
        newly_off = off and self.protocol.off_since is None
        actions = self._protocol(ClockBound(off, outliers, on_time_at))
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

