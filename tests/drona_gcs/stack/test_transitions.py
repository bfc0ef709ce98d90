"""The one check every machine's state change goes through: a move its table has, or a refusal naming all."""

from __future__ import annotations

import enum

import pytest

from drona_gcs.errors import ProtocolViolation
from drona_gcs.stack.transitions import checked, lookup


class Light(enum.Enum):
    OFF = "off"
    ON = "on"


class Switch(enum.Enum):
    FLIP = "flip"
    CUT = "cut"


class Flipped:
    """An event keyed by its type, as the battery monitor's and the protocol's tables are."""


TABLE: dict[Light, dict[object, Light]] = {
    Light.OFF: {Switch.FLIP: Light.ON, Flipped: Light.ON},
    Light.ON: {Switch.FLIP: Light.OFF, Switch.CUT: Light.OFF, (Switch.CUT, Light.ON): Light.OFF},
}


def test_a_move_in_the_table_leads_where_its_row_says() -> None:
    assert lookup(TABLE, "lamp", Light.OFF, Switch.FLIP) is Light.ON
    assert lookup(TABLE, "lamp", Light.ON, Switch.FLIP) is Light.OFF
    assert lookup(TABLE, "lamp", Light.OFF, Flipped) is Light.ON


@pytest.mark.parametrize(("state", "event", "message"), [
    (Light.OFF, Switch.CUT, "lamp: 'cut' in state off cannot lead anywhere"),
    (Light.ON, Flipped, "lamp: 'Flipped' in state on cannot lead anywhere"),
    (Light.OFF, (Switch.CUT, Light.ON), "lamp: 'cut on' in state off cannot lead anywhere"),
])
def test_an_event_the_row_has_no_move_for_is_refused_naming_machine_state_and_event(
        state: Light, event: object, message: str) -> None:
    with pytest.raises(ProtocolViolation) as refused:
        lookup(TABLE, "lamp", state, event)
    assert str(refused.value) == message


def test_a_chosen_target_passes_only_if_the_move_allows_it() -> None:
    assert checked("drone 'a'", Light.OFF, Flipped, Light.ON, frozenset({Light.ON})) is Light.ON
    with pytest.raises(ProtocolViolation) as refused:
        checked("drone 'a'", Light.OFF, Flipped, Light.OFF, frozenset({Light.ON}))
    assert str(refused.value) == "drone 'a': 'Flipped' in state off cannot lead to off"


def test_a_change_outside_any_event_is_refused() -> None:
    with pytest.raises(ProtocolViolation) as refused:
        checked("drone 'a'", Light.OFF, None, Light.ON, frozenset())
    assert str(refused.value) == "drone 'a': a change outside any event in state off cannot lead to on"
