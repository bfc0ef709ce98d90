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
only after ``hold_steps``. One that cannot afford the way off and a charger after it
goes to charge instead, unless each charger it affords is behind the peer that asked
(see :func:`~drona_gcs.stack.drone_ways.walled_behind`): then it leaves all the same,
keeping nothing for a charger, as a stranded drone does. Mail whose pickup found no plan in
:data:`MAX_STRIKES` legs, other legs between them or not, is handed back.

A leg to a cell another drone is known to rest on would cost a whole
coordination round with every peer and end in no plan, so it counts as failed
without asking, and the retries back off (2, 4, 8 steps). It is tried again
at once when that drone is known to have left (the runtime hears every new
plan), and a real round every 8 steps keeps what is known fresh: in the
systematic tester's model, rounds are the only news.

State. What decides the next leg is one :class:`MailState` (the leg flown, the mail on board,
charging first, the operator's command), changed only as :data:`TRANSITIONS` says
(:mod:`drona_gcs.stack.mail_table`). The planner's other modules: :mod:`~drona_gcs.stack.mail_requests`
(mail, actions, budget), :mod:`~drona_gcs.stack.mail_reach` (its fields and energy arithmetic) and
:mod:`~drona_gcs.stack.mail_events` (what happens to it); this one decides.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence

from drona_gcs.stack.mail_events import MailPlannerInputs
from drona_gcs.stack.mail_reach import MailPlannerBase
from drona_gcs.stack.mail_requests import (
    DRAINED,
    MAX_FAILURES,
    MAX_MISSES,
    MAX_STRIKES,
    NO_WAY,
    NOT_CLEARED,
    SPENT,
    STRANDED,
    Budget,
    Distance,
    GoTo,
    MailAction,
    MailDelivered,
    MailLost,
    MailPickedUp,
    MailProgress,
    MailRejected,
    MailRequest,
    MailStarted,
    mail_cell_problem,
)
from drona_gcs.stack.mail_table import (
    TRANSITIONS,
    Command,
    Energy,
    Load,
    MailEvent,
    MailState,
    Phase,
)
from drona_gcs.workspace import Cell

__all__ = [
    "DRAINED",
    "MAX_FAILURES",
    "MAX_MISSES",
    "MAX_STRIKES",
    "NOT_CLEARED",
    "NO_WAY",
    "SPENT",
    "STRANDED",
    "TRANSITIONS",
    "Budget",
    "Command",
    "Distance",
    "Energy",
    "GoTo",
    "Load",
    "MailAction",
    "MailDelivered",
    "MailEvent",
    "MailLost",
    "MailPickedUp",
    "MailPlanner",
    "MailPlannerBase",
    "MailPlannerInputs",
    "MailProgress",
    "MailRejected",
    "MailRequest",
    "MailStarted",
    "MailState",
    "Phase",
    "mail_cell_problem",
]


class MailPlanner(MailPlannerInputs):
    """The task planner of one drone; :meth:`decide` is called at every step boundary."""

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
        if frozenset(taken) != self.cut_off_among:  # a drone that walled a pickup off may have left since
            self.cut_off_mail = frozenset()
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
        # The parking spots only when asked for: a drone parked and idle looks every boundary.
        if not self.low and self.tried and not self._parked() and (spots := self._parking_spots()) and any(
                g not in spots for g in self.tried) and self._in_reach_charged(spots, budget):
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
        if not self._parked() and (spots := self._parking_spots()) and self._in_reach_charged(spots, budget):
            return self._to_one_of(spots, budget, taken, Phase.TO_PARKING)
        return []  # parked, or its parking cells beyond a full charge: idle here, it makes way when asked

    def _in_reach_charged(self, spots: Sequence[Cell], budget: Budget) -> bool:
        """Whether one of ``spots``, and the way on from it to a charger, is in reach now or once charged.
        Beyond a full charge, the way to park would send the drone to charge (see :meth:`_to_one_of`), and
        charged it would find the same: charging at 100 % for good, its mail waiting, and
        the charger held by a drone that makes way for nobody while it charges."""
        reach = max(budget.steps, self.battery.steps_affordable(self.recharged_level))
        return budget.unchecked or any(self._leg(self.cell, c) + self._after(c) <= reach for c in spots)

    def _make_way(self, budget: Budget, taken: Collection[Cell]) -> list[MailAction]:
        """Leave for the spot a peer's way asked for, and stay there a while: going home at once
        would close the way again before the peer's next try."""
        spot, self.make_way_to = self.make_way_to, None
        behind, self.make_way_behind = self.make_way_behind, frozenset()
        if spot is None:
            return []
        reserve = self._after(spot)
        if not budget.allows(self._leg(self.cell, spot) + reserve):
            if not self.chargers or self.cell in self.chargers:
                return []
            self._enter(MailEvent.LOW)  # the way off would leave too little: off to charge instead
            ahead = [c for c in self._staging_chargers() if c not in behind]
            if any(budget.allows(self._leg(self.cell, c)) for c in self._reachable(ahead)):
                return self._to_charger(budget, taken, ahead)
            # Each charger it affords is reached only once it has left (staying, it and the peer wait for
            # each other for good): it leaves keeping nothing for one, as a drone stranded does; with mail
            # on board, keeping the way to one of those (stranded off every charger, the mail would wait).
            reserve = min((self._leg(spot, c) for c in behind), default=NO_WAY) if self.carrying else 0
            if not budget.allows(self._leg(self.cell, spot) + reserve):
                return []
        self.retry_at = budget.now + self._leg(self.cell, spot) + max(self.hold_steps, self.make_way_stay)
        return self._go(spot, budget, reserve, Phase.MAKING_WAY, taken)

    def _start_next_mail(self, budget: Budget, taken: Collection[Cell]) -> list[MailAction]:
        self.queue.sort(key=lambda r: (r.id in self.cut_off_mail, r.rank))
        best = self.queue[0]
        cut_off = self._cut_off_end(best)
        if cut_off is not None:
            self.queue.pop(0)
            why = f"its {cut_off} is cut off from here (obstacles, vehicles down or lost, drones whose clock is off)"
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
        self._enter(MailEvent.LOW)
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

    def _to_charger(self, budget: Budget, taken: Collection[Cell],
                    staging: Sequence[Cell] | None = None) -> list[MailAction]:
        # Low on energy: land before coordinating, so the wait for the peers' answers is free
        # and the whole budget is left for the way to the charger (or land to charge here).
        self.landed_here = True
        staging = self._staging_chargers() if staging is None else staging
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
                self._enter(MailEvent.LOW)
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
        self.goal, self.goal_taken, self.leg_among = goal, goal in taken, frozenset(taken)
        if self.goal_taken and self.backoff < self.max_retry_steps:
            return self.leg_failed(budget.now, asked=False)
        return [GoTo(goal, budget.flight(reserve), purpose)]

