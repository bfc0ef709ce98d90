"""The priority mail-delivery task planner (the application's task planner, paper Fig. 2).

A drone keeps its assigned requests and serves them in priority order (9 is
the most urgent), oldest first among equals: each is a leg to the pickup and
then a leg to the drop-off, each a motion task for the coordination protocol.

Energy. Flying a step (moving or hovering) drains ``drain_per_step``; landed,
nothing; landed on a charger, the battery charges. A drone is in the air from
the moment its leg's plan is made (it climbs during the lead steps) until it
lands again. The rules, which keep the battery above the safe threshold
whatever the schedule:

* **Every leg has a flight budget**: what the battery affords now, less what
  must remain on arrival (the way from the goal to a charger, and for a pickup
  the way on to the drop-off too). The protocol turns it into the plan's
  maximum length when it plans, less what the leg flies besides its moves (the
  lead steps, hovered or climbed, and the plan's first step, held in the start
  cell: ``leg_overhead``) and the steps spent hovering while it coordinated, so
  a plan that would wait too long is refused by the planner itself.
* **A leg is started only when its deadline can be met** by the shortest
  path; otherwise the drone goes to charge first. Every leg counted, the one to
  the charger included, costs its overhead besides its way.
* **What must remain is the way to the second-nearest charger**: the nearest
  may be taken by a drone charging there.
* **A drone never waits in the air when energy is tight.** When a leg finds
  no plan, it lands where it is (or stays on the parking cell, charger or
  start it is on) and tries again from the ground, where waiting is free; and
  before coordinating a leg to a charger it lands too. A drone that hovers
  while it coordinates lands once its budget no longer affords the way to the
  goal (a round may take long, or never end): the plan is then refused, and
  the leg tried again from the ground.
* **Mail on board goes to its drop-off**, or to a charger first when the
  battery does not afford the way; nowhere else. When its leg finds no plan,
  the drone waits on the ground where it is and tries again.

A workspace without charging stations has no energy model: batteries are
not budgeted (the runtime then does not drain them either).

Idle drones fly to the nearest parking cell and land there, instead of
hovering where they block corridors: a parked drone is an obstacle for every
plan (the paper notes MRMP is incomplete because parked robots can wall others
in). Chargers are for charging: a charged drone leaves for a parking cell.
A failed leg is retried after ``retry_steps``, towards the next candidate when
the goal was a charger or parking cell (another drone's free parking cell,
once ours finds no plan); a drone with no mail on board clears the way on a
parking cell first. Mail is never dropped: a drone whose vehicle came down
by itself hands all of it back (:meth:`MailPlanner.abandon`).

Making way. The paper leaves MRMP incomplete: drones resting for good can wall
a goal off. A drone whose leg found no plan asks the drones resting on a way to
its goal to leave it (see :mod:`drona_gcs.stack.drone`); one asked, not charging,
flies to the spot it is given (with its mail on board, if any: the one flight
such mail makes besides its drop-off and a charger), lands there, and goes on
only after ``hold_steps``. Mail whose pickup found no plan in
:data:`MAX_STRIKES` legs, other legs between them or not, is handed back.

A leg to a cell another drone is known to rest on would cost a whole
coordination round with every peer and end in no plan, so it counts as failed
without asking, and the retries back off (2, 4, 8 steps). It is tried again
at once when that drone is known to have left (the runtime hears every new
plan), and a real round every 8 steps keeps what is known fresh: in the
systematic tester's model, rounds are the only news.
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass, field

from drona_gcs.errors import ProblemError, ProtocolViolation
from drona_gcs.stack.battery import BatteryModel
from drona_gcs.workspace import Cell, Workspace

#: distance(a, b): steps of the shortest static path from a to b (NO_WAY if none).
Distance = Callable[[Cell, Cell], int]
NO_WAY = 10**6  #: the distance between cells no path joins (a vehicle down may wall a drone in for good)
MAX_MISSES = 3  #: plans to a pickup that end with the vehicle not there, before the mail is handed back
#: Why a drone whose battery is low flies no mail, where no charger can fill it up again.
SPENT = "its battery is low, and the workspace has no charger"
DRAINED = "its battery affords no move above the floor, and it rests off every charger"
STRANDED = ("its battery is low, and reaches no charger from here (the others are walled in by obstacles, "
            "vehicles down or drones whose clock is off)")
MAX_FAILURES = 4  #: rounds in a row that find no plan, before mail not on board is handed back (see leg_failed)
MAX_STRIKES = 8  #: legs to a mail's pickup that found no plan, in a row or not, before it is handed back
NOT_CLEARED = "at the pickup, not cleared by the service to take it on board"


def mail_cell_problem(workspace: Workspace, cell: Cell) -> tuple[str, str] | None:
    """Why ``cell`` cannot be a pickup or drop-off, as ``(kind, message)``; None if it can.

    Besides the grid's rules: never a charging station or parking cell, where a drone may
    rest for good (its goal would be another drone's resting cell). One rule, used by the
    agents that take mail and by the service that accepts it.
    """
    if not workspace.in_bounds(cell):
        return "out_of_bounds", f"cell {list(cell)} is outside the grid {list(workspace.size)}"
    if cell in workspace.obstacles:
        return "obstacle", f"cell {list(cell)} is on an obstacle"
    if cell not in workspace.main_region:
        return "unreachable", f"cell {list(cell)} is walled off from the main free region: no drone can reach it"
    if cell in workspace.charging_stations or cell in workspace.parking:
        return "rest_spot", f"cell {list(cell)} is a charging station or parking cell, where drones rest"
    return None


@dataclass(frozen=True)
class MailRequest:
    id: str
    pickup: Cell
    dropoff: Cell
    priority: int  #: 0..9, 9 the most urgent
    seq: int = 0  #: arrival order; lower is older

    def __post_init__(self) -> None:
        if not 0 <= self.priority <= 9:
            raise ProblemError(f"mail {self.id}: priority must be within 0..9, got {self.priority}")
        if self.pickup == self.dropoff:
            raise ProblemError(f"mail {self.id}: pickup and drop-off are the same cell {list(self.pickup)}")

    @property
    def rank(self) -> tuple[int, int]:
        """Sort key: most urgent first, then oldest."""
        return (-self.priority, self.seq)


class Phase(enum.Enum):
    IDLE = "idle"  #: nothing to do (landed when at a parking cell or charger)
    TO_PICKUP = "to_pickup"  #: flying to the pickup of ``current``
    TO_DROPOFF = "to_dropoff"  #: carrying ``current`` to its drop-off
    TO_CHARGER = "to_charger"  #: flying to a charging station
    CHARGING = "charging"  #: landed on a station until recharged
    TO_PARKING = "to_parking"  #: flying to a parking cell
    MAKING_WAY = "making_way"  #: leaving a cell another drone's way crosses


class MailEvent(enum.Enum):
    """What moves a mail planner from one :class:`Phase` to another (see :data:`TRANSITIONS`)."""

    LEG = "leg"  #: a leg starts: to the phase of its purpose
    CHARGE_HERE = "charge_here"  #: already on a charger: charge without flying
    ARRIVED = "arrived"  #: the leg's plan was flown to its goal
    NOT_FLOWN = "not_flown"  #: the leg's plan ended with the vehicle not seen at its goal
    FAILED = "failed"  #: no plan was found for the leg
    RECHARGED = "recharged"  #: the battery is full again
    RELOCATED = "relocated"  #: the vehicle, lost, is back somewhere
    RELOCATED_ON_CHARGER = "relocated_on_charger"  #: ... landed on a charger


_LEGS = (Phase.TO_PICKUP, Phase.TO_DROPOFF, Phase.TO_CHARGER, Phase.TO_PARKING, Phase.MAKING_WAY)
_Event = MailEvent | tuple[MailEvent, Phase]  #: a leg's event is (LEG, its purpose)
_LEG_ENDS: dict[_Event, Phase] = {MailEvent.NOT_FLOWN: Phase.IDLE, MailEvent.FAILED: Phase.IDLE,
                                  MailEvent.RELOCATED: Phase.IDLE}
#: phase -> event -> the next phase. Every change of phase goes through MailPlanner._enter, which raises
#: ProtocolViolation naming the phase and the event for one not here.
TRANSITIONS: dict[Phase, dict[_Event, Phase]] = {
    Phase.IDLE: {**{(MailEvent.LEG, leg): leg for leg in _LEGS}, MailEvent.CHARGE_HERE: Phase.CHARGING,
                 MailEvent.RECHARGED: Phase.IDLE, MailEvent.RELOCATED: Phase.IDLE,
                 **_LEG_ENDS},  # a leg already ended (its vehicle relocated) may still report how
    **{leg: {MailEvent.ARRIVED: Phase.CHARGING if leg is Phase.TO_CHARGER else Phase.IDLE, **_LEG_ENDS,
             MailEvent.RECHARGED: leg} for leg in _LEGS},
    Phase.CHARGING: {MailEvent.RECHARGED: Phase.IDLE, MailEvent.RELOCATED: Phase.IDLE,
                     MailEvent.RELOCATED_ON_CHARGER: Phase.CHARGING},
}


# --------------------------------------------------------------- actions
@dataclass(frozen=True)
class GoTo:
    """Ask the coordination protocol for a motion task; the battery affords ``flight_steps``."""

    goal: Cell
    flight_steps: int | None
    purpose: Phase


@dataclass(frozen=True)
class MailStarted:
    request: MailRequest
    waiting: tuple[MailRequest, ...]  #: the rest of the queue at that moment (for the order monitor)


@dataclass(frozen=True)
class MailPickedUp:
    request: MailRequest


@dataclass(frozen=True)
class MailDelivered:
    request: MailRequest


@dataclass(frozen=True)
class MailRejected:
    """A mail this drone will not fly: handed back to whoever assigned it. ``handed_back``: the mail
    is fine, the drone is not (its vehicle lost, down, late): another drone may fly it."""

    request: MailRequest
    reason: str
    handed_back: bool = False


@dataclass(frozen=True)
class MailLost:
    """A mail on board a vehicle that came down by itself: it is wherever the vehicle is."""

    request: MailRequest
    reason: str


MailProgress = MailStarted | MailPickedUp | MailDelivered | MailRejected | MailLost  #: what a dispatcher is told
MailAction = GoTo | MailProgress


@dataclass
class MailPlanner:
    """The task planner of one drone; :meth:`decide` is called at every step boundary."""

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
    _phase: Phase = field(default=Phase.IDLE, init=False, repr=False)
    queue: list[MailRequest] = field(default_factory=list)
    current: MailRequest | None = None
    low: bool = False
    retry_at: int = 0
    goal: Cell | None = None
    carrying: bool = False  #: ``current`` is on board
    landed_here: bool = True  #: on the ground (drones start landed)
    tried: set[Cell] = field(default_factory=set)  #: goals that found no plan since the last leg
    goal_taken: bool = False  #: the leg under way goes to a cell another drone was known to rest on
    blocked: Cell | None = None  #: the goal of the failed leg, while it is believed taken
    backoff: int = 0  #: the back-off of retries towards cells believed taken, steps (0: none)
    misses: int = 0  #: legs in a row whose plan ended with the vehicle not seen at the goal
    failures: int = 0  #: coordination rounds in a row that found no plan to a pickup, drop-off or charger
    occupied: frozenset[Cell] = frozenset()  #: chargers other drones rested on at the last decision
    passing: frozenset[Cell] = frozenset()  #: where plans under way ended, at the last decision
    cut_offs: int = 0  #: legs in a row whose goal no path at all joined
    #: at the last decision, the battery reached no charger a way joins to ours: none will fill it again
    stranded: bool = False
    #: mail whose leg no path joined from here: tried after the rest, until the drone has moved
    cut_off_mail: frozenset[str] = frozenset()
    strikes: dict[str, int] = field(default_factory=dict)  #: legs to each mail's pickup that found no plan
    make_way_to: Cell | None = None  #: a peer's way crosses our cell: leave for this one
    hold_steps: int = 16  #: how long a drone that made way stays out of it before going home
    make_way_stay: int = 0  #: at least how long to stay out of the way asked for
    paused: bool = False  #: the operator's pause: no mail starts (mail on board is still delivered)
    held: bool = False  #: the operator landed the drone where it is: no leg at all until resumed
    #: mail the dispatcher cleared for pickup; None: no clearance needed (no service dispatches the mail)
    cleared: set[str] | None = None

    @property
    def phase(self) -> Phase:
        return self._phase

    def _enter(self, event: _Event) -> None:
        """The one place the phase changes: to where :data:`TRANSITIONS` says ``event`` leads."""
        target = TRANSITIONS[self._phase].get(event)
        if target is None:
            name = event.value if isinstance(event, MailEvent) else f"{event[0].value} {event[1].value}"
            raise ProtocolViolation(f"mail planner: no {name!r} while {self._phase.value}")
        self._phase = target

    # ---------------------------------------------------------- inputs
    def assign(self, request: MailRequest) -> None:
        if self.holds(request.id):
            return  # a duplicate assignment is harmless
        self.queue.append(request)

    def holds(self, mail_id: str) -> bool:
        """Whether ``mail_id`` is queued here, under way or on board."""
        return any(r.id == mail_id for r in self.queue) or (self.current is not None and self.current.id == mail_id)

    def clear(self, mail_id: str) -> bool:
        """The dispatcher holds ``mail_id`` as this drone's from now on: it may take it on board. False if
        no dispatcher clears this drone's mail, or if the mail is not held here: a clearance that comes
        after the mail was handed back would let it be taken on board when given again, uncleared."""
        if self.cleared is None or not self.holds(mail_id):
            return False
        self.cleared = self.cleared | {mail_id}
        return True

    def reported(self, action: MailAction) -> None:
        """A clearance is for one holding: it ends once the mail is handed back, delivered or lost."""
        if self.cleared is not None and isinstance(action, (MailRejected, MailDelivered, MailLost)):
            self.cleared = self.cleared - {action.request.id}

    def cancel(self, mail_id: str) -> bool:
        """Drop a mail still waiting in the queue; one already under way is flown to the end."""
        kept = [r for r in self.queue if r.id != mail_id]
        dropped = len(kept) != len(self.queue)
        self.queue = kept
        return dropped

    def abandon(self, reason: str) -> list[MailAction]:
        """The vehicle came down by itself (a failsafe, a pilot) and flies no more legs: every mail
        is handed back, most urgent first. One waiting, or not picked up yet, is rejected (another
        drone may fly it); one on board is lost (it is wherever the vehicle is). A leg under way
        ends with no mail: its end reports nothing."""
        handed: list[MailAction] = [MailRejected(r, reason, True) for r in sorted(self.queue, key=lambda r: r.rank)]
        self.queue = []
        if self.current is not None:
            handed.append(MailLost(self.current, reason) if self.carrying else MailRejected(self.current, reason, True))
            self.current, self.carrying = None, False
        return handed

    def _may_pick_up(self, request: MailRequest) -> bool:
        """Mail is taken on board only once its dispatcher knows it may be (see :attr:`cleared`): then a
        drone it loses touch with may hold it, and it gives it to no other drone meanwhile."""
        return self.cleared is None or request.id in self.cleared

    def release(self, reason: str, keep_cleared: bool = False) -> list[MailAction]:
        """Hand back every mail not on board, most urgent first (the vehicle is lost: another drone
        may fly them); mail on board stays, and with ``keep_cleared`` mail cleared for pickup (its
        dispatcher holds it as this drone's). A leg to a pickup under way ends with no mail."""
        def kept(request: MailRequest) -> bool:
            return keep_cleared and self.cleared is not None and request.id in self.cleared

        ranked = sorted(self.queue, key=lambda r: r.rank)
        handed: list[MailAction] = [MailRejected(r, reason, True) for r in ranked if not kept(r)]
        self.queue = [r for r in self.queue if kept(r)]
        if self.current is not None and not self.carrying and not kept(self.current):
            handed.append(MailRejected(self.current, reason, True))
            self.current = None
        return handed

    def make_way(self, spot: Cell, stay: int = 0) -> None:
        """A peer found no plan, for a way that crosses the cell we rest on: leave for ``spot`` at
        the next decision, unless a leg is under way or the drone charges, and stay out at least
        ``stay`` steps (back home sooner, a drone walled the peer's goal in again before the peer got
        there). Mail on board goes along: a drone waiting with it for a drop-off walled off for good
        would wall others off in turn."""
        if not self.busy and self.phase is not Phase.CHARGING:
            self.make_way_to, self.make_way_stay = spot, stay

    @property
    def homeless(self) -> bool:
        """Idle with no mail, no leg and nowhere to park or charge: it waits wherever it is."""
        return (not self.busy and not self.carrying and not self.queue and self.phase is Phase.IDLE
                and not self.held and self.make_way_to is None and not self._parking_spots())

    def battery_low(self) -> None:
        self.low = True

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

    def battery_recharged(self) -> None:
        self.low = False
        self._enter(MailEvent.RECHARGED)

    def leg_done(self) -> list[MailAction]:
        """The protocol completed the current leg: we are at ``goal``."""
        if self.goal is None:
            raise ProtocolViolation(f"leg done while {self.phase.value}, with no leg under way")
        done, actions = self.phase, list[MailAction]()
        self._enter(MailEvent.ARRIVED)  # first: refused, nothing else changes (a drop-off leg starts next)
        self.cell, self.goal, self.misses, self.failures, self.cut_offs = self.goal, None, 0, 0, 0
        self.cut_off_mail = frozenset()
        self.tried.clear()
        self.blocked, self.backoff = None, 0
        self.landed_here = self._parked() or self.cell in self.chargers or done is Phase.MAKING_WAY
        if done is Phase.TO_PICKUP and self.current is not None and not self._may_pick_up(self.current):
            actions.append(MailRejected(self.current, NOT_CLEARED, True))
            self.current = None
        elif done is Phase.TO_PICKUP and self.current is not None:
            self.strikes.pop(self.current.id, None)
            actions.append(MailPickedUp(self.current))
            self.carrying = True
        elif done is Phase.TO_DROPOFF and self.current is not None:
            actions.append(MailDelivered(self.current))
            self.current, self.carrying = None, False
        return actions

    def leg_not_flown(self, now: int) -> list[MailAction]:
        """The plan ended but telemetry never put the vehicle at the goal: the leg did not happen. It
        is tried again at once (the vehicle may only be late); a pickup missed :data:`MAX_MISSES`
        times in a row is handed back, for another drone to fly. Mail on board stays on board."""
        self._enter(MailEvent.NOT_FLOWN)
        current, carrying = self.current, self.carrying
        self.misses += 1
        self.goal, self.retry_at = None, now
        if current is None or carrying:
            return []
        self.current = None
        if self.misses < MAX_MISSES:
            self.queue.append(current)
            return []
        self.misses = 0
        return [MailRejected(current, f"its vehicle never reached the pickup {list(current.pickup)} "
                                      f"({MAX_MISSES} plans flown, none seen there)")]

    def relocate(self, cell: Cell, landed: bool) -> None:
        """The vehicle was lost and is back in ``cell``: a leg under way is over (not flown), the
        mail stays as it was (on board, or in the queue), and the next decision starts from here."""
        # Charging goes on only on the charger: elsewhere it would wait for good.
        on_charger = self.phase is Phase.CHARGING and cell in self.chargers and landed
        self._enter(MailEvent.RELOCATED_ON_CHARGER if on_charger else MailEvent.RELOCATED)
        self.cell, self.goal, self.landed_here, self.retry_at = cell, None, landed, 0
        if self.current is not None and not self.carrying:
            self.queue.append(self.current)
            self.current = None
        self.tried.clear()

    def leg_failed(self, now: int, asked: bool = True, cut_off: bool = False) -> list[MailAction]:
        """No plan was found (``asked``: by a coordination round; else the goal was known taken;
        ``cut_off``: no path at all joins start and goal): land here and try again a little later,
        from the ground (or in the air, where a peer's plan under way ends at the goal). Mail not on
        board is handed back for another drone to fly once :data:`MAX_FAILURES` rounds in a row found
        no plan to its pickup (a vehicle down may rest on it for good), or to the drop-off of the
        mail on board, or to a charger it needs (the queue behind them), and all of it once as many
        legs in a row were cut off (drones resting for good wall this one in). A leg to a cell a peer
        holds only while its plan is under way counts for none of that: the peer moves on (two mails
        with one pickup, or a peer whose clock is off passing through)."""
        passing = self.goal in self.passing
        asked = asked and not passing
        to_pickup = self.phase is Phase.TO_PICKUP and self.current is not None and not self.carrying
        to_dropoff = self.phase is Phase.TO_DROPOFF and self.carrying
        to_charger = self.phase is Phase.TO_CHARGER
        self._enter(MailEvent.FAILED)
        self.retry_at = now + self._retry_delay()
        if self.goal is not None:
            self.tried.add(self.goal)
        self.goal = None
        self.landed_here = self.landed_here or not passing  # a peer passing through: hover the short wait
        if self.current is not None and not self.carrying:
            # Not picked up yet: back in the queue, to be weighed again against priorities and battery.
            self.queue.append(self.current)
            self.current = None
        self.failures += asked and (to_pickup or to_dropoff or to_charger)
        self.cut_offs = self.cut_offs + 1 if cut_off else 0 if asked else self.cut_offs
        if to_pickup and not passing and self._struck(self.queue[-1]):
            request = self.queue.pop()
            return [MailRejected(request, f"no plan to its pickup {list(request.pickup)} in {MAX_STRIKES} legs")]
        reason = f"no plan in {MAX_FAILURES} rounds in a row"
        if cut_off and to_pickup:  # that mail only: the others may have a way
            self.cut_off_mail |= {self.queue[-1].id}
            if self.cut_offs >= MAX_FAILURES:
                self.cut_offs = self.failures = 0
                request = self.queue.pop()
                return [MailRejected(request, f"{reason}: its pickup {list(request.pickup)} is cut off from here")]
            return []
        if self.cut_offs >= MAX_FAILURES:
            self.cut_offs = self.failures = 0
            return self.release(f"{reason}: walled in")
        if self.failures < MAX_FAILURES or not (to_pickup or to_dropoff or to_charger):
            return []
        self.failures = 0
        if to_pickup:
            request = self.queue.pop()
            return [MailRejected(request, f"{reason} to its pickup {list(request.pickup)}")]
        return self.release(f"{reason} to " + ("the drop-off of the mail on board" if to_dropoff else "a charger"))

    def _struck(self, request: MailRequest) -> bool:
        """Count a leg to ``request``'s pickup that found no plan; True at :data:`MAX_STRIKES`. Other
        legs in between (to park, to charge) do not reset the count: a vehicle down on the pickup
        would otherwise keep the mail, and the drone flying between them, for good."""
        self.strikes[request.id] = self.strikes.get(request.id, 0) + 1
        if self.strikes[request.id] < MAX_STRIKES:
            return False
        del self.strikes[request.id]
        return True

    def _retry_delay(self) -> int:
        """``retry_steps``; doubled on each failure in a row towards a cell believed taken (capped).
        Records that cell as ``blocked`` and the delay as ``backoff`` (both cleared otherwise)."""
        if not self.goal_taken or self.goal is None:
            self.blocked, self.backoff = None, 0
            return self.retry_steps
        # Counted over the goals tried in turn (two chargers, say): what grows is the wait for
        # news, and at the cap every try is a real round, which brings it.
        self.blocked = self.goal
        self.backoff = min(2 * self.backoff, self.max_retry_steps) if self.backoff else self.retry_steps
        return self.backoff

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

    # ---------------------------------------------------------- decide
    def decide(self, now: int, level: float, taken: Collection[Cell],
               passing: Collection[Cell] = ()) -> list[MailAction]:
        """At step boundary ``now`` with battery ``level``; ``taken``: cells other drones rest on;
        ``passing``: cells drones hold only until their plans under way end (they will move on)."""
        self.occupied = frozenset(c for c in self.chargers if c in taken)
        self.passing = frozenset(passing)
        if self.phase is Phase.CHARGING and level >= self.recharged_level:
            self.battery_recharged()  # also ends charging for a mail it could not afford
        if self.held and not self.busy:
            self.landed_here = True  # where it stopped: down there, or hovering above layer 0
            return []
        if self.busy or self.phase is Phase.CHARGING:
            return []
        budget = self._budget(now, level)
        self.stranded = bool(self.chargers) and not any(
            budget.allows(self._leg(self.cell, c)) for c in self._reachable(self.chargers))
        if self.make_way_to is not None:
            return self._make_way(budget, taken)
        if now < self.retry_at and (self.blocked is None or self.blocked in taken):
            return []  # waiting to retry, unless the drone that blocked the goal has left it
        if self.carrying and self.current is not None:
            # Mail on board goes to its drop-off, or to a charger on the way, and nowhere else:
            # after a failed leg it waits on the ground where it is (see leg_failed).
            dropoff, after = self.current.dropoff, self._kept_after(self.current.dropoff)
            if not self._reachable([dropoff]):  # held or walled off by vehicles down: the rest goes back
                self.landed_here = True
                return self.release(f"the drop-off {list(dropoff)} of the mail on board is cut off from here")
            if budget.allows(self._leg(self.cell, dropoff) + after + self.battery.margin_steps // 2):
                return self._go(dropoff, budget, after, Phase.TO_DROPOFF, taken)
            return self._to_charger(budget, taken)  # charge with the mail on board, then deliver
        spots = self._parking_spots()
        if not self.low and spots and not self._parked() and any(g not in spots for g in self.tried):
            # A leg found no plan: maybe our goal is where another drone waits, while we wait
            # where it wants to go. Clear the way on a parking cell before trying again (once:
            # should no parking cell be reached either, the mail is not kept waiting for one).
            return self._to_one_of(spots, budget, taken, Phase.TO_PARKING)
        if self.spent:
            return self._park_spent(budget, taken)
        if self.low:
            return self._to_charger(budget, taken)
        if self.queue and not self.paused:
            return self._start_next_mail(budget, taken)
        if spots and not self._parked():
            return self._to_one_of(spots, budget, taken, Phase.TO_PARKING)
        return []

    def _make_way(self, budget: Budget, taken: Collection[Cell]) -> list[MailAction]:
        """Leave for the spot a peer's way asked for, and stay there a while: going home at once
        would close the way again before the peer's next try."""
        spot, self.make_way_to = self.make_way_to, None
        if spot is None:
            return []
        if not budget.allows(self._leg(self.cell, spot) + self._after(spot)):
            if not self.chargers or self.cell in self.chargers or self.carrying:
                return []
            self.low = True  # the way off would leave too little: off to charge instead
            return self._to_charger(budget, taken)
        self.retry_at = budget.now + self._leg(self.cell, spot) + max(self.hold_steps, self.make_way_stay)
        return self._go(spot, budget, self._after(spot), Phase.MAKING_WAY, taken)

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

    def _start_next_mail(self, budget: Budget, taken: Collection[Cell]) -> list[MailAction]:
        self.queue.sort(key=lambda r: (r.id in self.cut_off_mail, r.rank))
        best = self.queue[0]
        cut_off = self._cut_off_end(best)
        if cut_off is not None:
            self.queue.pop(0)
            why = f"its {cut_off} is cut off from here (obstacles, vehicles down, drones whose clock is off)"
            return [MailRejected(best, why), *self.decide_again(budget, taken)]
        if budget.allows(self._need(self.cell, best)):
            self.queue.pop(0)
            self.current = best
            rest = self._leg(best.pickup, best.dropoff) + self._after(best.dropoff)  # kept for after the pickup
            leg = self._go(best.pickup, budget, rest, Phase.TO_PICKUP, taken)
            if not any(isinstance(a, GoTo) for a in leg):
                return leg  # not started: back in the queue, or handed back
            return [MailStarted(best, tuple(self.queue)), *leg]
        # Not enough for this mail: charge first, at a charger from which a full battery will do.
        full = self.battery.steps_affordable(self.recharged_level)
        staging = [c for c in self._reachable(self.chargers) if self._need(c, best) <= full]
        free = [c for c in staging if c not in taken or c == self.cell]
        if not free:  # hand it back rather than block the queue: another drone may be better placed
            self.queue.pop(0)
            why = (f"needs {self._need(self.cell, best)} steps of flight; a full battery gives {full}, at a charger "
                   "it can reach" if not staging else
                   f"the chargers it must charge at first ({', '.join(map(str, map(list, staging)))}) are taken")
            return [MailRejected(best, why), *self.decide_again(budget, taken)]
        self.low = True
        self.landed_here = True  # on the ground while it coordinates the way to the charger, or charges
        if self.cell in free:
            self._enter(MailEvent.CHARGE_HERE)
            return []
        return self._to_one_of(free, budget, taken, Phase.TO_CHARGER)

    def _cut_off_end(self, request: MailRequest) -> str | None:
        """The end of ``request`` no way joins to here (vehicles down may wall one off), or None."""
        if not self._reachable([request.pickup]):
            return f"pickup {list(request.pickup)}"
        if self.distance(request.pickup, request.dropoff) >= NO_WAY:
            return f"drop-off {list(request.dropoff)}"
        return None

    def decide_again(self, budget: Budget, taken: Collection[Cell]) -> list[MailAction]:
        return self._start_next_mail(budget, taken) if self.queue else []

    def _need(self, start: Cell, request: MailRequest) -> int:
        """Steps of flight a mail takes from ``start``: pickup, drop-off, a charger, and the margin."""
        return (self._leg(start, request.pickup) + self._leg(request.pickup, request.dropoff)
                + self._after(request.dropoff) + self.battery.margin_steps)

    def _park_spent(self, budget: Budget, taken: Collection[Cell]) -> list[MailAction]:
        """Spent: the mail not on board goes to drones that can fly it, and this one parks and lands
        there (or lands where it is, with nowhere to park), off the cells others need."""
        handed = self.release(self.why_spent or SPENT) if self.queue else []
        spots = self._parking_spots()
        if spots and not self._parked():
            return handed + self._to_one_of(spots, budget, taken, Phase.TO_PARKING)
        self.landed_here = True
        return handed

    def _to_charger(self, budget: Budget, taken: Collection[Cell]) -> list[MailAction]:
        # Low on energy: land before coordinating, so the wait for the peers' answers is free
        # and the whole budget is left for the way to the charger (or land to charge here).
        self.landed_here = True
        staging = self._staging_chargers()
        if self.cell in staging or (self.cell in self.chargers
                                    and not any(budget.allows(self._leg(self.cell, c)) for c in staging)):
            self._enter(MailEvent.CHARGE_HERE)  # (at another charger: enough to get to one of those first)
            return []
        if self.queue and not self._reachable(self.chargers):
            return self.release("no charger can be reached from here (obstacles, vehicles down and drones "
                                "whose clock is off wall it in)")
        return self._to_one_of(staging, budget, taken, Phase.TO_CHARGER)

    def _staging_chargers(self) -> Sequence[Cell]:
        """Where to charge: with mail on board, at a charger from which a full battery delivers it (charged
        in full at another, a drone would wait there with it for good); else any."""
        if not self.carrying or self.current is None:
            return self.chargers
        dropoff = self.current.dropoff
        return self._staging(dropoff, self._kept_after(dropoff)) or self.chargers

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

    def _to_one_of(self, candidates: Sequence[Cell], budget: Budget, taken: Collection[Cell],
                   purpose: Phase) -> list[MailAction]:
        """Fly to the best candidate whose way (and what must remain after it) the battery affords.

        Free ones first: one we believe taken may have been left since we last heard, and
        trying it costs one coordination round. A parking cell that would leave too little to
        reach a charger from it is skipped, and if none is left the drone charges instead.
        """
        def reserve(cell: Cell) -> int:
            return 0 if purpose is Phase.TO_CHARGER else self._after(cell)

        ranked = sorted((c for c in candidates if budget.allows(self._leg(self.cell, c) + reserve(c))),
                        key=lambda c: (c in taken, self.distance(self.cell, c), c))
        if not ranked:
            if purpose is Phase.TO_PARKING and self.chargers:
                self.low = True
                return self._to_charger(budget, taken)
            self.landed_here = True  # no charger in reach: wait on the ground
            # Waiting, it would hold mail for good: another drone flies what is not on board.
            return self.release("its battery reaches no charger") if purpose is Phase.TO_CHARGER else []
        untried = [c for c in ranked if c not in self.tried]  # after a failure, the next one
        if not untried:
            self.tried.clear()
            untried = ranked
        return self._go(untried[0], budget, reserve(untried[0]), purpose, taken)

    def _go(self, goal: Cell, budget: Budget, reserve: int, purpose: Phase,
            taken: Collection[Cell]) -> list[MailAction]:
        """The leg to ``goal``; none (a failure, without a round) while it is known taken and no
        real round is due."""
        self._enter((MailEvent.LEG, purpose))
        self.goal, self.goal_taken = goal, goal in taken
        if self.goal_taken and self.backoff < self.max_retry_steps:
            return self.leg_failed(budget.now, asked=False)
        return [GoTo(goal, budget.flight(reserve), purpose)]

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


@dataclass(frozen=True)
class Budget:
    """What the battery affords from step ``now``: ``steps`` of flight before the safe threshold."""

    now: int
    steps: int
    unchecked: bool = False  #: no energy model (no chargers): every leg is allowed

    def allows(self, steps: int) -> bool:
        return self.unchecked or steps <= self.steps

    def flight(self, reserve: int) -> int | None:
        """The steps of flight a leg may take and still leave ``reserve`` steps."""
        return None if self.unchecked else self.steps - reserve
