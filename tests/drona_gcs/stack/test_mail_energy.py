"""The priority mail task planner's energy rules: charging and parking by hand, then the planner
in a small simulated world with walls (real shortest-path distances), random mail and failed legs,
where the battery never goes below the floor and no mail is lost.
"""

from __future__ import annotations

import random

import pytest

from drona_gcs.planner import SafePlanner
from drona_gcs.stack.battery import BatteryModel, BatteryMonitor, BatteryRecharged
from drona_gcs.stack.drone import _distance_function
from drona_gcs.stack.mail import (
    Distance,
    GoTo,
    MailAction,
    MailDelivered,
    MailPickedUp,
    MailPlanner,
    MailRejected,
    MailRequest,
    MailStarted,
    Phase,
)
from drona_gcs.workspace import Cell, Workspace
from tests.drona_gcs.stack.mail_helpers import MODEL, P1, P2, Q1, Q2, c, goto, mail, manhattan, planner, request_of


def assert_energy_rules(goal_from: Cell, action: GoTo, level: float, chargers: tuple[Cell, ...],
                        distance: Distance, model: BatteryModel = MODEL) -> None:
    """The leg is affordable, and on arrival the way from the goal to a charger is still left."""
    assert action.flight_steps is not None
    assert distance(goal_from, action.goal) <= action.flight_steps
    to_charger = min(distance(action.goal, q) for q in chargers)
    assert action.flight_steps + to_charger <= model.steps_affordable(level)


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
