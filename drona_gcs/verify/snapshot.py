"""Copies and keys of the drones' stacks, for the exhaustive search: a copy shares what no move
changes, and a key leaves out what does not decide the future."""

from __future__ import annotations

from collections.abc import Callable, Hashable
from typing import Any, TypeVar

from drona_gcs.stack.drone import DroneStack

_T = TypeVar("_T")


#: Attributes that are the same in every state of a run (shared, immutable or functions).
_STATIC = frozenset({"config", "plan", "distance", "bugs", "peers", "battery", "chargers", "parking"})
_MACHINES = ("clock", "protocol", "executor", "monitor", "mail")


def shallow(machine: _T) -> _T:
    """A copy whose containers are new and whose values (all immutable) are shared."""
    new = object.__new__(type(machine))
    vars(new).update({name: value.copy() if isinstance(value, (dict, list, set)) else value
                      for name, value in vars(machine).items()})
    return new


def clone_stack(stack: DroneStack) -> DroneStack:
    """A copy of ``stack`` whose machines are copied one level deep (see :func:`shallow`)."""
    new = stack.copy()
    for name in _MACHINES:
        setattr(new, name, shallow(getattr(new, name)))
    return new


def key_of_stack(stack: DroneStack) -> Hashable:
    """What of ``stack`` decides its future."""
    # What the stack keeps besides its machines.
    own = (stack.arrival, stack.unreached, stack.asked_clear, stack.stuck, stack.stop_short, stack.threat,
           stack.braked, stack.resting_now, stack.in_touch)
    return (*(_machine_key(getattr(stack, name)) for name in _MACHINES), own)


def _machine_key(machine: object) -> Hashable:
    return tuple(_FREEZE.get(type(value), _as_is)(value) for name, value in vars(machine).items()
                 if name not in _STATIC)


def _as_is(value: Hashable) -> Hashable:
    return value


#: How a machine's mutable attribute enters the key (any other value is immutable, and enters as it is).
_FREEZE: dict[type, Callable[[Any], Hashable]] = {
    dict: lambda value: frozenset(value.items()), set: frozenset, list: tuple,
}
