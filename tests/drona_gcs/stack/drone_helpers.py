"""Shared helpers of one drone's whole stack tests (``test_drone*.py``): a lone drone on an open
grid (no peers, so each task plans at once) takes one mail, and the test plays its vehicle.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TypeVar

from drona_gcs.planner import SafePlanner
from drona_gcs.stack.drone import DroneAction, DroneStack, StackConfig
from drona_gcs.stack.mail import MailRequest
from drona_gcs.stack.messages import Message
from drona_gcs.stack.protocol import (
    Broadcast,
    CoordinationProtocol,
    Send,
    State,
)
from drona_gcs.workspace import Cell, Workspace

WS = Workspace.build(size=(6, 6, 1), drones={"d1": (0, 0, 0)})
MAIL = MailRequest("m1", pickup=(3, 0, 0), dropoff=(3, 3, 0), priority=5)
#: How the test's vehicle flies: from the stack and the step, the cell telemetry puts it in (None: none).
Vehicle = Callable[[DroneStack, int], Cell | None]
A = TypeVar("A")


def ideal(stack: DroneStack, step: int) -> Cell | None:
    """Where the last step took it: the executor's cell before the boundary."""
    return stack.executor.cell


def fly(vehicle: Vehicle, steps: int, stack: DroneStack | None = None,
        workspace: Workspace = WS) -> tuple[DroneStack, list[DroneAction]]:
    stack = stack or DroneStack("d1", StackConfig(workspace, SafePlanner(workspace)), dict(workspace.drones))
    if not stack.mail.queue and stack.mail.current is None:
        stack.assign(MAIL)
    actions: list[DroneAction] = []
    for step in range(stack.executor.step + 1, stack.executor.step + 1 + steps):
        actions += stack.step(step, 100.0, vehicle(stack, step))
    return stack, actions


def of(kind: type[A], actions: list[DroneAction]) -> list[A]:
    return [a for a in actions if isinstance(a, kind)]


def state_of(protocol: CoordinationProtocol) -> State:
    """The protocol's state now: read anew after an action (mypy keeps the state an earlier check found)."""
    return protocol.state


def route(stacks: Mapping[str, DroneStack], inbox: list[tuple[str, Message]], sender: str,
          actions: list[DroneAction]) -> None:
    """Put ``sender``'s messages in ``inbox``, as (receiver, message), in the order sent."""
    for action in actions:
        if isinstance(action, Send):
            inbox.append((action.to, action.message))
        elif isinstance(action, Broadcast):
            inbox.extend((d, action.message) for d in stacks if d != sender)


def drain(stacks: Mapping[str, DroneStack], inbox: list[tuple[str, Message]],
          done: dict[str, list[DroneAction]]) -> None:
    """Hand every message in ``inbox`` to its receiver, and the messages that sends in turn, until none is
    left (every one arrives at once); what each drone does goes in ``done``."""
    while inbox:
        to, message = inbox.pop(0)
        answered = stacks[to].receive(message)
        done[to] += answered
        route(stacks, inbox, to, answered)
