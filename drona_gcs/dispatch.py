"""Which drone should take a mail: the fleet-level choice made by whoever hands out mail.

Each drone's task planner orders its own queue (priority, then age); this
only picks the drone. It prefers a healthy drone, then the one with the
least mail in hand, then an idle one, then the one nearest the pickup, then
the smaller name (so the choice is deterministic). ``drona mail`` and the
service's dispatcher both choose with it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

from drona_gcs.workspace import Cell

Distance = Callable[[Cell, Cell], int]


@dataclass(frozen=True)
class Candidate:
    drone: str
    cell: Cell
    held: int  #: mail queued, current or on board
    busy: bool  #: flying or coordinating a plan
    healthy: bool = True  #: no alarm (clock skew, vehicle, lag)


def manhattan(a: Cell, b: Cell) -> int:
    return sum(abs(p - q) for p, q in zip(a, b, strict=True))


def choose_drone(candidates: Sequence[Candidate], pickup: Cell, distance: Distance = manhattan) -> str | None:
    """The drone to give a mail picked up at ``pickup``; None if there is none."""
    ranked = rank_drones(candidates, pickup, distance)
    return ranked[0] if ranked else None


def rank_drones(candidates: Sequence[Candidate], pickup: Cell, distance: Distance = manhattan) -> list[str]:
    """Every candidate, the one to give the mail first: whoever offers it goes down the list while the
    drones refuse (an alarm may be about a peer, and a drone may take no mail for a reason of its own)."""
    ranked = sorted(candidates, key=lambda c: (not c.healthy, c.held, c.busy, distance(c.cell, pickup), c.drone))
    return [c.drone for c in ranked]
