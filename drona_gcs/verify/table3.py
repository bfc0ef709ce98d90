"""The paper's Table 3: how deep exhaustive search gets for 2, 4 and 8 drones on 8x8, 16x16 and
32x32 grids, within a time budget per cell.

Each cell is the scenario ``drona verify --strategy dfs`` runs by default for that fleet and
grid, with one mail request per drone: Delta 1, messages delivered within the step they were
sent in (``max_delay`` 0), obstacles 0.2, the field's faults unless told otherwise.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

from drona_gcs.errors import DronaError
from drona_gcs.verify.dfs import ALL, DEEPEN, Reductions
from drona_gcs.verify.explore import Explorer, Outcome, Scenario

DRONES = (2, 4, 8)
GRIDS = (8, 16, 32)


@dataclass(frozen=True)
class Row:
    scenario: Scenario
    outcome: Outcome
    refused: str | None = None  #: why the scenario could not be built (then the outcome is empty)

    @property
    def grid(self) -> str:
        w, h, _ = self.scenario.grid
        return f"{w}x{h}"


def scenarios(seed: int = 0, faults: bool = True) -> Iterator[Scenario]:
    for grid in GRIDS:
        for drones in DRONES:
            yield Scenario(drones=drones, requests=drones, delta=1, seed=seed, grid=(grid, grid, 1),
                           max_delay=0, faults=faults)


def run_table(cells: Iterator[Scenario], max_depth: int, stop_after: Callable[[], Callable[[], bool]],
              on_row: Callable[[Row], None] = lambda row: None, deepen: int = DEEPEN,
              reductions: Reductions = ALL) -> list[Row]:
    """Each cell searched until its own ``stop_after()`` says so, or to ``max_depth``."""
    rows = []
    for scenario in cells:
        try:
            explorer = Explorer(scenario)
        except DronaError as exc:
            row = Row(scenario, Outcome(), str(exc))
        else:
            row = Row(scenario, explorer.exhaustive(max_depth, stop_after(), deepen=deepen, reductions=reductions))
        on_row(row)
        rows.append(row)
    return rows
