"""What the mail planner takes and says: mail requests, the rules on their cells, its actions and its budget
(see :mod:`drona_gcs.stack.mail`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from drona_gcs.errors import ProblemError
from drona_gcs.stack.mail_table import Phase
from drona_gcs.workspace import Cell, Workspace

#: distance(a, b): steps of the shortest static path from a to b (NO_WAY if none).
Distance = Callable[[Cell, Cell], int]
NO_WAY = 10**6  #: the distance between cells no path joins (a vehicle down may wall a drone in for good)
MAX_MISSES = 3  #: plans to a pickup that end with the vehicle not there, before the mail is handed back
#: Why a drone whose battery is low flies no mail, where no charger can fill it up again.
SPENT = "its battery is low, and the workspace has no charger"
DRAINED = "its battery affords no move above the floor, and it rests off every charger"
STRANDED = ("its battery is low, and reaches no charger from here (the others are walled in by obstacles, "
            "vehicles down or lost, or drones whose clock is off)")
MAX_FAILURES = 4  #: rounds in a row that find no plan, before mail not on board is handed back (see leg_failed)
MAX_STRIKES = 8  #: legs to a mail's pickup that found no plan, in a row or not, before it is handed back
NOT_CLEARED = "at the pickup, not cleared by the service to take it on board"


def mail_cell_problem(workspace: Workspace, cell: Cell) -> tuple[str, str] | None:
    """Why ``cell`` cannot be a pickup or drop-off, as ``(kind, message)``; None if it can.

    Besides the grid's rules: never a charging station or parking cell, where a drone may
    rest for good (its goal would be another drone's resting cell). One rule, used by the
    agents that take mail and by the service that accepts it.
    """
    if not workspace.in_bounds(cell):
        return "out_of_bounds", f"cell {list(cell)} is outside the grid {list(workspace.size)}"
    if cell in workspace.obstacles:
        return "obstacle", f"cell {list(cell)} is on an obstacle"
    if cell not in workspace.main_region:
        return "unreachable", f"cell {list(cell)} is walled off from the main free region: no drone can reach it"
    if cell in workspace.charging_stations or cell in workspace.parking:
        return "rest_spot", f"cell {list(cell)} is a charging station or parking cell, where drones rest"
    return None


@dataclass(frozen=True)
class MailRequest:
    id: str
    pickup: Cell
    dropoff: Cell
    priority: int  #: 0..9, 9 the most urgent
    seq: int = 0  #: arrival order; lower is older

    def __post_init__(self) -> None:
        if not 0 <= self.priority <= 9:
            raise ProblemError(f"mail {self.id}: priority must be within 0..9, got {self.priority}")
        if self.pickup == self.dropoff:
            raise ProblemError(f"mail {self.id}: pickup and drop-off are the same cell {list(self.pickup)}")

    @property
    def rank(self) -> tuple[int, int]:
        """Sort key: most urgent first, then oldest."""
        return (-self.priority, self.seq)


# --------------------------------------------------------------- actions
@dataclass(frozen=True)
class GoTo:
    """Ask the coordination protocol for a motion task; the battery affords ``flight_steps``."""

    goal: Cell
    flight_steps: int | None
    purpose: Phase


@dataclass(frozen=True)
class MailStarted:
    request: MailRequest
    waiting: tuple[MailRequest, ...]  #: the rest of the queue at that moment (for the order monitor)


@dataclass(frozen=True)
class MailPickedUp:
    request: MailRequest


@dataclass(frozen=True)
class MailDelivered:
    request: MailRequest


@dataclass(frozen=True)
class MailRejected:
    """A mail this drone will not fly: handed back to whoever assigned it. ``handed_back``: the mail
    is fine, the drone is not (its vehicle lost, down, late): another drone may fly it."""

    request: MailRequest
    reason: str
    handed_back: bool = False


@dataclass(frozen=True)
class MailLost:
    """A mail on board a vehicle that came down by itself: it is wherever the vehicle is."""

    request: MailRequest
    reason: str


MailProgress = MailStarted | MailPickedUp | MailDelivered | MailRejected | MailLost  #: what a dispatcher is told
MailAction = GoTo | MailProgress


@dataclass(frozen=True)
class Budget:
    """What the battery affords from step ``now``: ``steps`` of flight before the safe threshold."""

    now: int
    steps: int
    unchecked: bool = False  #: no energy model (no chargers): every leg is allowed

    def allows(self, steps: int) -> bool:
        return self.unchecked or steps <= self.steps

    def flight(self, reserve: int) -> int | None:
        """The steps of flight a leg may take and still leave ``reserve`` steps."""
        return None if self.unchecked else self.steps - reserve
