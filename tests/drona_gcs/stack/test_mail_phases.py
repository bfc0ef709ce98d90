"""The mail planner's state (phase, mail on board, charging first, the operator's command) changes only as its
one table says (``drona_gcs.stack.mail.TRANSITIONS``)."""

from __future__ import annotations

import dataclasses
import itertools

import pytest

from drona_gcs.errors import ProtocolViolation
from drona_gcs.stack.battery import BatteryModel
from drona_gcs.stack.mail import (
    TRANSITIONS,
    Command,
    Energy,
    GoTo,
    Load,
    MailEvent,
    MailPickedUp,
    MailPlanner,
    MailRequest,
    MailState,
    Phase,
)
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
    with pytest.raises(ProtocolViolation, match="mail planner: 'charge_here' in state to_pickup cannot lead anywhere"):
        mp._enter(MailEvent.CHARGE_HERE)
    with pytest.raises(ProtocolViolation,
                       match="mail planner: 'leg to_charger' in state to_pickup cannot lead anywhere"):
        mp._enter((MailEvent.LEG, Phase.TO_CHARGER))
    assert mp.phase is Phase.TO_PICKUP  # refused: nothing changed


def test_the_phase_is_changed_only_through_the_table() -> None:
    with pytest.raises(AttributeError):
        planner().phase = Phase.CHARGING  # type: ignore[misc]


def test_every_state_is_in_the_table_and_can_get_back_to_idle() -> None:
    every = {MailState(*parts) for parts in itertools.product(Phase, Load, Energy, Command)}
    assert set(TRANSITIONS) == every
    back = {MailState(Phase.IDLE)}
    for _ in every:
        back |= {state for state, moves in TRANSITIONS.items() if set(moves.values()) & back}
    assert back == every


START_MAIL = (MailEvent.LEG, Phase.TO_PICKUP)


def test_the_table_starts_mail_only_with_none_on_board_charged_enough_and_no_command() -> None:
    starting = {state for state, moves in TRANSITIONS.items() if START_MAIL in moves}
    assert starting == {MailState(Phase.IDLE)}


def test_a_held_drone_may_start_no_leg_nor_charge_where_it_is() -> None:
    for state, moves in TRANSITIONS.items():
        legs = {e for e in moves if isinstance(e, tuple) or e is MailEvent.CHARGE_HERE}
        assert not (state.command is Command.HELD and legs), state


def test_mail_goes_on_board_only_at_the_end_of_a_leg_to_its_pickup_and_off_only_at_a_drop_off_or_lost() -> None:
    for state, moves in TRANSITIONS.items():
        for event, target in moves.items():
            if target.load is not state.load:
                on = target.load is Load.ON_BOARD
                assert (state.phase, event) == (Phase.TO_PICKUP, MailEvent.PICKED_UP) if on else \
                    event is MailEvent.LOST or (state.phase, event) == (Phase.TO_DROPOFF, MailEvent.DELIVERED)


def test_an_event_the_state_cannot_take_names_the_whole_state() -> None:
    mp = planner()
    mp.assign(MailRequest("m1", PICKUP, DROPOFF, 5))
    mp.decide(0, 100.0, ())
    assert mp.leg_done() == [MailPickedUp(MailRequest("m1", PICKUP, DROPOFF, 5))]
    mp.battery_low()
    mp.pause()
    assert mp.state == MailState(Phase.IDLE, Load.ON_BOARD, Energy.LOW, Command.PAUSED)
    with pytest.raises(ProtocolViolation,
                       match=r"'leg to_pickup' in state idle \(on_board, low, paused\) cannot lead anywhere"):
        mp._enter(START_MAIL)
    mp.hold()
    with pytest.raises(ProtocolViolation,
                       match=r"'leg to_dropoff' in state idle \(on_board, low, held\) cannot lead anywhere"):
        mp._enter((MailEvent.LEG, Phase.TO_DROPOFF))
    assert mp.state == MailState(Phase.IDLE, Load.ON_BOARD, Energy.LOW, Command.HELD)  # refused: nothing changed


def test_a_held_drone_decides_nothing_and_a_resumed_one_delivers() -> None:
    mp = planner()
    mp.assign(MailRequest("m1", PICKUP, DROPOFF, 5))
    mp.pause()
    mp.hold()
    assert mp.decide(0, 100.0, ()) == [] and mp.held and mp.paused
    mp.resume()
    assert mp.state == MailState(Phase.IDLE)
    assert phases_of_a_delivery(mp)[-1] is Phase.IDLE and mp.queue == []


#: The planner's booleans that are data, not state (each says why where it is declared): whatever decides
#: the next leg is in the table, so a new boolean field must be one of these, or a part of MailState.
DATA_FLAGS = {"landed_here", "goal_taken", "stranded"}


def test_no_boolean_beside_the_state_but_plain_data() -> None:
    flags = {f.name for f in dataclasses.fields(MailPlanner) if f.type in ("bool", bool)}
    assert flags == DATA_FLAGS
    mp = planner()
    for folded in ("carrying", "low", "paused", "held"):
        with pytest.raises(AttributeError):
            setattr(mp, folded, True)


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
