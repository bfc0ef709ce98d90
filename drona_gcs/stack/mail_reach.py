"""The mail planner's fields, its state (changed only through :meth:`MailPlannerBase._enter`) and what
the battery affords where (see :mod:`drona_gcs.stack.mail` for the energy rules)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from drona_gcs.stack.battery import BatteryModel
from drona_gcs.stack.mail_requests import NO_WAY, SPENT, STRANDED, Budget, Distance, MailRequest
from drona_gcs.stack.mail_table import Command, Energy, Load, MailState, Phase, _Event, next_state
from drona_gcs.workspace import Cell


@dataclass
class MailPlannerBase:
    """The task planner of one drone, its state and its arithmetic (the rest: :class:`MailPlanner`)."""

    cell: Cell
    chargers: Sequence[Cell]
    parking: Sequence[Cell]
    distance: Distance
    battery: BatteryModel = field(default_factory=BatteryModel)
    retry_steps: int = 2
    max_retry_steps: int = 8  #: the longest back-off of a leg to a cell another drone rests on
    recharged_level: float = 95.0  #: charging ends here
    #: steps of flight a leg takes besides its moves; DroneStack's legs take the lead steps before
    #: their plans start (climbing, or hovering) and the plans' first steps, held in the start cell
    leg_overhead: int = 0
    spare_parking: Sequence[Cell] = ()  #: other drones' parking cells, for when ours is out of reach
    #: what decides the next leg: phase, mail on board, charging first, the operator's command (see TRANSITIONS)
    _state: MailState = field(default=MailState(Phase.IDLE), init=False, repr=False)
    queue: list[MailRequest] = field(default_factory=list)
    current: MailRequest | None = None
    retry_at: int = 0  #: no leg before this step, unless ``blocked`` is known left
    goal: Cell | None = None
    #: on the ground (drones start landed); data, not state: what the vehicle does, which decides no leg
    landed_here: bool = True
    tried: set[Cell] = field(default_factory=set)  #: goals that found no plan since the last leg
    #: the leg under way goes to a cell another drone was known to rest on; data: what was known when it started
    goal_taken: bool = False
    blocked: Cell | None = None  #: the goal of the failed leg, while it is believed taken
    backoff: int = 0  #: the back-off of retries towards cells believed taken, steps (0: none)
    misses: int = 0  #: legs in a row whose plan ended with the vehicle not seen at the goal
    failures: int = 0  #: coordination rounds in a row that found no plan to a pickup, drop-off or charger
    occupied: frozenset[Cell] = frozenset()  #: chargers other drones rested on at the last decision
    passing: frozenset[Cell] = frozenset()  #: where plans under way ended, at the last decision
    cut_offs: int = 0  #: legs in a row whose goal no path at all joined
    #: at the last decision, the battery reached no charger a way joins to ours: none will fill it again
    #: (data, not state: measured anew at each decision)
    stranded: bool = False
    #: mail whose leg no path joined from here: tried after the rest, until the drone has moved, or the
    #: drones resting then (``cut_off_among``) have (one of them may have walled it off)
    cut_off_mail: frozenset[str] = frozenset()
    leg_among: frozenset[Cell] = frozenset()  #: where other drones rested when the last leg started
    cut_off_among: frozenset[Cell] = frozenset()  #: where they rested when the last leg cut off started
    strikes: dict[str, int] = field(default_factory=dict)  #: legs to each mail's pickup that found no plan
    make_way_to: Cell | None = None  #: a peer's way crosses our cell: leave for this one
    hold_steps: int = 16  #: how long a drone that made way stays out of it before going home
    make_way_stay: int = 0  #: at least how long to stay out of the way asked for
    #: chargers reached only through the drone that asked us to make way, which cannot leave before we do
    make_way_behind: frozenset[Cell] = frozenset()
    #: mail the dispatcher cleared for pickup; None: no clearance needed (no service dispatches the mail)
    cleared: set[str] | None = None

    @property
    def phase(self) -> Phase:
        return self._state.phase

    @property
    def state(self) -> MailState:
        return self._state

    def _enter(self, event: _Event) -> None:
        """The one place the state changes: to where :data:`TRANSITIONS` says ``event`` leads."""
        self._state = next_state(self._state, event)

    @property
    def carrying(self) -> bool:
        """``current`` is on board."""
        return self._state.load is Load.ON_BOARD

    @property
    def low(self) -> bool:
        """Charge first: no mail starts until recharged."""
        return self._state.energy is Energy.LOW

    @property
    def paused(self) -> bool:
        """The operator's pause (or a recall, or a landing): no mail starts; mail on board is still delivered."""
        return self._state.command is not Command.NONE

    @property
    def held(self) -> bool:
        """The operator landed the drone where it is: no leg at all until resumed."""
        return self._state.command is Command.HELD

    @property
    def spent(self) -> bool:
        """Low, with no charger to fill up at: it flies no more mail."""
        return self.why_spent is not None

    def drained(self, level: float) -> bool:
        """Off every charger, ``level`` affords no move: the vehicle never flies again (the floor kept)."""
        return (bool(self.chargers) and self.cell not in self.chargers
                and not self._budget(0, level).allows(self.leg_overhead + 1))

    @property
    def why_spent(self) -> str | None:
        if not self.low:
            return None
        return SPENT if not self.chargers else STRANDED if self.stranded else None

    def land(self) -> None:
        """Land where we are (the leg being coordinated can no longer be afforded from the air)."""
        self.landed_here = True

    def took_off(self) -> None:
        """A leg's plan is made: the drone is in the air from now (climbing during the lead steps)
        until it lands again, at a parking cell or charger or by a decision to."""
        self.landed_here = False

    def landed(self, holding: bool) -> bool:
        """Whether the drone is on the ground: holding still (not flying a plan), landed here.
        It stays landed while it coordinates its next leg, so waiting costs no energy, and takes
        off once the leg's plan is made (:meth:`took_off`)."""
        return holding and self.landed_here

    @property
    def busy(self) -> bool:
        return self.goal is not None

    def flight_to(self, goal: Cell, level: float) -> int | None:
        """Steps of flight ``level`` affords on the way to ``goal``, what must remain there kept
        (None: no energy model)."""
        reserve = 0 if goal in self.chargers else self._after(goal)
        return self._budget(0, level).flight(reserve)

    def _parking_spots(self) -> Sequence[Cell]:
        """Where to park: our own parking cells (chargers when there are none); once each has found
        no plan since the last leg, any other drone's parking cell too (walled in by drones
        resting around it, ours may be out of reach for long; its owner then parks on ours)."""
        spots = self._reachable(self.parking or self.chargers)
        if self.spare_parking and all(c in self.tried for c in spots):
            return [*spots, *self._reachable(self.spare_parking)]
        return spots

    def _reachable(self, cells: Sequence[Cell]) -> Sequence[Cell]:
        """Those of ``cells`` a way joins to ours (vehicles down may wall some off for good)."""
        return [c for c in cells if self.distance(self.cell, c) < NO_WAY]

    def _parked(self) -> bool:
        return self.cell in (self.parking or self.chargers) or self.cell in self.spare_parking

    def _budget(self, now: int, level: float) -> Budget:
        """What ``level`` affords; unchecked with no chargers (no energy model)."""
        return Budget(now, self.battery.steps_affordable(level), unchecked=not self.chargers)

    def _staging(self, dropoff: Cell, after: int) -> list[Cell]:
        full = self.battery.steps_affordable(self.recharged_level)
        return [c for c in self.chargers if self._leg(c, dropoff) + after + self.battery.margin_steps // 2 <= full]

    def _kept_after(self, dropoff: Cell) -> int:
        """What must remain at the drop-off of the mail on board: the way to the second nearest charger
        (see :meth:`_after`), or to the nearest where a full charge affords no more. The mail was taken
        while the other was busy; waiting at the drop-off for the nearest to be free costs nothing."""
        after = self._after(dropoff)
        if self._staging(dropoff, after):
            return after
        return min((w for w in (self._leg(dropoff, c) for c in self.chargers) if w < NO_WAY), default=after)

    def _leg(self, start: Cell, goal: Cell) -> int:
        """The fewest steps of flight a leg from ``start`` to ``goal`` takes: the shortest way,
        and ``leg_overhead``."""
        return self.leg_overhead + self.distance(start, goal)

    def _after(self, cell: Cell) -> int:
        """Steps of flight from ``cell`` to a charger: what must stay in the battery on arrival.

        The nearest charger may be taken by a drone charging there by then, so this is
        the leg to the second nearest when there are two or more. Chargers other drones
        rest on now do not count, while one is free: one may be a vehicle down for good; nor do
        chargers no way joins, while one can be reached (vehicles down may wall one off). None when
        stranded: no energy is worth keeping for a charger out of reach.
        """
        if self.stranded:
            return 0
        free = [c for c in self.chargers if c not in self.occupied] or self.chargers
        legs = [self._leg(cell, c) for c in free]
        ways = sorted(w for w in legs if w < NO_WAY) or legs
        return ways[min(1, len(ways) - 1)] if ways else 0

