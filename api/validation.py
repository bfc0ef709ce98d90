"""Checks of a mail request against the workspace and the drones' energy rules.

A pickup or drop-off must be in the grid, free, in the main free region (or no
drone can reach it) and not a charging station or parking cell (the drones' own rule,
:func:`drona_gcs.stack.mail.mail_cell_problem`). Then the energy rule: the request is refused when no drone
with a charged battery could fly it. That verdict is the drones' own: a
:class:`drona_gcs.stack.mail.MailPlanner` at a charging station, with the battery
at the level where charging ends, is given the mail and asked to decide; it
either starts the mail, goes to charge first at a station from which it can fly
it, or rejects it (``MailRejected``), exactly as an agent would. Distances are the
workspace's static shortest paths, computed as the drones compute them.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

from drona_gcs.planner.grid import GridIndex
from drona_gcs.planner.heuristic import UNREACHABLE, DistanceGraph, GoalDistance
from drona_gcs.stack.battery import BatteryModel
from drona_gcs.stack.drone import default_lead_steps, leg_overhead
from drona_gcs.stack.mail import MailPlanner, MailRejected, MailRequest, mail_cell_problem
from drona_gcs.workspace import Cell, Workspace

#: What a distance is when there is no path (as the drones' own distance function).
NO_PATH = 10**6


@dataclass(frozen=True)
class Problem:
    """One thing wrong with a request: the field (``pickup``, ``dropoff``) and the reason."""

    field: str
    message: str
    kind: str  #: a short machine-readable code: out_of_bounds, obstacle, unreachable, rest_spot, same_cell, energy


class MailChecker:
    def __init__(self, workspace: Workspace, battery: BatteryModel | None = None,
                 lead_steps: int | None = None) -> None:
        """The drones' energy rule, with their defaults unless ``battery`` and ``lead_steps`` are given."""
        self.ws = workspace
        self.battery = battery or BatteryModel.for_period(workspace.tau_s)
        self.leg_overhead = leg_overhead(lead_steps if lead_steps is not None else default_lead_steps(workspace))
        # The drones' own distances: one breadth-first search in C per goal (drona_gcs.planner.heuristic).
        self._graph = DistanceGraph(GridIndex.build(workspace))
        self._to = lru_cache(maxsize=4096)(self._distances_to)
        self.verdict = lru_cache(maxsize=65536)(self._verdict)

    def distance(self, a: Cell, b: Cell) -> int:
        """Static shortest-path steps from ``a`` to ``b`` (:data:`NO_PATH` if none)."""
        d = self._to(b).get(self.ws.cell_id(a))
        return int(d) if d < UNREACHABLE else NO_PATH

    def path(self, a: Cell, b: Cell) -> list[Cell]:
        """The cells of a shortest static path from ``a`` to ``b`` (both included; empty if none)."""
        ids = self._to(b).tree_path(self.ws.cell_id(a)) or []
        return [self.ws.cell_of_id(i) for i in ids]

    def _distances_to(self, goal: Cell) -> GoalDistance:
        return self._graph.distances(self.ws.cell_id(goal), frozenset())

    def check(self, pickup: Cell, dropoff: Cell) -> list[Problem]:
        """Every problem of the request, or none."""
        problems = [p for name, cell in (("pickup", pickup), ("dropoff", dropoff))
                    if (p := self.check_cell(name, cell)) is not None]
        if problems:
            return problems
        if pickup == dropoff:
            return [Problem("dropoff", f"is the pickup cell {list(pickup)}: they must differ", "same_cell")]
        energy = self.verdict(pickup, dropoff)
        return [energy] if energy is not None else []

    def check_cell(self, name: str, cell: Cell) -> Problem | None:
        found = mail_cell_problem(self.ws, cell)
        return Problem(name, found[1], found[0]) if found is not None else None

    def _verdict(self, pickup: Cell, dropoff: Cell) -> Problem | None:
        chargers = self.ws.charging_stations
        if not chargers:
            return None  # no chargers: the drones do not budget energy
        planner = MailPlanner(chargers[0], chargers, self.ws.parking, self.distance, self.battery,
                              leg_overhead=self.leg_overhead)
        planner.assign(MailRequest("check", pickup, dropoff, 0))
        rejected = [a for a in planner.decide(0, planner.recharged_level, ()) if isinstance(a, MailRejected)]
        if not rejected:
            return None
        field = "pickup" if self._pickup_alone_too_far(pickup, planner) else "dropoff"
        return Problem(field, f"no drone with a charged battery can fly pickup {list(pickup)} -> drop-off "
                              f"{list(dropoff)} and get back to a charger: {rejected[0].reason}", "energy")

    def _pickup_alone_too_far(self, pickup: Cell, planner: MailPlanner) -> bool:
        """Whether even charger -> pickup -> charger is beyond a charged battery (then the pickup is to blame)."""
        full = self.battery.steps_affordable(planner.recharged_level)
        ways = sorted(self.distance(pickup, c) for c in self.ws.charging_stations)
        return ways[0] + ways[min(1, len(ways) - 1)] + 2 * self.leg_overhead + self.battery.margin_steps > full
