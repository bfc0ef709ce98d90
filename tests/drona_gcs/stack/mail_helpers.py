"""Shared helpers of the priority mail task planner tests (``test_mail_*.py``).

Most tests use a 10 x 10 plane with Manhattan distances (cells written (x, y)):
chargers at the corners (0, 0) and (9, 0), parking cells at (0, 9) and (5, 9).
The default battery drains 1 % a step down to a 20 % floor, so a level of
``L`` affords ``L - 20`` steps.
"""

from __future__ import annotations

from drona_gcs.stack.battery import BatteryModel
from drona_gcs.stack.mail import (
    GoTo,
    MailAction,
    MailPlanner,
    MailRequest,
)
from drona_gcs.workspace import Cell


def c(x: int, y: int) -> Cell:
    return (x, y, 0)


def manhattan(a: Cell, b: Cell) -> int:
    return sum(abs(p - q) for p, q in zip(a, b, strict=True))


Q1, Q2 = c(0, 0), c(9, 0)  # chargers
P1, P2 = c(0, 9), c(5, 9)  # parking
MODEL = BatteryModel()  # drain 1, floor 20, margin 8


def planner(at: Cell = P1) -> MailPlanner:
    return MailPlanner(at, (Q1, Q2), (P1, P2), manhattan, MODEL)


def mail(name: str, pickup: Cell, dropoff: Cell, priority: int = 5, seq: int = 0) -> MailRequest:
    return MailRequest(name, pickup, dropoff, priority, seq)


def goto(actions: list[MailAction]) -> GoTo:
    found = [a for a in actions if isinstance(a, GoTo)]
    assert len(found) == 1, actions
    return found[0]


def request_of(action: MailAction) -> MailRequest:
    """The mail a progress report is about (a GoTo is about none)."""
    assert not isinstance(action, GoTo), action
    return action.request
