"""What a search returns, shared by the space-time A* (:mod:`.astar`) and SIPP (:mod:`.sipp`)."""

from __future__ import annotations

from dataclasses import dataclass

from drona_gcs.errors import DronaError
from drona_gcs.motion import Primitive, Trajectory


class BudgetExceeded(DronaError):
    """Internal: the search used its expansion budget (not an error of the plan)."""


@dataclass(frozen=True)
class SearchStats:
    expansions: int
    generated: int


@dataclass(frozen=True)
class SearchResult:
    trajectory: Trajectory
    primitives: tuple[Primitive, ...]
    cost: float
    stats: SearchStats
