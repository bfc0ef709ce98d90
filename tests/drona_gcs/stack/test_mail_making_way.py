"""The priority mail task planner making way: a drone parked or resting where another's leg
goes leaves, and mail whose pickup stays taken is handed back.
"""

from __future__ import annotations

from drona_gcs.planner import SafePlanner
from drona_gcs.stack.drone import _distance_function
from drona_gcs.stack.mail import (
    GoTo,
    MailRejected,
    MailStarted,
    Phase,
)
from drona_gcs.workspace import Cell, Workspace
from tests.drona_gcs.stack.mail_helpers import P1, P2, Q1, Q2, c, goto, mail, manhattan, planner


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


def test_a_drone_with_mail_on_board_asked_to_make_way_by_the_drone_on_its_charger_makes_way() -> None:
    """Found by the systematic tester (sweep 30362, seed 561331): a drone with mail on board waited to
    charge at a dead-end charger (9, 0) and walled in the drone on it, which asked it to make way; too
    low for the way off and a charger after it, it stayed, for good. With mail on board it does as any
    drone: goes to a charger it affords that the asker does not wall in, else leaves keeping the way to
    the charger behind (reached once the asker has left), not stranding the mail off every charger."""
    for level, leg in ((26.0, GoTo(c(9, 2), 4, Phase.MAKING_WAY)), (30.0, GoTo(Q1, 10, Phase.TO_CHARGER)),
                       (22.0, None)):
        mp = planner(at=c(9, 1))
        mp.assign(mail("m", c(9, 1), c(9, 9)))
        goto(mp.decide(0, 100, set()))
        mp.leg_done()
        assert mp.carrying
        mp.make_way(c(9, 2), 2, frozenset({Q2}))  # 1 step off, 11 from there to (0, 0), 2 back to (9, 0)
        assert mp.decide(1, level, {Q2}) == ([leg] if leg else []), level
