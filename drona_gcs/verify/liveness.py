"""Monitors (d) and (e): every mail is delivered within a bound, unless the field made it
undeliverable; no battery drops below the safe threshold."""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

from drona_gcs.stack.mail import MailRequest
from drona_gcs.verify.verdicts import Violation
from drona_gcs.workspace import Cell, Workspace

if TYPE_CHECKING:
    from drona_gcs.verify.config import WorldConfig


@dataclass(frozen=True)
class Flier:
    """A drone in service, for (d): where it is, its battery, the level it charges to, and the steps
    each leg flies besides its moves (its lead steps and a plan's first step, as the README says)."""

    cell: Cell
    level: float
    charged: float
    overhead: int = 0


class Reach:
    """Breadth-first distances in one workspace, cached: the liveness monitor asks the same at
    every step."""

    def __init__(self, workspace: Workspace, most: int = 4096) -> None:
        self.workspace, self.most = workspace, most
        self.cache: dict[tuple[Cell, frozenset[Cell]], dict[Cell, int]] = {}

    def distances(self, goal: Cell, walls: frozenset[Cell]) -> dict[Cell, int]:
        key = (goal, walls)
        found = self.cache.get(key)
        if found is None:
            if len(self.cache) >= self.most:
                self.cache.clear()
            found = self.cache[key] = self.workspace.distances_from(goal, walls)
        return found


class DeliveryMonitor:
    """(d) and (e), on the records the monitors keep (see :class:`.monitors.Monitors`)."""

    config: WorldConfig
    settled: set[str]
    carrying: dict[str, MailRequest]
    reach: Reach

    def liveness(self, steps_since_last_request: int, wait_for: Callable[[], str] = lambda: "",
                 blocked: frozenset[Cell] = frozenset(), fleet: Mapping[str, Flier] | None = None,
                 agents_gone: frozenset[str] = frozenset()) -> None:
        """``wait_for`` describes who waits for whom, for the counterexample; ``blocked``: the cells
        vehicles that came down rest on for good; ``fleet``: the drones still in service;
        ``agents_gone``: the drones whose agents crashed and have not restarted."""
        if steps_since_last_request <= self.config.liveness_steps:
            return
        if not self._may_plan_without(agents_gone):
            return  # the rest cannot tell a crash from a partition: nothing is owed until an agent is back
        if fleet is not None:  # a drone that can never fly again is in the way for good
            grounded = {d for d, flier in fleet.items() if self._grounded(flier)}
            blocked = blocked | {fleet[d].cell for d in grounded}
            fleet = {d: flier for d, flier in fleet.items() if d not in grounded}
        missing = sorted(r.id for r in self.config.requests
                         if r.id not in self.settled and self._deliverable(r, blocked, fleet))
        if missing:
            raise Violation("d", f"mail {missing} not delivered {self.config.liveness_steps} steps after the "
                                 f"last request arrived. Wait-for: {wait_for()}")

    def _may_plan_without(self, gone: frozenset[str]) -> bool:
        """The README's quorum: the agents up are a strict majority of the fleet, or half of it with its
        first drone by name (one side of a partition at most)."""
        drones = self.config.drones
        up = len(drones) - len(gone)
        return 2 * up > len(drones) or (2 * up == len(drones) and min(drones) not in gone)

    def _grounded(self, flier: Flier) -> bool:
        """Off every charger, a battery that affords no move (a leg's overhead and one step above the
        safe threshold) never flies again."""
        chargers, battery = self.config.workspace.charging_stations, self.config.battery
        affordable = (flier.level - battery.safe_threshold) / battery.drain_per_step
        return bool(chargers) and flier.cell not in chargers and affordable < flier.overhead + 1

    def _deliverable(self, request: MailRequest, blocked: frozenset[Cell], fleet: Mapping[str, Flier] | None) -> bool:
        """Whether a drone in service can still bring the mail to its drop-off and then reach a charger
        no vehicle down rests on, by the shortest ways around obstacles and the vehicles down, on
        what its battery holds now or once charged at such a charger, by the README's energy rule:
        each leg's overhead, and the battery's margin, kept."""
        if fleet is None:
            return request.dropoff not in blocked and request.pickup not in blocked
        carrier = next((d for d, r in self.carrying.items() if r.id == request.id), None)
        if carrier is not None:
            flier = fleet.get(carrier)
            return flier is not None and request.dropoff not in blocked and self._affords(flier, None, request.dropoff,
                                                                                          blocked)
        if request.pickup in blocked or request.dropoff in blocked:
            return False
        return any(self._affords(flier, request.pickup, request.dropoff, blocked) for flier in fleet.values())

    def _affords(self, flier: Flier, pickup: Cell | None, dropoff: Cell, blocked: frozenset[Cell]) -> bool:
        ws, battery, steps = self.config.workspace, self.config.battery, self._steps(blocked)
        stops = [cell for cell in (pickup, dropoff) if cell is not None]

        def way(start: Cell) -> float:
            return sum(steps(a, b) + flier.overhead for a, b in itertools.pairwise([start, *stops]))

        if not ws.charging_stations:  # no chargers: no energy model
            return way(flier.cell) < math.inf
        chargers = [c for c in ws.charging_stations if c not in blocked]
        home = min((steps(dropoff, c) for c in chargers), default=math.inf) + flier.overhead + battery.margin_steps

        def affordable(level: float) -> float:
            return (level - battery.safe_threshold) / battery.drain_per_step

        if way(flier.cell) + home <= affordable(flier.level):
            return True
        return any(steps(flier.cell, c) + flier.overhead <= affordable(flier.level)
                   and way(c) + home <= affordable(flier.charged) for c in chargers)

    def _steps(self, blocked: frozenset[Cell]) -> Callable[[Cell, Cell], float]:
        def steps(a: Cell, b: Cell) -> float:
            return self._distances(b, blocked).get(a, math.inf)
        return steps

    def _distances(self, goal: Cell, walls: frozenset[Cell]) -> dict[Cell, int]:
        """Moves from every cell to ``goal``, around obstacles and ``walls``."""
        return self.reach.distances(goal, walls)

    # (e)
    def battery(self, drone: str, step: int, level: float) -> None:
        if level < self.config.battery.safe_threshold:
            raise Violation("e", f"{drone}'s battery fell to {level:.1f}% at step {step}, below the safe "
                                 f"threshold {self.config.battery.safe_threshold}%")
