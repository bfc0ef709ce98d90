"""The priority mail task planner: order, legs, retries, charging, parking and the energy rules.

Most tests use a 10 x 10 plane with Manhattan distances (cells written (x, y)):
chargers at the corners (0, 0) and (9, 0), parking cells at (0, 9) and (5, 9).
The default battery drains 1 % a step down to a 20 % floor, so a level of
``L`` affords ``L - 20`` steps. A last test runs the planner in a small
simulated world with walls (real shortest-path distances), random mail and
failed legs, and checks that the battery never goes below the floor and no
mail is lost.
"""

from __future__ import annotations

import itertools
import random
from collections.abc import Callable, Collection

import pytest

from drona_gcs.errors import ProblemError, ProtocolViolation
from drona_gcs.planner import SafePlanner
from drona_gcs.stack.battery import BatteryModel, BatteryMonitor, BatteryRecharged
from drona_gcs.stack.drone import _distance_function
from drona_gcs.stack.mail import (
    NO_WAY,
    NOT_CLEARED,
    STRANDED,
    Distance,
    GoTo,
    MailAction,
    MailDelivered,
    MailLost,
    MailPickedUp,
    MailPlanner,
    MailRejected,
    MailRequest,
    MailStarted,
    Phase,
)
from drona_gcs.workspace import Cell, Workspace


def c(x: int, y: int) -> Cell:
    return (x, y, 0)


def manhattan(a: Cell, b: Cell) -> int:
    return sum(abs(p - q) for p, q in zip(a, b, strict=True))


Q1, Q2 = c(0, 0), c(9, 0)  # chargers
P1, P2 = c(0, 9), c(5, 9)  # parking
MODEL = BatteryModel()  # drain 1, floor 20, margin 8


def planner(at: Cell = P1) -> MailPlanner:
    return MailPlanner(at, (Q1, Q2), (P1, P2), manhattan, MODEL)


def mail(name: str, pickup: Cell, dropoff: Cell, priority: int = 5, seq: int = 0) -> MailRequest:
    return MailRequest(name, pickup, dropoff, priority, seq)


def goto(actions: list[MailAction]) -> GoTo:
    found = [a for a in actions if isinstance(a, GoTo)]
    assert len(found) == 1, actions
    return found[0]


def take_on_board(mp: MailPlanner, request: MailRequest) -> None:
    """Take ``request`` on board as a drone does: its leg to the pickup, flown (the only way mail gets on board)."""
    mp.assign(request)
    assert goto(mp.decide(0, 100.0, ())).goal == request.pickup
    assert mp.leg_done() == [MailPickedUp(request)] and mp.carrying


def request_of(action: MailAction) -> MailRequest:
    """The mail a progress report is about (a GoTo is about none)."""
    assert not isinstance(action, GoTo), action
    return action.request


def assert_energy_rules(goal_from: Cell, action: GoTo, level: float, chargers: tuple[Cell, ...],
                        distance: Distance, model: BatteryModel = MODEL) -> None:
    """The leg is affordable, and on arrival the way from the goal to a charger is still left."""
    assert action.flight_steps is not None
    assert distance(goal_from, action.goal) <= action.flight_steps
    to_charger = min(distance(action.goal, q) for q in chargers)
    assert action.flight_steps + to_charger <= model.steps_affordable(level)


# ======================================================== requests
@pytest.mark.parametrize("priority", [-1, 10, 99])
def test_priority_must_be_0_to_9(priority: int) -> None:
    with pytest.raises(ProblemError, match="priority"):
        mail("m", c(1, 1), c(2, 2), priority)
    for ok in (0, 9):
        assert mail("m", c(1, 1), c(2, 2), ok).priority == ok


def test_pickup_and_dropoff_must_differ() -> None:
    with pytest.raises(ProblemError, match="same cell"):
        mail("m", c(3, 3), c(3, 3))


def test_a_duplicate_assignment_is_ignored() -> None:
    mp = planner()
    m = mail("m", c(2, 2), c(4, 4))
    mp.assign(m)
    mp.assign(m)
    mp.assign(mail("m", c(7, 7), c(8, 8)))  # the id is what counts
    assert mp.queue == [m]
    [started, _] = mp.decide(0, 100, ())
    assert started == MailStarted(m, ())
    mp.assign(m)  # while it is under way
    assert mp.queue == []


# ======================================================== order and legs
def test_most_urgent_first_then_oldest() -> None:
    mp = planner()
    low = mail("low", c(1, 1), c(2, 2), priority=0, seq=0)
    urgent_new = mail("urgent-new", c(3, 3), c(4, 4), priority=9, seq=2)
    urgent_old = mail("urgent-old", c(5, 5), c(6, 6), priority=9, seq=1)
    middle = mail("middle", c(7, 7), c(8, 8), priority=4, seq=3)
    for m in (low, urgent_new, urgent_old, middle):
        mp.assign(m)
    order = []
    for now in range(200):
        for action in mp.decide(now, 100, ()):
            if isinstance(action, MailStarted):
                order.append(action.request)
                assert action.waiting == tuple(r for r in (urgent_new, middle, low) if r not in order)
        if mp.busy:
            mp.leg_done()
    assert order == [urgent_old, urgent_new, middle, low]


def test_pickup_then_dropoff_then_parking() -> None:
    mp = planner()
    m = mail("m", c(2, 2), c(4, 4))
    mp.assign(m)
    actions = mp.decide(0, 100, ())
    # the pickup leg keeps, on top of the way from (2, 2): 4 steps to the drop-off and from there
    # 9 to the second-nearest charger (9, 0) (the nearest may be taken): 80 - 13
    assert actions == [MailStarted(m, ()), GoTo(c(2, 2), 67, Phase.TO_PICKUP)]
    assert mp.busy and mp.decide(1, 100, ()) == []  # one leg at a time
    assert mp.leg_done() == [MailPickedUp(m)]
    assert (mp.cell, mp.carrying, mp.current) == (c(2, 2), True, m)
    assert mp.decide(2, 96, ()) == [GoTo(c(4, 4), 76 - 9, Phase.TO_DROPOFF)]
    assert mp.leg_done() == [MailDelivered(m)]
    assert (mp.current, mp.carrying) == (None, False)
    # the nearer parking cell (5, 9); from there (9, 0) is 13 steps and (0, 0), the second nearest, 14
    assert mp.decide(3, 92, ()) == [GoTo(P2, 72 - 14, Phase.TO_PARKING)]
    assert mp.leg_done() == []
    assert mp.decide(4, 87, ()) == []  # parked: nothing to do


@pytest.mark.parametrize("picked_up", [False, True], ids=["before-pickup", "on-board"])
def test_a_vehicle_down_by_itself_hands_back_every_mail_and_its_leg_ends_with_none(picked_up: bool) -> None:
    mp = planner()
    m = mail("m", c(2, 2), c(4, 4), priority=5, seq=1)
    urgent, later = mail("u", c(3, 3), c(6, 6), priority=9, seq=2), mail("l", c(1, 5), c(6, 2), priority=1, seq=3)
    mp.assign(m)
    mp.decide(0, 100, ())
    if picked_up:
        mp.leg_done()
        mp.decide(1, 96, ())  # on its way to the drop-off
    mp.assign(later)
    mp.assign(urgent)
    handed = mp.abandon("vehicle down")
    # The waiting mail most urgent first, then the one under way: lost on board, else rejected.
    under_way = MailLost(m, "vehicle down") if picked_up else MailRejected(m, "vehicle down", True)
    assert handed == [MailRejected(urgent, "vehicle down", True), MailRejected(later, "vehicle down", True), under_way]
    assert (mp.queue, mp.current, mp.carrying) == ([], None, False)
    assert mp.leg_done() == []  # the executor flew the leg to its end: no pickup, no delivery to report
    assert mp.abandon("again") == []


def test_leg_done_without_a_leg_is_a_violation() -> None:
    with pytest.raises(ProtocolViolation, match="no leg"):
        planner().leg_done()


def test_a_failed_pickup_puts_the_mail_back_in_the_queue() -> None:
    mp = planner()  # on a parking cell: it can retry from there
    m, other = mail("m", c(2, 2), c(4, 4), priority=7), mail("o", c(3, 3), c(6, 6), priority=1)
    mp.assign(m)
    mp.assign(other)
    assert MailStarted(m, (other,)) in mp.decide(0, 100, ())
    mp.leg_failed(0)
    assert sorted(r.id for r in mp.queue) == ["m", "o"] and mp.current is None
    assert (mp.phase, mp.busy, mp.retry_at) == (Phase.IDLE, False, 2)
    assert mp.decide(1, 100, ()) == []  # it waits retry_steps
    actions = mp.decide(2, 100, ())
    assert actions[0] == MailStarted(m, (other,))  # weighed again: still first
    assert goto(actions).goal == c(2, 2)


def test_a_leg_to_a_cell_another_drone_rests_on_waits_without_a_round_and_backs_off() -> None:
    """A round would end in no plan while the cell stays taken: the leg fails without asking,
    retries back off 2, 4, 8 steps, then a real round every 8 steps refreshes what is known."""
    mp = planner()  # on a parking cell
    m = mail("m", c(2, 2), c(4, 4))
    mp.assign(m)
    taken = {c(2, 2)}
    now, tries = 0, []
    for _ in range(6):
        actions = mp.decide(now, 100, taken)
        asked = any(isinstance(a, GoTo) for a in actions)
        if asked:
            assert actions[0] == MailStarted(m, ()) and goto(actions).goal == c(2, 2)
            mp.leg_failed(now)  # the round found the cell taken
        else:
            assert actions == [] and mp.queue == [m] and mp.current is None  # not started
        tries.append((now, asked))
        assert all(mp.decide(t, 100, taken) == [] for t in range(now + 1, mp.retry_at))
        last, now = now, mp.retry_at
    assert tries == [(0, False), (2, False), (6, False), (14, True), (22, True), (30, True)]
    assert goto(mp.decide(last + 1, 100, set())).goal == c(2, 2)  # known gone: at once, before retry_at
    assert mp.leg_done() == [MailPickedUp(m)]
    assert (mp.blocked, mp.backoff) == (None, 0)


def test_alternating_between_taken_chargers_still_reaches_a_real_round() -> None:
    """Found by the systematic tester: both chargers taken, a low drone tried them in turn, the
    back-off restarted with each goal, and it waited for news forever without asking anyone."""
    mp = planner(at=c(4, 5))
    mp.battery_low()
    taken, now, asked = {Q1, Q2}, 0, []
    while now < 40:
        actions = mp.decide(now, 60, taken)
        if actions:
            asked.append((now, goto(actions).goal))
            mp.leg_failed(now)
        now = mp.retry_at
    assert asked and asked[0][0] <= 14
    assert {goal for _, goal in asked} == {Q1, Q2}  # real rounds, each charger in turn
    assert all(b - a == 8 for (a, _), (b, _) in itertools.pairwise(asked))


def test_a_leg_that_fails_with_its_goal_free_retries_after_retry_steps() -> None:
    mp = planner()
    m = mail("m", c(2, 2), c(4, 4))
    mp.assign(m)
    for now in (0, 2, 4):
        assert goto(mp.decide(now, 100, ())).goal == c(2, 2)
        mp.leg_failed(now)
        assert mp.retry_at == now + mp.retry_steps


def test_a_failed_leg_away_from_parking_clears_the_way_first_and_puts_the_mail_back() -> None:
    mp = planner(at=c(4, 4))
    m = mail("m", c(2, 2), c(6, 6))
    mp.assign(m)
    mp.decide(0, 100, ())
    mp.leg_failed(0)  # no plan to the pickup: maybe our goal is where another drone waits for us to leave
    assert (mp.current, mp.queue) == (None, [m])
    assert goto(mp.decide(2, 100, ())) == GoTo(P2, 80 - manhattan(P2, Q1), Phase.TO_PARKING)
    assert mp.leg_done() == []
    assert goto(mp.decide(3, 95, ())).goal == c(2, 2)  # then it tries the pickup again


def test_parking_cells_it_cannot_reach_do_not_keep_it_from_its_mail() -> None:
    """After a failed pickup leg it clears the way on a parking cell; when no parking leg finds a plan
    either (the cells walled in by drones resting around them), it goes back to its mail."""
    mp = planner(at=c(4, 4))
    m = mail("m", c(2, 2), c(6, 6))
    mp.assign(m)
    legs: list[Phase] = []
    for now in range(60):
        for action in mp.decide(now, 100, ()):
            if isinstance(action, GoTo):
                legs.append(action.purpose)
                if action.purpose is Phase.TO_PICKUP and legs.count(Phase.TO_PICKUP) > 1:
                    assert mp.leg_done() == [MailPickedUp(m)]
                else:
                    mp.leg_failed(now)  # the first pickup leg, and every parking leg, find no plan
        if mp.carrying:
            break
    assert mp.carrying, [p.value for p in legs]
    assert legs[:2] == [Phase.TO_PICKUP, Phase.TO_PARKING]


def test_a_failed_leg_with_mail_on_board_tries_its_dropoff_again_and_never_parks() -> None:
    """Carried mail goes to its drop-off (or a charger) and nowhere else: in the demo, a drone with the
    parcel on board was sent to parking when its drop-off had no plan for the moment."""
    mp = planner()
    m = mail("m", c(2, 2), c(4, 4))
    mp.assign(m)
    mp.decide(0, 100, ())
    mp.leg_done()  # picked up, hovering at (2, 2)
    mp.decide(1, 100, ())
    mp.leg_failed(1)  # no plan to the drop-off
    assert (mp.current, mp.carrying, mp.queue) == (m, True, [])
    assert mp.landed(holding=True)  # it waits on the ground, where waiting is free
    retry = goto(mp.decide(mp.retry_at, 100, ()))
    assert (retry.goal, retry.purpose) == (c(4, 4), Phase.TO_DROPOFF)
    assert mp.leg_done() == [MailDelivered(m)]


#: What happens to the legs a drone carrying mail asks for, by the leg's number (1 for the first).
Setback = Callable[[int, GoTo], str | None]


def legs_until_delivered(mp: MailPlanner, m: MailRequest, level: float, start: int,
                         setback: Setback = lambda n, leg: None,
                         taken: Callable[[int], Collection[Cell]] = lambda now: ()) -> list[Phase]:
    """Play the planner from step ``start`` until ``m`` is delivered: legs are flown at once unless
    ``setback`` says "no-plan" (the round found none) or "not-flown" (the plan ended, the vehicle
    was not seen at the goal); a drone charges on a charger only. The purposes of the legs asked."""
    asked: list[Phase] = []
    for now in range(start, start + 400):
        if mp.phase is Phase.CHARGING and mp.cell in (Q1, Q2):
            level = min(100.0, level + MODEL.charge_per_step)
        for action in mp.decide(now, level, taken(now)):
            if not isinstance(action, GoTo):
                continue
            asked.append(action.purpose)
            what = setback(len(asked), action)
            if what == "no-plan":
                mp.leg_failed(now)
            elif what == "not-flown":
                mp.leg_not_flown(now)
            else:
                level -= manhattan(mp.cell, action.goal) * MODEL.drain_per_step
                assert level >= MODEL.safe_threshold
                if MailDelivered(m) in mp.leg_done():
                    return asked
    raise AssertionError(f"{m.id} not delivered; legs asked: {[p.value for p in asked]}, phase {mp.phase.value}")


def picked_up(at: Cell, dropoff: Cell, level: float = 100) -> tuple[MailPlanner, MailRequest]:
    mp = planner()
    m = mail("m", at, dropoff)
    mp.assign(m)
    mp.decide(0, level, ())
    assert mp.leg_done() == [MailPickedUp(m)]
    return mp, m


@pytest.mark.parametrize(("setback", "taken"), [
    (lambda n, leg: "no-plan" if n <= 3 else None, lambda now: ()),
    (lambda n, leg: None, lambda now: {c(4, 4)} if now < 30 else ()),  # a drone rests on the drop-off
    (lambda n, leg: "no-plan" if n == 1 else "not-flown" if n == 2 else None, lambda now: ()),
], ids=["no-plan", "drop-off-taken", "not-flown"])
def test_mail_on_board_goes_to_its_drop_off_and_nowhere_else(setback: Setback,
                                                           taken: Callable[[int], Collection[Cell]]) -> None:
    mp, m = picked_up(c(2, 2), c(4, 4))
    assert set(legs_until_delivered(mp, m, 96, 1, setback, taken)) == {Phase.TO_DROPOFF}


def test_mail_on_board_it_must_charge_for_goes_to_a_charger_then_its_drop_off_and_nowhere_else() -> None:
    # 8 steps on to (9, 9) and 18 more to the second-nearest charger, with a margin of 4: more than
    # the 25 of 45 %; a parking cell, (5, 9), 4 steps and 14 more, would do
    mp, m = picked_up(c(5, 5), c(9, 9))
    legs = legs_until_delivered(mp, m, 45, 1, taken=lambda now: {Q1, Q2} if now < 20 else ())
    assert set(legs) == {Phase.TO_CHARGER, Phase.TO_DROPOFF} and legs[-1] is Phase.TO_DROPOFF


def test_a_vehicle_back_elsewhere_while_charging_with_mail_on_board_charges_again_and_delivers() -> None:
    """Charging goes on only on a charger: found elsewhere, it would wait there for good."""
    mp, m = picked_up(c(5, 5), c(9, 9))
    assert goto(mp.decide(1, 35, ())).purpose is Phase.TO_CHARGER
    mp.leg_done()
    assert mp.phase is Phase.CHARGING
    mp.relocate(c(1, 1), landed=True)
    legs = legs_until_delivered(mp, m, 35, 2)
    assert set(legs) == {Phase.TO_CHARGER, Phase.TO_DROPOFF} and legs[-1] is Phase.TO_DROPOFF


# ======================================================== charging
def test_low_battery_sends_it_to_the_nearest_charger_until_recharged() -> None:
    mp = planner()
    mp.assign(mail("m", c(2, 2), c(4, 4)))
    mp.battery_low()
    assert mp.decide(0, 38, ()) == [GoTo(Q1, 18, Phase.TO_CHARGER)]  # 9 steps away; (9, 0) is 18
    assert mp.leg_done() == []
    assert mp.phase is Phase.CHARGING
    for now, level in enumerate([40, 60, 80, 94.9], start=1):
        assert mp.decide(now, level, ()) == []
    actions = mp.decide(5, 95, ())
    assert mp.low is False
    assert isinstance(actions[0], MailStarted)  # recharged: back to work


def test_charging_ends_with_the_recharged_event_and_a_charged_drone_leaves_the_charger() -> None:
    mp = planner(at=Q1)
    mp.battery_low()
    assert (mp.decide(0, 30, ()), mp.phase) == ([], Phase.CHARGING)  # already on a charger
    mp.battery_recharged()
    assert mp.phase is Phase.IDLE
    assert goto(mp.decide(1, 96, ())).purpose is Phase.TO_PARKING


def test_a_taken_charger_is_avoided_when_another_is_affordable() -> None:
    mp = planner(at=c(4, 0))
    mp.battery_low()
    assert goto(mp.decide(0, 60, {Q1})).goal == Q2  # 5 steps instead of 4, but free
    mp = planner(at=c(1, 9))
    mp.battery_low()
    # (9, 0) is beyond the 12 steps left: it waits for (0, 0) on the ground (no round while it is
    # known taken), and goes as soon as (0, 0) is known free
    assert mp.decide(0, 32, {Q1}) == [] and mp.landed(holding=True) and mp.retry_at == 2
    assert goto(mp.decide(1, 32, set())).goal == Q1


def test_a_mail_it_cannot_afford_sends_it_to_charge_first() -> None:
    mp = planner()
    far = mail("far", c(9, 9), c(9, 5))
    mp.assign(far)
    # from (0, 9): 9 to the pickup, 4 to the drop-off, 14 on to (0, 0), 8 of margin = 35 > 20
    assert mp.decide(0, 40, ()) == [GoTo(Q1, 20, Phase.TO_CHARGER)]
    assert mp.queue == [far] and mp.current is None and mp.low
    mp.leg_done()
    assert mp.decide(1, 90, ()) == []  # charging
    actions = mp.decide(2, 95, ())
    assert actions[0] == MailStarted(far, ())
    assert_energy_rules(Q1, goto(actions), 95, (Q1, Q2), manhattan)


def test_a_carried_mail_it_cannot_deliver_is_delivered_after_charging() -> None:
    mp = planner()
    m = mail("m", c(5, 5), c(9, 9))
    mp.assign(m)
    mp.decide(0, 100, ())
    mp.leg_done()  # picked up at (5, 5)
    # 8 steps to (9, 9), then 18 to the second-nearest charger (0, 0): not with 35 % (15 steps)
    assert goto(mp.decide(1, 35, ())).purpose is Phase.TO_CHARGER
    mp.leg_done()
    assert mp.carrying and mp.current == m
    assert mp.decide(2, 95, ()) == [GoTo(c(9, 9), 75 - 18, Phase.TO_DROPOFF)]


# ======================================================== parking
def test_an_idle_drone_goes_to_the_nearest_free_parking_cell() -> None:
    assert planner(at=c(5, 5)).decide(0, 100, ()) == [GoTo(P2, 80 - 14, Phase.TO_PARKING)]
    assert goto(planner(at=c(5, 5)).decide(0, 100, {P2})).goal == P1  # P2 is taken
    for spot in (P1, P2):
        assert planner(at=spot).decide(0, 100, ()) == []  # parked already


def test_an_idle_drone_whose_parking_cell_is_out_of_reach_parks_on_another_drones() -> None:
    """Found by the systematic tester (4 drones, 8 mails, Delta 0, seed 3): a drone with mail on board
    waited on the ground in a corridor for the drone next to its drop-off to leave, while that one,
    idle, asked for its own parking cell beyond the corridor 115 times, and no plan around it fit its
    budget. Once its own cell has found no plan, another drone's free parking cell will do."""
    mp = MailPlanner(c(5, 5), (Q1, Q2), (P1,), manhattan, MODEL, spare_parking=(P2,))
    asked = []
    for now in range(20):
        for action in mp.decide(now, 100, ()):
            if isinstance(action, GoTo):
                asked.append(action.goal)
                if action.goal == P1:
                    mp.leg_failed(now)  # no plan within its budget
                else:
                    mp.leg_done()
    assert asked == [P1, P2]  # parked on P2, it stays there
    assert mp.landed(holding=True) and mp.cell == P2


def test_parking_it_could_not_come_back_from_sends_it_to_charge() -> None:
    # with 20 steps from (9, 1): (5, 9) is 12 away and 14 more from the second-nearest charger (0, 0) after
    # it; (0, 9) is 17 and 18 more. Neither leaves enough, so it charges at (9, 0), one step away
    mp = planner(at=c(9, 1))
    assert goto(mp.decide(0, 40, ())) == GoTo(Q2, 20, Phase.TO_CHARGER)
    assert mp.low


# ======================================================== the energy rules, simulated
WALLS = Workspace.build(
    size=(8, 8, 1),
    obstacles=frozenset({c(3, y) for y in range(1, 7)} | {c(5, y) for y in range(2, 8)}),
    charging_stations=(c(0, 0), c(7, 0)),
    parking=(c(0, 7), c(7, 7)),
)


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("drain", [1.0, 1.5])
def test_simulated_schedules_keep_the_battery_above_the_floor_and_lose_no_mail(drain: float, seed: int) -> None:
    """Legs are flown at once along the shortest way; a fifth of them find no plan (and cost nothing,
    as the drone waits on the ground); charging adds charge_per_step a step."""
    rng = random.Random(seed)
    model = BatteryModel(drain_per_step=drain)
    ways = _distance_function(SafePlanner(WALLS))

    def distance(a: Cell, b: Cell) -> int:
        return ways(a, b, frozenset(), frozenset())

    chargers = WALLS.charging_stations
    mp = MailPlanner(WALLS.parking[0], chargers, WALLS.parking, distance, model)
    monitor = BatteryMonitor(low=40, recharged=95)
    free = [cell for cell in WALLS.free_cells if cell not in chargers]
    mails = []
    for i in range(12):
        pickup, dropoff = rng.sample(free, 2)
        mails.append(MailRequest(f"m{i}", pickup, dropoff, rng.randint(0, 9), seq=i))
        mp.assign(mails[-1])
    level, delivered, lowest = 100.0, [], 100.0
    for now in range(600):
        for event in monitor.reading(level):
            (mp.battery_recharged if isinstance(event, BatteryRecharged) else mp.battery_low)()
        for action in mp.decide(now, level, ()):
            if isinstance(action, MailStarted):
                assert all(action.request.rank < r.rank for r in action.waiting)
            if not isinstance(action, GoTo):
                continue
            assert_energy_rules(mp.cell, action, level, chargers, distance, model)
            if rng.random() < 0.2:
                mp.leg_failed(now)  # found no plan: it waits on the ground, for free
                continue
            level -= distance(mp.cell, action.goal) * model.drain_per_step
            lowest = min(lowest, level)
            delivered += [d.request for d in mp.leg_done() if isinstance(d, MailDelivered)]
        if mp.phase is Phase.CHARGING:
            level = min(100.0, level + model.charge_per_step)
        if len(delivered) == len(mails):
            break
    assert lowest >= model.safe_threshold
    assert delivered == sorted(mails, key=lambda r: r.rank)  # all of them, most urgent first


def test_a_pickup_no_round_reaches_is_handed_back_and_the_queue_behind_it_goes_on() -> None:
    """Found by the systematic tester: a vehicle down rested on a pickup for good; the drone tried
    that mail first forever and the mail queued behind it was never delivered."""
    mp = planner()
    blocked, other = mail("blocked", c(2, 2), c(4, 4), priority=9), mail("other", c(6, 6), c(7, 7))
    mp.assign(blocked)
    mp.assign(other)
    handed: list[MailAction] = []
    for now in range(0, 200, 2):
        actions = mp.decide(now, 100, ())
        if any(isinstance(a, GoTo) for a in actions) and mp.current == other:
            break
        if any(isinstance(a, GoTo) for a in actions):
            assert mp.current == blocked
            handed += mp.leg_failed(now)  # every round finds the pickup taken for good
    assert [(type(a), a.request.id) for a in handed if isinstance(a, MailRejected)] == [(MailRejected, "blocked")]
    assert mp.current == other and mp.queue == []


def test_a_drone_walled_in_hands_back_every_mail_not_on_board() -> None:
    """Found by the systematic tester: a drone walled in by a vehicle down, obstacles and a parked
    drone held its mail for good while the others could have flown it."""
    mp = planner()
    mp.assign(mail("a", c(2, 2), c(4, 4)))
    mp.assign(mail("b", c(3, 3), c(5, 5)))
    mp.battery_low()  # its legs go to the chargers, and find no way there
    handed: list[MailAction] = []
    for now in range(0, 200, 2):
        if any(isinstance(a, GoTo) for a in mp.decide(now, 45, ())):
            assert mp.phase is Phase.TO_CHARGER
            handed += mp.leg_failed(now, cut_off=True)
        if handed:
            break
    assert sorted(a.request.id for a in handed if isinstance(a, MailRejected)) == ["a", "b"]
    assert mp.queue == [] and mp.current is None


def test_mail_whose_pickup_is_cut_off_from_here_waits_behind_the_rest() -> None:
    """Found by the systematic tester: the most urgent mail's pickup was walled off from the only drone
    in service; handed back, it came back to it and was tried first again and again, and the rest waited
    for good."""
    mp = planner()
    urgent, other = mail("urgent", c(2, 2), c(4, 4), priority=9), mail("other", c(6, 6), c(7, 7))
    mp.assign(urgent)
    mp.assign(other)
    mp.decide(0, 100, ())
    assert mp.current == urgent
    assert mp.leg_failed(0, cut_off=True) == []
    actions = mp.decide(mp.retry_at, 100, ())
    assert MailStarted(other, (urgent,)) in actions and goto(actions).goal == c(6, 6)
    mp.leg_done()  # picked up, somewhere else: the urgent mail is tried first again
    mp.decide(mp.retry_at + 1, 100, ())
    mp.leg_done()
    assert mp.decide(mp.retry_at + 2, 100, ())[0] == MailStarted(urgent, ())


def test_a_mail_whose_only_staging_charger_is_taken_is_handed_back() -> None:
    """Found by the systematic tester: the only charger from which a full battery affords the mail was
    taken for good; the drone flew between its parking cell and the other charger forever."""
    far = mail("far", c(9, 8), c(9, 2))  # a full battery (37 steps) affords it from Q2, not from Q1

    def at_q1() -> MailPlanner:
        mp = MailPlanner(Q1, (Q1, Q2), (P1, P2), manhattan, BatteryModel(drain_per_step=2))
        mp.assign(far)
        return mp

    mp = at_q1()
    assert goto(mp.decide(0, 100, ())).goal == Q2 and mp.phase is Phase.TO_CHARGER  # to charge there first
    [rejected] = at_q1().decide(0, 100, {Q2})
    assert isinstance(rejected, MailRejected) and "taken" in rejected.reason


def test_mail_queued_behind_a_drop_off_no_round_reaches_is_handed_back() -> None:
    """Found by the systematic tester: a vehicle down rested on the drop-off of the mail on board;
    the drone kept it (it cannot be handed over in the air) and the mail queued behind it waited for good."""
    mp = planner()
    on_board, behind = mail("on-board", c(2, 2), c(4, 4)), mail("behind", c(6, 6), c(7, 7))
    mp.assign(on_board)
    mp.assign(behind)
    mp.decide(0, 100, ())
    assert mp.leg_done() == [MailPickedUp(on_board)]
    handed: list[MailAction] = []
    for now in range(1, 200, 2):
        if any(isinstance(a, GoTo) for a in mp.decide(now, 100, ())):
            assert mp.phase is Phase.TO_DROPOFF
            handed += mp.leg_failed(now)  # every round finds the drop-off taken for good
        if handed:
            break
    assert [(type(a), a.request) for a in handed if isinstance(a, MailRejected)] == [(MailRejected, behind)]
    assert mp.carrying and mp.current == on_board and mp.queue == []


def test_a_drone_no_round_takes_to_a_charger_hands_back_the_mail_it_waits_with() -> None:
    """Found by the systematic tester: a vehicle down on the only charger a low drone could reach; the
    drone tried it for good, holding mail that other drones could have flown."""
    mp = planner()
    waiting = mail("waiting", c(2, 2), c(4, 4))
    mp.assign(waiting)
    mp.battery_low()
    handed: list[MailAction] = []
    for now in range(0, 300, 2):
        if any(isinstance(a, GoTo) for a in mp.decide(now, 45, ())):
            assert mp.phase is Phase.TO_CHARGER
            handed += mp.leg_failed(now)  # every round finds the charger another drone's for good
        if handed:
            break
    assert [(type(a), request_of(a)) for a in handed] == [(MailRejected, waiting)]


# ------------------------------------------------------------ making way
def test_a_parked_drone_asked_to_make_way_leaves_lands_and_stays_out_a_while() -> None:
    """A peer's way crosses our parking cell: fly to the spot, land there (waiting is free on the
    ground), and go home only after ``hold_steps``, not at once (that would close the way again)."""
    mp = planner()
    mp.make_way(c(1, 8))
    leg = goto(mp.decide(0, 100, set()))
    assert (leg.goal, leg.purpose) == (c(1, 8), Phase.MAKING_WAY)
    assert mp.leg_done() == [] and mp.landed(holding=True)
    away = manhattan(P1, c(1, 8)) + mp.hold_steps
    assert all(mp.decide(t, 100, set()) == [] for t in range(1, away))
    home = goto(mp.decide(away, 100, set()))
    assert (home.goal, home.purpose) == (P1, Phase.TO_PARKING)


def test_a_drone_with_mail_on_board_makes_way_then_goes_on_to_its_drop_off() -> None:
    """Found by the systematic tester: a vehicle down on one drone's drop-off, that drone waiting with
    its mail on another's drop-off, which waited for good in turn. Charging drones stay."""
    m = mail("m", c(2, 2), c(4, 4))
    carrying = planner()
    carrying.assign(m)
    goto(carrying.decide(0, 100, set()))
    carrying.leg_done()
    carrying.make_way(c(1, 2))
    leg = goto(carrying.decide(1, 100, set()))
    assert (leg.goal, leg.purpose) == (c(1, 2), Phase.MAKING_WAY)
    assert carrying.leg_done() == [] and carrying.carrying
    later = carrying.retry_at
    assert carrying.decide(later - 1, 100, set()) == []
    assert goto(carrying.decide(later, 100, set())).goal == c(4, 4)
    charging = planner(at=Q1)
    charging.battery_low()
    assert charging.decide(0, 50, set()) == [] and charging.phase is Phase.CHARGING
    charging.make_way(c(1, 1))
    assert charging.decide(1, 55, set()) == [] and charging.phase is Phase.CHARGING


def test_mail_whose_pickup_stays_taken_is_handed_back_even_with_other_legs_between() -> None:
    """Found by the systematic tester: a vehicle down on the pickup of the most urgent mail; from
    the charger the drone failed that leg without a round, parked to clear the way, could not afford
    the mail from there, charged, and tried again, each leg resetting its count: that mail and the
    ones behind it waited for good (892 steps)."""
    mp = planner(at=Q1)
    urgent, later = mail("urgent", c(2, 2), c(4, 4), priority=8), mail("later", c(1, 1), c(2, 0), priority=1)
    mp.assign(urgent)
    mp.assign(later)
    taken, handed, now, legs = {c(2, 2)}, list[MailRejected](), 0, 0
    while not handed and now < 2000:
        level = 100.0 if mp.cell in (Q1, Q2) else 45.0  # a full battery on a charger; afar, too little
        actions = mp.decide(now, level, taken)
        handed += [a for a in actions if isinstance(a, MailRejected)]
        if mp.busy:  # a round to the pickup finds no plan; the legs in between are flown
            legs += mp.goal not in taken
            ended = mp.leg_failed(now) if mp.goal in taken else mp.leg_done()
            handed += [a for a in ended if isinstance(a, MailRejected)]
        now = max(now + 1, mp.retry_at)
    assert [a.request for a in handed] == [urgent] and legs >= 2
    for _ in range(3):  # perhaps by a parking cell first, to clear the way
        actions = mp.decide(now, 100.0 if mp.cell in (Q1, Q2) else 45.0, taken)
        if MailStarted(later, ()) in actions:
            break
        mp.leg_done()
        now = max(now + 1, mp.retry_at)
    assert MailStarted(later, ()) in actions


def test_the_budgeted_way_goes_around_drones_resting_now_where_it_can() -> None:
    """Found by the systematic tester: a vehicle down sat on the shortest way to a drop-off; the
    budget counted the way through it, the planner found no plan within what the battery afforded,
    and the drone with mail on board tried again for good instead of charging first."""
    ring = Workspace.build(size=(5, 3, 1), obstacles=frozenset({(1, 1, 0), (2, 1, 0), (3, 1, 0)}))
    ways = _distance_function(SafePlanner(ring))
    none: frozenset[Cell] = frozenset()
    assert ways(c(0, 1), c(4, 1), none, none) == 6
    assert ways(c(0, 1), c(4, 1), frozenset({c(2, 0)}), none) == 6  # the other side of the ring is as short
    both = frozenset({c(2, 0), c(2, 2)})
    assert ways(c(0, 1), c(4, 1), both, none) == 6  # walled in by drones at rest: through them, as before
    assert ways(c(0, 0), c(3, 0), frozenset({c(2, 0)}), none) == 9  # around by the top, not through (2, 0)
    # A vehicle down moves for nobody: walled in, the way is through the drone at rest, never through it.
    assert ways(c(0, 0), c(3, 0), frozenset({c(2, 0)}), frozenset({c(2, 2)})) == 3
    assert ways(c(0, 1), c(4, 1), none, both) == 10**6
    assert ways(c(0, 1), c(2, 0), none, frozenset({c(2, 0)})) == 10**6  # nor to it: a pickup it sits on


def test_a_drone_asked_to_make_way_that_cannot_afford_the_spot_goes_to_charge() -> None:
    """Found by the systematic tester: a parked drone low on energy could not afford the way off and
    the reserve after it, stayed, and walled a drop-off off for good. Charging is a way off too."""
    mp = planner(at=P2)
    mp.make_way(c(8, 8))  # 4 steps off, 16 more to the charger second nearest it: 15 are left
    leg = goto(mp.decide(0, 35.0, set()))
    assert leg.purpose is Phase.TO_CHARGER and leg.goal in (Q1, Q2)


def walled_off(*cells: Cell) -> Distance:
    """Manhattan distance, but no way at all joins ``cells`` to anything (vehicles down wall them off)."""
    def distance(a: Cell, b: Cell) -> int:
        return NO_WAY if (a in cells) != (b in cells) else manhattan(a, b)
    return distance


def test_mail_whose_pickup_is_walled_off_is_handed_back_at_once() -> None:
    """Found by a crash sweep (seed 101): a vehicle down walled a drone in, and it kept mail it
    could not reach for good."""
    mp = MailPlanner(P1, (Q1, Q2), (P1, P2), walled_off(c(2, 2)), MODEL)
    mp.assign(mail("far", c(2, 2), c(3, 3), priority=9))
    mp.assign(mail("near", c(1, 5), c(2, 5), priority=1))
    actions = mp.decide(0, 100.0, set())
    rejected = [a for a in actions if isinstance(a, MailRejected)]
    assert [a.request.id for a in rejected] == ["far"] and "cut off" in rejected[0].reason  # not "needs 10**6 steps"
    assert goto(actions).goal == c(1, 5)


def test_a_drone_walled_off_from_every_charger_hands_its_mail_back() -> None:
    """Found by the tester (test_clean_stack_stays_live_under_the_fields_faults[4-2-5] once vehicles
    down were walls): low, with no charger in reach, it held four mails on the ground for good."""
    mp = MailPlanner(P1, (Q1, Q2), (P1, P2), walled_off(Q1, Q2), MODEL)
    mp.assign(mail("a", c(1, 5), c(2, 5)))
    mp.assign(mail("b", c(3, 5), c(4, 5)))
    mp.battery_low()
    actions = mp.decide(0, 38.0, set())
    assert sorted(a.request.id for a in actions if isinstance(a, MailRejected)) == ["a", "b"]
    assert mp.queue == []


def test_a_low_drone_whose_battery_reaches_no_charger_makes_way_and_hands_its_mail_back() -> None:
    """Found by the systematic tester (sweep 20142 with --skews 1): a drone whose clock was off landed on
    one charger for good. A low drone beside it could afford the way off a drop-off, but not that and the
    way to the other charger after it: it stayed, and the mail was never delivered. Energy kept for a
    charger out of reach is kept for nothing; the floor still holds."""
    mp = MailPlanner(c(1, 0), (Q1, Q2), (P1, P2), walled_off(Q1), MODEL)
    mp.assign(mail("queued", c(6, 6), c(7, 7)))
    mp.battery_low()
    mp.make_way(c(2, 1))
    level = MODEL.safe_threshold + 6 * MODEL.drain_per_step  # 2 steps to the spot; Q2 is 8 away
    actions = mp.decide(0, level, set())
    assert goto(actions) == GoTo(c(2, 1), 6, Phase.MAKING_WAY)
    assert mp.why_spent == STRANDED
    mp.leg_done()
    handed = mp.decide(30, level - 2, set())
    assert [(a.request.id, a.reason) for a in handed if isinstance(a, MailRejected)] == [("queued", STRANDED)]


def test_the_reserve_counts_only_the_chargers_a_way_joins() -> None:
    """With one charger walled off for good, the reserve is the way to the other: counting the
    second nearest left every mail unaffordable, and the drone charged at 100% for good."""
    mp = MailPlanner(P1, (Q1, Q2), (P1, P2), walled_off(Q2), MODEL)
    mp.assign(mail("m", c(1, 5), c(2, 3)))
    assert goto(mp.decide(0, 100.0, set())).goal == c(1, 5)


def test_a_parking_cell_walled_off_does_not_keep_a_charged_drone_charging() -> None:
    """Found by the same test: its parking cell walled off, a charged drone went to park, found no
    way, went to charge instead (at the charger it stood on), and started again, for good."""
    mp = MailPlanner(Q1, (Q1, Q2), (P1,), walled_off(P1), MODEL)
    mp.tried.add(c(4, 4))  # a leg found no plan: it would park first to clear the way
    mp.assign(mail("m", c(1, 5), c(2, 3)))
    assert goto(mp.decide(0, 100.0, set())).goal == c(1, 5)


def test_mail_on_board_whose_drop_off_is_walled_off_hands_the_queue_back() -> None:
    """Found by sweep seed 8007 once no way led into a vehicle down's cell: one came down on the
    drop-off of the mail on board, and the drone charged at 100% for good, the queue behind it held."""
    carried, walls = mail("on board", c(1, 5), c(3, 3)), set[Cell]()

    def distance(a: Cell, b: Cell) -> int:  # the drop-off is walled off once the mail is on board
        return walled_off(*walls)(a, b)

    mp = MailPlanner(c(1, 5), (Q1, Q2), (P1, P2), distance, MODEL)
    take_on_board(mp, carried)
    walls.add(c(3, 3))
    mp.assign(mail("next", c(2, 5), c(4, 5)))
    actions = mp.decide(0, 100.0, set())
    assert [(a.request.id, "cut off" in a.reason) for a in actions if isinstance(a, MailRejected)] == [("next", True)]
    assert mp.current == carried and mp.queue == [] and mp.decide(1, 100.0, set()) == []


def test_a_drone_whose_battery_reaches_no_charger_hands_its_mail_back() -> None:
    """Found by the tester (sweep seed 98791: 5 drones, 8x8): its way to a charger blocked, a drone
    waited until its battery afforded neither charger, then held three mails on the ground for good."""
    mp = MailPlanner(c(5, 5), (Q1, Q2), (P1, P2), manhattan, MODEL)
    mp.assign(mail("a", c(1, 5), c(2, 5)))
    mp.assign(mail("b", c(3, 5), c(4, 5)))
    mp.battery_low()
    actions = mp.decide(0, 25.0, set())  # 9 and 10 cells to the chargers; the floor is 20
    assert sorted(a.request.id for a in actions if isinstance(a, MailRejected)) == ["a", "b"]
    assert "reaches no charger" in next(a for a in actions if isinstance(a, MailRejected)).reason
    assert mp.queue == []


# ======================================================== legs with an overhead, goals passed through
def test_a_pickup_leg_is_given_its_overhead_and_moves_even_where_the_overhead_outweighs_the_margin() -> None:
    """What the leg to a pickup keeps for after it is the drop-off leg and the way to a charger; its own
    overhead (lead steps, first step) is flown within it. Reserving a leg from the pickup to itself
    (an overhead) in place of the margin left a landed drone with less than its lead: no plan, for good."""
    overhead = MODEL.margin_steps + 2
    mp = MailPlanner(Q1, (Q1, Q2), (P1, P2), manhattan, MODEL, leg_overhead=overhead)
    m = mail("m", c(1, 0), c(3, 0))
    need = (overhead + 1) + (overhead + 2) + (overhead + manhattan(c(3, 0), Q2)) + MODEL.margin_steps
    mp.assign(m)
    leg = goto(mp.decide(0, MODEL.safe_threshold + need, ()))
    assert leg.goal == m.pickup and leg.flight_steps is not None
    assert leg.flight_steps >= overhead + manhattan(Q1, m.pickup)


def test_a_mail_whose_drop_off_no_way_joins_is_rejected_before_its_pickup() -> None:
    """A vehicle down on the drop-off: picked up, the mail would stay on board for good. (No chargers,
    so no energy rule rejects it first.)"""
    walled = c(4, 4)
    mp = MailPlanner(P1, (), (P1, P2), lambda a, b: NO_WAY if walled in (a, b) else manhattan(a, b), MODEL)
    m = mail("m", c(2, 2), walled)
    mp.assign(m)
    [rejected] = mp.decide(0, 100, ())
    assert isinstance(rejected, MailRejected) and "drop-off [4, 4, 0] is cut off" in rejected.reason
    assert not mp.carrying and mp.current is None


def test_a_drone_low_where_no_charger_is_hands_its_mail_back_parks_and_takes_no_more() -> None:
    """Flown on ArduCopter SITL (no charger in the workspace, SITL's battery low after 5 minutes): the
    low drone handed its mail back as if walls cut it off from a charger, and each low peer took it
    over and handed it back in turn. It says why, delivers what is on board, parks, and flies no more."""
    carried, queued = mail("on board", c(2, 2), c(4, 4)), mail("queued", c(6, 6), c(7, 7))
    mp = MailPlanner(c(3, 3), (), (P1, P2), manhattan, MODEL)
    take_on_board(mp, carried)
    mp.assign(queued)
    mp.battery_low()
    assert mp.spent
    [to_dropoff] = mp.decide(0, 100, ())
    assert to_dropoff == GoTo(c(4, 4), None, Phase.TO_DROPOFF)
    mp.leg_done()
    handed, to_parking = mp.decide(1, 100, ())
    assert handed == MailRejected(queued, "its battery is low, and the workspace has no charger", True)
    assert isinstance(to_parking, GoTo) and to_parking.goal in (P1, P2) and to_parking.purpose is Phase.TO_PARKING
    mp.leg_done()
    assert mp.decide(2, 100, ()) == [] and mp.landed_here and mp.queue == []


def handed_back_while_the_pickup_is_taken(passing: bool, steps: int = 600) -> list[MailAction]:
    """A mail whose pickup another drone rests on all along (``passing``: its plan ends there, under
    way) : every round to it fails; what was handed back."""
    pickup = c(2, 2)
    mp = planner(at=c(5, 5))
    mp.assign(mail("m", pickup, c(4, 4)))
    handed: list[MailAction] = []
    for now in range(steps):
        actions = mp.decide(now, 100, (pickup,), (pickup,) if passing else ())
        handed += [a for a in actions if isinstance(a, MailRejected)]
        if any(isinstance(a, GoTo) for a in actions):
            handed += [a for a in mp.leg_failed(now) if isinstance(a, MailRejected)]
    return handed


def test_a_pickup_where_a_peer_s_plan_ends_is_waited_for_not_handed_back() -> None:
    """Two mails with one pickup: the drone that gets there first rests there until its next leg. The
    other waits, whatever it takes; the same pickup held by a drone at rest is handed back as before."""
    assert handed_back_while_the_pickup_is_taken(passing=True) == []
    assert handed_back_while_the_pickup_is_taken(passing=False)


# ======================================================== clearance for pickup (a service dispatches)
def test_mail_is_taken_on_board_only_once_its_dispatcher_cleared_it() -> None:
    mp = planner()
    mp.cleared = set()
    m = mail("m", c(2, 2), c(4, 4))
    mp.assign(m)
    goto(mp.decide(0, 100, ()))
    [rejected] = mp.leg_done()  # at the pickup with no clearance: handed back, not on board
    assert rejected == MailRejected(m, NOT_CLEARED, True)
    assert (mp.current, mp.carrying, mp.queue) == (None, False, [])
    mp.assign(m)
    mp.cleared.add("m")
    goto(mp.decide(1, 100, ()))
    assert mp.leg_done() == [MailPickedUp(m)] and mp.carrying


def test_a_clearance_holds_for_one_holding_of_the_mail() -> None:
    """One that comes once the mail was handed back is not taken; one for mail handed back, delivered or
    lost ends with it: given the mail again, the drone waits for a new clearance."""
    mp = planner()
    mp.cleared = set()
    m = mail("m", c(2, 2), c(4, 4))
    assert not mp.clear("m") and mp.cleared == set()  # not held here
    mp.assign(m)
    assert mp.clear("m") and mp.cleared == {"m"}
    mp.reported(MailPickedUp(m))
    assert mp.cleared == {"m"}
    mp.reported(MailRejected(m, "a goal taken", True))
    assert mp.cleared == set()
    no_service = planner()
    no_service.assign(m)
    assert not no_service.clear("m") and no_service.cleared is None


def test_out_of_touch_with_its_dispatcher_a_drone_keeps_only_cleared_mail() -> None:
    mp = planner()
    mp.cleared = {"started"}
    started, waiting, later = mail("started", c(2, 2), c(4, 4), 9), mail("waiting", c(3, 3), c(5, 5)), \
        mail("later", c(1, 1), c(6, 6), 1)
    for m in (started, waiting, later):
        mp.assign(m)
    goto(mp.decide(0, 100, ()))
    assert mp.current == started
    handed = mp.release("out of touch", keep_cleared=True)
    assert [(type(a), request_of(a).id) for a in handed] == [(MailRejected, "waiting"), (MailRejected, "later")]
    assert mp.current == started and mp.queue == []
    assert [request_of(a).id for a in mp.release("lost")] == ["started"]  # without keep_cleared: all not on board
