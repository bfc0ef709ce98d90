"""The mail planner's phases change only as its one table says (``drona_gcs.stack.mail.TRANSITIONS``)."""

from __future__ import annotations

import pytest

from drona_gcs.errors import ProtocolViolation
from drona_gcs.stack.battery import BatteryModel
from drona_gcs.stack.mail import TRANSITIONS, GoTo, MailEvent, MailPlanner, MailRequest, Phase
from drona_gcs.workspace import Cell

CHARGER, PARKING, PICKUP, DROPOFF = (0, 0, 0), (0, 9, 0), (4, 4, 0), (8, 2, 0)


def manhattan(a: Cell, b: Cell) -> int:
    return sum(abs(p - q) for p, q in zip(a, b, strict=True))


def planner() -> MailPlanner:
    return MailPlanner(PARKING, (CHARGER, (9, 0, 0)), (PARKING,), manhattan, BatteryModel())


def phases_of_a_delivery(mp: MailPlanner) -> list[Phase]:
    mp.assign(MailRequest("m1", PICKUP, DROPOFF, 5))
    seen = [mp.phase]
    for _ in range(2):
        legs = [a for a in mp.decide(0, 100.0, ()) if isinstance(a, GoTo)]
        assert len(legs) == 1
        seen.append(mp.phase)
        mp.leg_done()
        seen.append(mp.phase)
    return seen


def test_a_delivery_goes_through_the_table() -> None:
    assert phases_of_a_delivery(planner()) == [Phase.IDLE, Phase.TO_PICKUP, Phase.IDLE, Phase.TO_DROPOFF, Phase.IDLE]


def test_an_event_the_phase_cannot_take_names_both() -> None:
    mp = planner()
    mp.assign(MailRequest("m1", PICKUP, DROPOFF, 5))
    mp.decide(0, 100.0, ())
    assert mp.phase is Phase.TO_PICKUP
    with pytest.raises(ProtocolViolation, match="mail planner: no 'charge_here' while to_pickup"):
        mp._enter(MailEvent.CHARGE_HERE)
    with pytest.raises(ProtocolViolation, match="no 'leg to_charger' while to_pickup"):
        mp._enter((MailEvent.LEG, Phase.TO_CHARGER))
    assert mp.phase is Phase.TO_PICKUP  # refused: nothing changed


def test_the_phase_is_changed_only_through_the_table() -> None:
    with pytest.raises(AttributeError):
        planner().phase = Phase.CHARGING  # type: ignore[misc]


def test_every_phase_is_in_the_table_and_can_get_back_to_idle() -> None:
    assert set(TRANSITIONS) == set(Phase)
    back = {Phase.IDLE}
    for _ in Phase:
        back |= {phase for phase, moves in TRANSITIONS.items() if set(moves.values()) & back}
    assert back == set(Phase)


def test_a_failure_reported_after_its_leg_ended_is_taken_in_idle() -> None:
    """The vehicle relocated while its round went on: the round's failure still comes, and is no error."""
    mp = planner()
    mp.assign(MailRequest("m1", PICKUP, DROPOFF, 5))
    mp.decide(0, 100.0, ())
    mp.relocate((2, 2, 0), landed=True)
    assert mp.phase is Phase.IDLE
    mp.leg_failed(3)
    mp.leg_not_flown(4)
    assert mp.phase is Phase.IDLE and [r.id for r in mp.queue] == ["m1"]
