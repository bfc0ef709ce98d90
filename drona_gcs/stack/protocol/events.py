"""What the coordination protocol takes: the events of :data:`Event`, its own and the peers' messages."""

from __future__ import annotations

from dataclasses import dataclass

from drona_gcs.motion import Trajectory
from drona_gcs.stack.messages import (
    CurrentTraj,
    PlanAck,
    PlanDecision,
    PlanProposal,
    PlanRefusal,
    ReqForCurrentTraj,
    Task,
)
from drona_gcs.workspace import Cell


@dataclass(frozen=True)
class NewTask:
    task: Task


@dataclass(frozen=True)
class PlanCompleted:
    """The executor finished the trajectory (the paper's Reset)."""


@dataclass(frozen=True)
class PeerLeft:
    drone: str
    #: the earliest step it may have gone silent at (a lost link is noticed only when its lease
    #: expires); None: now
    silent_since: int | None = None


@dataclass(frozen=True)
class PeerJoined:
    drone: str
    cell: Cell  #: where it is now, as it announced
    trajectory: Trajectory | None = None  #: the plan it announced it is flying, if any

    def announced(self, now: int) -> Trajectory:
        return self.trajectory if self.trajectory is not None else Trajectory.stationary(self.cell, now)


@dataclass(frozen=True)
class VehicleLost:
    """My vehicle stopped answering at step ``since``; it was last seen in ``seen``."""

    since: int
    seen: Cell


@dataclass(frozen=True)
class Relocated:
    """My vehicle is back and seen in ``cell`` (or landed below it): I rest there, with no plan."""

    cell: Cell


@dataclass(frozen=True)
class VehicleDown:
    """My vehicle came down by itself in ``cell`` (a failsafe, a pilot): it stays there for good."""

    cell: Cell


@dataclass(frozen=True)
class PeerDown:
    """``drone`` announced its vehicle came down in ``cell``: it stays there for good."""

    drone: str
    cell: Cell


@dataclass(frozen=True)
class PeerLost:
    """``drone``'s vehicle is lost: it may be in any of ``cells`` for good (none: it is back). ``for_now``:
    late, or its clock off, not lost: held until it says so, but no wall for the task planner."""

    drone: str
    cells: tuple[Cell, ...]
    for_now: bool = False
    seq: tuple[int, int] = (0, 0)  #: ``Holding.seq``: one older than the newest heard from ``drone`` is dropped


@dataclass(frozen=True)
class PeerBraked:
    """``drone`` cut the plan it flies short (:class:`Braked`): ``trajectory`` holds at its end until
    its next plan."""

    drone: str
    trajectory: Trajectory


@dataclass(frozen=True)
class PeerAnnounced:
    """``drone`` announced the plan it flies now, outside any round of mine (see :meth:`CoordinationProtocol.heard`)."""

    drone: str
    trajectory: Trajectory


@dataclass(frozen=True)
class Released:
    """The operator saw ``drone``, gone, out of the air for good (landed, or taken away): no cell is
    held for it any more, until it joins again."""

    drone: str


@dataclass(frozen=True)
class ClockBound:
    """The clock check's verdict: my clock is beyond the fleet's bound (``mine_off``: I hold where my plan
    ends, plan nothing, and every peer holds that for good), or these peers' are (``outliers``)."""

    mine_off: bool
    outliers: frozenset[str] = frozenset()
    #: my vehicle late: the last step it was seen on time. It flies my plan's cells in order, so it is
    #: somewhere on the plan from then on, and all of that is held, not only the rest from now
    on_time_at: int | None = None


@dataclass(frozen=True)
class NextStep:
    """The executor is about to take the boundary after ``now``: a last look at the cell it enters."""


@dataclass(frozen=True)
class Reroute:
    """A new plan to the goal of the one I fly, asked for after :class:`Threatened`."""

    task: Task


@dataclass(frozen=True)
class Brake:
    """No new rest of the plan I fly could be planned clear of the cells held for good on it (after
    :class:`Threatened`): stop short of the first now, not a step before it."""


Event = (NewTask | PlanCompleted | PeerLeft | PeerJoined | ReqForCurrentTraj | CurrentTraj | VehicleLost
         | Relocated | Reroute | Brake | VehicleDown | PeerDown | PeerBraked | PeerAnnounced | Released | NextStep
         | PlanProposal | PlanAck | PlanRefusal | PlanDecision | ClockBound | PeerLost)
