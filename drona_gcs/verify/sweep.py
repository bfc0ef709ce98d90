"""A sweep of the tester over configurations nobody picked by hand.

:func:`configurations` draws them from a seed, uniformly over the ranges the
stack must hold in (fleet size, requests, Delta, grid, obstacles, strategy,
scenario seed): the same seed gives the same sweep anywhere, and a new seed
gives configurations nobody has tuned for. :func:`run_sweep` runs each for a
caller-given time (the clock stays at the edge: ``stop_after(seconds)`` makes
the stop predicate) and returns one :class:`SweepRow` per run.
"""

from __future__ import annotations

import random
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from drona_gcs.errors import ProblemError
from drona_gcs.verify.explore import Explorer, Outcome, Scenario, Strategy, encode_token

DRONES = range(2, 7)
REQUESTS = range(2, 11)
DELTAS = range(0, 3)
GRIDS = ((8, 8, 1), (16, 16, 1))
OBSTACLES = (0.0, 0.2)
STRATEGIES = (Strategy.RANDOM, Strategy.PCT)
DRAWS_PER_CONFIGURATION = 100  #: a sweep gives up drawing a valid configuration after this many tries each


@dataclass(frozen=True)
class Configuration:
    scenario: Scenario
    strategy: Strategy

    def __str__(self) -> str:
        s = self.scenario
        w, h, _ = s.grid
        crashes = f", {s.crashes} crash(es)" if s.crashes else ""
        partitions = f", {s.partitions} partition(s)" if s.partitions else ""
        skews = f", {s.skews} clock(s) off" if s.skews else ""
        delay = f", messages within {s.max_delay} steps" if s.max_delay != Scenario.max_delay else ""
        bugs = f", bugs {', '.join(s.bugs)}" if s.bugs else ""
        return (f"{s.drones} drones, {s.requests} requests, delta {s.delta}, {w}x{h} obstacles {s.obstacles:g}, "
                f"{self.strategy.value}, seed {s.seed}{crashes}{partitions}{skews}{delay}{bugs}")


@dataclass(frozen=True)
class SweepRow:
    configuration: Configuration
    outcome: Outcome
    token: str | None  #: the replay token of a violation

    @property
    def clean(self) -> bool:
        return self.outcome.violation is None


def configurations(seed: int, count: int, faults: bool = True, crashes: int = 0, partitions: int = 0,
                   skews: int = 0, max_delay: int = Scenario.max_delay,
                   bugs: tuple[str, ...] = ()) -> Iterator[Configuration]:
    """``count`` configurations drawn from ``seed``: uniform over every range above; ``crashes``
    agents may crash and restart in each, ``partitions`` times a drone may be cut off, ``skews``
    clocks may go beyond the fleet's bound, each message arrives within ``max_delay`` steps, and
    ``bugs`` are planted in each (does the sweep find them?). A draw no
    mail can be given in (obstacles leave no pickup a charged drone can fly) is drawn again: it is no
    fleet the stack must serve, and it ended the whole sweep."""
    rng = random.Random(f"sweep-{seed}")
    made = 0
    for _ in range(count * DRAWS_PER_CONFIGURATION):
        if made == count:
            return
        scenario = Scenario(drones=rng.choice(DRONES), requests=rng.choice(REQUESTS), delta=rng.choice(DELTAS),
                            seed=rng.randrange(1_000_000), grid=rng.choice(GRIDS), obstacles=rng.choice(OBSTACLES),
                            faults=faults, crashes=crashes, partitions=partitions, skews=skews,
                            max_delay=max_delay, bugs=bugs)
        strategy = rng.choice(STRATEGIES)
        try:
            scenario.world_config(scenario.workspace())
        except ProblemError:
            continue
        made += 1
        yield Configuration(scenario, strategy)
    if made < count:
        raise ProblemError(f"sweep seed {seed}: {made} of {count} configurations drawn in "
                           f"{count * DRAWS_PER_CONFIGURATION} draws")


def run_sweep(configs: Iterator[Configuration], schedules: int, max_depth: int,
              stop_after: Callable[[], Callable[[], bool]],
              on_row: Callable[[SweepRow], None] = lambda row: None) -> list[SweepRow]:
    """Each configuration explored until its own ``stop_after()`` says so (or ``schedules`` are run)."""
    rows = []
    for config in configs:
        outcome = Explorer(config.scenario).run(config.strategy, schedules, max_depth, config.scenario.seed,
                                                stop=stop_after())
        token = None if outcome.violation is None else encode_token(config.scenario, outcome.choices)
        row = SweepRow(config, outcome, token)
        on_row(row)
        rows.append(row)
    return rows
