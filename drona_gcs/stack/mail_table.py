"""The mail planner's state and its one table of transitions (see :class:`drona_gcs.stack.mail.MailPlanner`).

Everything that decides what the planner does next lives here: the leg it flies (:class:`Phase`), the
mail on board (:class:`Load`), whether it must charge first (:class:`Energy`) and the operator's command
in force (:class:`Command`). Each part has its own table, and :data:`TRANSITIONS` joins them: an event
is taken when every part whose table names it has a move for it, and moves each of them (h11's
``_state.py`` in spirit; the parts are a statechart's orthogonal regions). So the table itself says
that a drone with mail on board, a low battery or a paused queue starts no mail, that a held drone
starts no leg at all, and that mail is taken on board only at the end of a leg to its pickup.
"""

from __future__ import annotations

import enum
import itertools
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

from drona_gcs.stack.transitions import lookup


class Phase(enum.Enum):
    IDLE = "idle"  #: nothing to do (landed when at a parking cell or charger)
    TO_PICKUP = "to_pickup"  #: flying to the pickup of ``current``
    TO_DROPOFF = "to_dropoff"  #: carrying ``current`` to its drop-off
    TO_CHARGER = "to_charger"  #: flying to a charging station
    CHARGING = "charging"  #: landed on a station until recharged
    TO_PARKING = "to_parking"  #: flying to a parking cell
    MAKING_WAY = "making_way"  #: leaving a cell another drone's way crosses


class Load(enum.Enum):
    EMPTY = "empty"  #: no mail on board (``current``, if any, is not picked up yet)
    ON_BOARD = "on_board"  #: ``current`` is on board


class Energy(enum.Enum):
    OK = "ok"  #: legs go wherever the budget affords
    LOW = "low"  #: charge before any leg but the drop-off of the mail on board (or park, where none charges)


class Command(enum.Enum):
    NONE = "none"  #: no operator's command in force
    PAUSED = "paused"  #: no mail starts; mail on board is still delivered
    HELD = "held"  #: landed where it is by the operator: no leg at all until resumed


class MailEvent(enum.Enum):
    """What moves a mail planner from one :class:`MailState` to another (see :data:`TRANSITIONS`)."""

    LEG = "leg"  #: a leg starts: to the phase of its purpose
    CHARGE_HERE = "charge_here"  #: already on a charger: charge without flying
    ARRIVED = "arrived"  #: the leg's plan was flown to its goal (no mail taken on board or delivered)
    PICKED_UP = "picked_up"  #: the leg to the pickup was flown, and its mail taken on board
    DELIVERED = "delivered"  #: the leg to the drop-off was flown, and the mail on board delivered
    NOT_FLOWN = "not_flown"  #: the leg's plan ended with the vehicle not seen at its goal
    FAILED = "failed"  #: no plan was found for the leg
    LOST = "lost"  #: the vehicle came down by itself: the mail on board is lost with it
    LOW = "low"  #: the battery is low, or affords too little for the leg wanted: charge first
    RECHARGED = "recharged"  #: the battery is full again
    RELOCATED = "relocated"  #: the vehicle, lost, is back somewhere
    RELOCATED_ON_CHARGER = "relocated_on_charger"  #: ... landed on a charger
    PAUSE = "pause"  #: the operator's pause (or recall)
    HOLD = "hold"  #: the operator landed the drone where it is
    RESUME = "resume"  #: the operator undid a pause, recall or landing


_LEGS = (Phase.TO_PICKUP, Phase.TO_DROPOFF, Phase.TO_CHARGER, Phase.TO_PARKING, Phase.MAKING_WAY)
_Event = MailEvent | tuple[MailEvent, Phase]  #: a leg's event is (LEG, its purpose)
_LEG: dict[Phase, _Event] = {purpose: (MailEvent.LEG, purpose) for purpose in _LEGS}
_LEG_ENDS: dict[_Event, Phase] = {MailEvent.NOT_FLOWN: Phase.IDLE, MailEvent.FAILED: Phase.IDLE,
                                  MailEvent.RELOCATED: Phase.IDLE}
_MAIL_ENDS: dict[Phase, dict[_Event, Phase]] = {Phase.TO_PICKUP: {MailEvent.PICKED_UP: Phase.IDLE},
                                                Phase.TO_DROPOFF: {MailEvent.DELIVERED: Phase.IDLE}}

#: The leg: phase -> event -> the next phase.
PHASES: dict[Phase, dict[_Event, Phase]] = {
    Phase.IDLE: {**{_LEG[leg]: leg for leg in _LEGS}, MailEvent.CHARGE_HERE: Phase.CHARGING,
                 MailEvent.RECHARGED: Phase.IDLE, MailEvent.RELOCATED: Phase.IDLE,
                 **_LEG_ENDS},  # a leg already ended (its vehicle relocated) may still report how
    **{leg: {MailEvent.ARRIVED: Phase.CHARGING if leg is Phase.TO_CHARGER else Phase.IDLE, **_LEG_ENDS,
             MailEvent.RECHARGED: leg, **_MAIL_ENDS.get(leg, {})} for leg in _LEGS},
    Phase.CHARGING: {MailEvent.RECHARGED: Phase.IDLE, MailEvent.RELOCATED: Phase.IDLE,
                     MailEvent.RELOCATED_ON_CHARGER: Phase.CHARGING},
}

#: The mail on board: taken on board at its pickup, off at its drop-off or with the vehicle. Mail
#: starts (and a drone parks) only with none on board; a leg to a drop-off only with some.
LOADS: dict[Load, dict[_Event, Load]] = {
    Load.EMPTY: {MailEvent.PICKED_UP: Load.ON_BOARD, _LEG[Phase.TO_PICKUP]: Load.EMPTY,
                 _LEG[Phase.TO_PARKING]: Load.EMPTY},
    Load.ON_BOARD: {MailEvent.DELIVERED: Load.EMPTY, MailEvent.LOST: Load.EMPTY,
                    _LEG[Phase.TO_DROPOFF]: Load.ON_BOARD},
}

#: Charging first: until recharged, no mail starts.
ENERGIES: dict[Energy, dict[_Event, Energy]] = {
    Energy.OK: {MailEvent.LOW: Energy.LOW, MailEvent.RECHARGED: Energy.OK, _LEG[Phase.TO_PICKUP]: Energy.OK},
    Energy.LOW: {MailEvent.LOW: Energy.LOW, MailEvent.RECHARGED: Energy.OK},
}

_ANY_LEG: dict[_Event, Command] = {_LEG[leg]: Command.NONE for leg in _LEGS}
_COMMANDS: dict[_Event, Command] = {MailEvent.PAUSE: Command.PAUSED, MailEvent.HOLD: Command.HELD,
                                    MailEvent.RESUME: Command.NONE}
#: The operator's command: paused, no mail starts; held, no leg at all (nor charging where it is).
COMMANDS: dict[Command, dict[_Event, Command]] = {
    Command.NONE: {**_ANY_LEG, MailEvent.CHARGE_HERE: Command.NONE, **_COMMANDS},
    Command.PAUSED: {**{e: Command.PAUSED for e in _ANY_LEG if e != _LEG[Phase.TO_PICKUP]},
                     MailEvent.CHARGE_HERE: Command.PAUSED, **_COMMANDS},
    Command.HELD: {**_COMMANDS, MailEvent.PAUSE: Command.HELD},  # a pause adds nothing to a hold
}


@dataclass(frozen=True)
class MailState:
    """Where a mail planner is: one value of each part of the table."""

    phase: Phase
    load: Load = Load.EMPTY
    energy: Energy = Energy.OK
    command: Command = Command.NONE

    def __str__(self) -> str:
        rest = [part.value for part, usual in ((self.load, Load.EMPTY), (self.energy, Energy.OK),
                                               (self.command, Command.NONE)) if part is not usual]
        return self.phase.value + (f" ({', '.join(rest)})" if rest else "")


_TABLES: dict[str, Mapping[Any, Mapping[_Event, enum.Enum]]] = {
    "phase": PHASES, "load": LOADS, "energy": ENERGIES, "command": COMMANDS}
#: part -> every event its table names
_ALPHABETS = {part: frozenset(e for moves in table.values() for e in moves) for part, table in _TABLES.items()}
_EVENTS = frozenset(e for alphabet in _ALPHABETS.values() for e in alphabet)


def _moves(state: MailState) -> dict[_Event, MailState]:
    """The events ``state`` takes: those every part that names them has a move for, each part moved."""
    moves: dict[_Event, MailState] = {}
    for event in _EVENTS:
        changes: dict[str, Any] = {}
        for part, table in _TABLES.items():
            if event in _ALPHABETS[part]:
                changes[part] = table[getattr(state, part)].get(event)
        if None not in changes.values():
            moves[event] = replace(state, **changes)
    return moves


#: state -> event -> the next state. Every change of state goes through MailPlanner._enter, which
#: raises ProtocolViolation naming the state and the event for one not here.
TRANSITIONS: dict[MailState, dict[_Event, MailState]] = {
    state: _moves(state)
    for state in itertools.starmap(MailState, itertools.product(Phase, Load, Energy, Command))
}


def next_state(state: MailState, event: _Event) -> MailState:
    """Where :data:`TRANSITIONS` says ``event`` leads from ``state`` (ProtocolViolation if nowhere)."""
    return lookup(TRANSITIONS, "mail planner", state, event)
