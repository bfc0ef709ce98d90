"""The one check of a state change against a machine's table (h11's ``_state.py`` style).

Every machine of the stack keeps its transitions in one table and changes state in one method; that method
asks :func:`lookup` (a table of ``state -> event -> target``) or :func:`checked` (a target the machine chose,
against the targets the table allows for the event) for the state to enter, so an illegal change raises one
:class:`ProtocolViolation`, worded alike for every machine, naming the machine, the state and the event.
"""

from __future__ import annotations

import enum
from collections.abc import Container, Mapping
from typing import TypeVar

from drona_gcs.errors import ProtocolViolation

S = TypeVar("S")  #: a machine's state
E = TypeVar("E")  #: what a machine's table is keyed by in a state


def checked(machine: str, state: object, event: object, target: S | None,
            allowed: Container[S] | None = None) -> S:
    """``target``, the state ``event`` leads ``machine`` to from ``state``; ProtocolViolation if the table has
    no move for it (``target`` None) or ``allowed`` (the targets the table's move lists) does not hold it.
    ``event`` None: a change outside any event, which no table allows."""
    if target is None or (allowed is not None and target not in allowed):
        where = "anywhere" if target is None else f"to {_name(target)}"
        happening = "a change outside any event" if event is None else repr(_name(event))
        raise ProtocolViolation(f"{machine}: {happening} in state {_name(state)} cannot lead {where}")
    return target


def lookup(table: Mapping[S, Mapping[E, S]], machine: str, state: S, event: E) -> S:
    """Where ``table`` (state -> event -> target) says ``event`` leads ``machine`` from ``state``."""
    return checked(machine, state, event, table[state].get(event))


def _name(part: object) -> str:
    """How a message names a state, an event or an event type: an enum by its value, a type by its name."""
    if isinstance(part, enum.Enum):
        return str(part.value)
    if isinstance(part, type):
        return part.__name__
    if isinstance(part, tuple):
        return " ".join(_name(p) for p in part)
    return str(part)
