"""What the coordination protocol asks of the drone: the actions of :data:`Action`."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from drona_gcs.motion import Trajectory
from drona_gcs.stack.messages import Message, Task
from drona_gcs.workspace import Cell


@dataclass(frozen=True)
class Send:
    to: str
    message: Message


@dataclass(frozen=True)
class Broadcast:
    message: Message


@dataclass(frozen=True)
class StartExecuting:
    task: Task
    trajectory: Trajectory
    psi: Mapping[str, Trajectory]  #: what the plan avoided, for the consistency monitor


@dataclass(frozen=True)
class TaskFailed:
    task: Task
    reason: str
    cut_off: bool = False  #: no path at all joins start and goal (see GoalCutOff)


@dataclass(frozen=True)
class Threatened:
    """The rest of the plan I fly crosses cells a departed drone may hold for good: the task
    planner should ask for a new plan to the same goal (:class:`Reroute`)."""

    departed: str  #: the peer that left, or whose vehicle came down
    cells: tuple[Cell, ...]  #: the cells of my plan it may hold


@dataclass(frozen=True)
class RerouteFailed:
    """No new plan avoids the departed drone: I fly the plan I have (what else is there)."""

    task: Task
    reason: str


@dataclass(frozen=True)
class Grounded:
    """Tell every peer my vehicle came down: it stays in ``trajectory.last`` for good."""

    trajectory: Trajectory


@dataclass(frozen=True)
class Braked:
    """I cut my plan short of a cell held for good (a vehicle down's, a departed drone's): ``trajectory``
    is what I fly now, holding at its end; every peer is told as of a new plan."""

    trajectory: Trajectory
    held: Cell  #: the cell it stops short of


@dataclass(frozen=True)
class Holding:
    """Tell every peer the cells my vehicle may be in, for good: it is lost, late, or my clock is off (none: it
    is back, see ``Relocated``, or on time again)."""

    cells: tuple[Cell, ...]
    #: late, or my clock off (not lost): held until I say so, but no wall a way to mail must go around
    for_now: bool = False
    #: which of my holds this is, (incarnation, count): a later one replaces an earlier, never the reverse
    #: (news reorders)
    seq: tuple[int, int] = (0, 0)


@dataclass(frozen=True)
class Present:
    """Tell ``to``, which joined (again), what I fly now: news of me it missed while apart (a brake, a new
    plan) would otherwise be lost for good. ``braked``: a plan I cut short, announced as any brake."""

    to: str
    trajectory: Trajectory
    braked: bool


Action = (Send | Broadcast | StartExecuting | TaskFailed | Threatened | RerouteFailed | Grounded | Braked | Holding
          | Present)
