"""The priority mail task planner's reach: cells walled off, chargers no way joins, legs with an
overhead and goals where a peer's plan ends.
"""

from __future__ import annotations

from drona_gcs.stack.mail import (
    NO_WAY,
    STRANDED,
    Distance,
    GoTo,
    MailAction,
    MailPickedUp,
    MailPlanner,
    MailRejected,
    MailRequest,
    Phase,
)
from drona_gcs.workspace import Cell
from tests.drona_gcs.stack.mail_helpers import MODEL, P1, P2, Q1, Q2, c, goto, mail, manhattan, planner


def take_on_board(mp: MailPlanner, request: MailRequest) -> None:
    """Take ``request`` on board as a drone does: its leg to the pickup, flown (the only way mail gets on board)."""
    mp.assign(request)
    assert goto(mp.decide(0, 100.0, ())).goal == request.pickup
    assert mp.leg_done() == [MailPickedUp(request)] and mp.carrying


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


def test_a_parking_cell_beyond_a_full_charge_does_not_keep_a_charged_drone_charging() -> None:
    """Found by sweep seed 30562 (two agents crashed): a leg had found no plan, so the drone would park
    first; its parking cell (and the way on to a charger) was beyond what a full battery affords, so it
    went to charge instead at the charger it stood on, charged in full, and started again, for good,
    its mail never tried."""
    far = c(60, 0)
    mp = MailPlanner(Q1, (Q1, Q2), (far,), manhattan, MODEL)
    mp.tried.add(c(4, 4))
    mp.assign(mail("m", c(1, 5), c(2, 3)))
    assert goto(mp.decide(0, 100.0, set())).goal == c(1, 5)


def test_an_idle_drone_whose_parking_cell_is_beyond_a_full_charge_rests_where_it_is() -> None:
    """Found by review: with no mail, the way to park sent it to charge at the charger it stood on, for
    good; charging, it makes way for nobody, and the charger was lost to the fleet. Idle, it is asked."""
    mp = MailPlanner(Q1, (Q1, Q2), (c(60, 0),), manhattan, MODEL)
    assert mp.decide(0, 100.0, set()) == [] and mp.phase is Phase.IDLE
    mp.make_way(c(1, 0), 10)
    assert goto(mp.decide(1, 100.0, set())).goal == c(1, 0)


def test_a_parking_cell_a_charge_brings_in_reach_is_still_parked_on_after_charging() -> None:
    """The way to park is cleared first when a charge affords it: a drone too low for it charges."""
    mp = MailPlanner(Q1, (Q1, Q2), (P1,), manhattan, MODEL)
    mp.tried.add(c(4, 4))
    mp.assign(mail("m", c(1, 5), c(2, 3)))
    assert mp.decide(0, 30.0, set()) == [] and mp.phase is Phase.CHARGING
    assert goto(mp.decide(1, 100.0, set())).goal == P1


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
