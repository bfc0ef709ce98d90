"""The priority mail task planner's order and legs: most urgent first, pickup then drop-off then
parking, failed legs, retries and vehicles that come down.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Collection

import pytest

from drona_gcs.errors import ProtocolViolation
from drona_gcs.stack.mail import (
    GoTo,
    MailDelivered,
    MailLost,
    MailPickedUp,
    MailPlanner,
    MailRejected,
    MailRequest,
    MailStarted,
    Phase,
)
from drona_gcs.workspace import Cell
from tests.drona_gcs.stack.mail_helpers import MODEL, P2, Q1, Q2, c, goto, mail, manhattan, planner


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
