"""Exploring schedules of a simulated fleet: random walks, PCT, and exhaustive search (see :mod:`.dfs`).

A schedule is the list of choices made at each transition: the index of the
transition taken among :meth:`World.enabled`, which lists them in a fixed
order. Replaying the choices from the scenario's initial state reproduces the
run exactly, so a violation comes with a *replay token*: the scenario and the
choices, compressed. Clocks stay at the edge: the caller passes ``stop()``,
which says when the time is up, and ``progress()``, which is told how far
the search has come.
"""

from __future__ import annotations

import base64
import enum
import json
import random
import zlib
from collections.abc import Callable, Hashable
from dataclasses import asdict, dataclass, field, replace

from drona_gcs.errors import DronaError, ProblemError, ProtocolViolation
from drona_gcs.planner import SafePlanner
from drona_gcs.verify.dfs import ALL, DEEPEN, Reductions, search
from drona_gcs.verify.monitors import Violation
from drona_gcs.verify.mutants import SEEDED_BUGS, planner_delta
from drona_gcs.verify.world import Faults, World, WorldConfig, make_world_config, tester_workspace
from drona_gcs.workspace import Workspace
from drona_gcs.workspace_files import load_workspace


class Strategy(enum.Enum):
    RANDOM = "random"  #: uniform random walks, one seed per schedule
    PCT = "pct"  #: probabilistic concurrency testing: random priorities with d change points
    DFS = "dfs"  #: depth-first over every schedule to a depth bound, with state caching


@dataclass(frozen=True)
class Scenario:
    """Everything that fixes the initial state: what a replay token carries besides the choices."""

    drones: int = 4
    requests: int = 6
    delta: int = 1
    seed: int = 0
    grid: tuple[int, int, int] = (8, 8, 1)
    obstacles: float = 0.2
    workspace_path: str | None = None
    bugs: tuple[str, ...] = ()
    max_delay: int = 2  #: steps of the sender's clock within which a message arrives
    faults: bool = True  #: the field's faults (duplicates, a cancel, a vehicle down) and a mixed fleet
    crashes: int = 0  #: agents that crash, and may restart (see Faults.crashes)
    partitions: int = 0  #: drones cut off from the rest for a while (see Faults.partitions)
    skews: int = 0  #: clocks that go beyond the fleet's bound (see Faults.skews)

    def __post_init__(self) -> None:
        unknown = sorted(set(self.bugs) - set(SEEDED_BUGS))
        if unknown:
            raise ProblemError(f"unknown seeded bug(s) {unknown}; known: {sorted(SEEDED_BUGS)}")
        if (self.drones < 1 or self.requests < 0 or self.delta < 0 or self.max_delay < 0 or self.crashes < 0
                or self.partitions < 0 or self.skews < 0):
            raise ProblemError("drones must be >= 1, and requests, delta, max_delay, crashes, partitions and skews "
                               ">= 0")
        if self.skews and (self.crashes or self.partitions):
            raise ProblemError("skews do not combine with crashes or partitions: the model's clock check "
                               "hears every drone")
        if any(n < 1 for n in self.grid) or not 0 <= self.obstacles < 0.9:
            raise ProblemError("grid sizes must be >= 1 and obstacles within [0, 0.9)")

    def workspace(self) -> Workspace:
        if self.workspace_path is not None:
            return load_workspace(self.workspace_path)
        w, h, layers = self.grid
        return tester_workspace(w, h, layers, self.obstacles, self.seed, self.drones)

    def world_config(self, workspace: Workspace) -> WorldConfig:
        field_faults = replace(Faults() if self.faults else Faults.none(), crashes=self.crashes,
                               partitions=self.partitions, skews=self.skews)
        faults: dict[str, object] = {"faults": field_faults} if self.faults else {"faults": field_faults,
                                                                                    "mixed": False}
        return make_world_config(workspace, self.drones, self.requests, self.delta, self.seed,
                                 frozenset(self.bugs), max_delay=self.max_delay, **faults)


@dataclass
class Outcome:
    """What exploring found: a violation with its schedule, or nothing."""

    schedules: int = 0
    transitions: int = 0
    states: int = 0  #: distinct states seen (DFS) or transitions taken (walks)
    violation: Violation | None = None
    choices: list[int] = field(default_factory=list)
    trace: list[str] = field(default_factory=list)
    exhausted: bool = False  #: DFS: every schedule to the depth bound was covered
    complete_depth: int = 0  #: DFS: every schedule to this depth was explored (the paper's Table 3 figure)
    complete_states: int = 0  #: DFS: distinct states within ``complete_depth``


class Explorer:
    """Runs schedules of one scenario; the planner is built once and shared by every world."""

    def __init__(self, scenario: Scenario) -> None:
        self.scenario = scenario
        self.workspace = scenario.workspace()
        self.config = scenario.world_config(self.workspace)
        self.planner = SafePlanner(self.workspace, delta=planner_delta(scenario.delta, scenario.bugs))

    def world(self) -> World:
        return World(self.config, self.planner)

    # ------------------------------------------------------------- runs
    def run(self, strategy: Strategy, schedules: int, max_depth: int, seed: int,
            stop: Callable[[], bool] = lambda: False,
            progress: Callable[[Outcome], None] = lambda o: None) -> Outcome:
        if strategy is Strategy.DFS:
            return self._dfs(max_depth, stop, progress)
        outcome = Outcome()
        for i in range(schedules):
            if stop():
                break
            rng = random.Random(f"{seed}-{i}")
            chooser = _pct_chooser(rng, max_depth) if strategy is Strategy.PCT else _uniform(rng)
            self._walk(chooser, max_depth, outcome)
            outcome.schedules += 1
            progress(outcome)
            if outcome.violation is not None:
                break
        return outcome

    def shrink(self, found: Outcome, strategy: Strategy, seed: int, stop: Callable[[], bool]) -> Outcome:
        """Look for a shorter schedule that breaks the same monitor, until ``stop()``: short
        traces are the ones people read. Random walks, each cut at the best length so far."""
        if found.violation is None or strategy is Strategy.DFS:
            return found
        best, i = found, 0
        while not stop() and len(best.choices) > 1:
            i += 1
            trial = Outcome()
            self._walk(_uniform(random.Random(f"shrink-{seed}-{i}")), len(best.choices) - 1, trial)
            if trial.violation is not None and trial.violation.monitor == found.violation.monitor:
                best = trial
        best.schedules, best.transitions, best.states = found.schedules, found.transitions, found.states
        return best

    def replay(self, choices: list[int]) -> Outcome:
        """Run exactly these choices (from a token); the outcome holds the trace. ProblemError if a
        choice is not a move of the world then (a token from another version of the model)."""
        outcome = Outcome(schedules=1)
        it = iter(choices)

        def chosen(moves: list[Hashable], depth: int) -> int:
            pick = next(it)
            if not 0 <= pick < len(moves):
                raise ProblemError(f"replay token: choice {depth + 1} is move {pick + 1}, but only {len(moves)} "
                                   "can be made there (a token from another version of the tester?)")
            return pick

        self._walk(chosen, len(choices), outcome)
        return outcome

    def _walk(self, choose: Callable[[list[Hashable], int], int], max_depth: int, outcome: Outcome) -> None:
        world, choices = self.world(), []
        try:
            for depth in range(max_depth):
                if world.finished:
                    break
                moves = world.enabled()
                pick = choose([world.actor(m) for m in moves], depth)
                choices.append(pick)
                world.apply(moves[pick])
                outcome.transitions += 1
                outcome.states += 1
        except (Violation, ProtocolViolation) as exc:
            outcome.violation = exc if isinstance(exc, Violation) else Violation("crash", str(exc))
            outcome.choices, outcome.trace = choices, world.trace

    def _dfs(self, max_depth: int, stop: Callable[[], bool], progress: Callable[[Outcome], None]) -> Outcome:
        return self.exhaustive(max_depth, stop, progress)

    def exhaustive(self, max_depth: int, stop: Callable[[], bool] = lambda: False,
                   progress: Callable[[Outcome], None] = lambda o: None, deepen: int = DEEPEN,
                   reductions: Reductions = ALL) -> Outcome:
        """Every schedule to ``max_depth``, by iterative deepening (see :mod:`.dfs`): the outcome's
        ``complete_depth`` is the greatest depth whose every schedule was explored."""
        return search(self.world, lambda choices: self.replay(choices).trace, max_depth, Outcome(), stop,
                      progress, deepen, reductions)


def _uniform(rng: random.Random) -> Callable[[list[Hashable], int], int]:
    """A random walk: every enabled transition equally likely."""
    return lambda actors, depth: rng.randrange(len(actors))


def _pct_chooser(rng: random.Random, max_depth: int,
                 change_points: int = 3) -> Callable[[list[Hashable], int], int]:
    """PCT (Burckhardt et al. 2010): every actor gets a random priority; the highest enabled one
    runs; at ``change_points`` random depths the running actor drops to the lowest priority."""
    priorities: dict[Hashable, float] = {}
    changes = set(rng.sample(range(max(1, max_depth)), min(change_points, max(1, max_depth))))
    low = [0.0]

    def choose(actors: list[Hashable], depth: int) -> int:
        ranked = []
        for i, who in enumerate(actors):
            if who not in priorities:
                priorities[who] = rng.random() + 1.0
            ranked.append((priorities[who], i))
        _, best = max(ranked)
        if depth in changes:
            low[0] -= 1.0
            priorities[actors[best]] = low[0]
        return best

    return choose


# ------------------------------------------------------------- tokens
def encode_token(scenario: Scenario, choices: list[int]) -> str:
    payload = {"v": 1, "scenario": asdict(scenario), "choices": choices}
    raw = zlib.compress(json.dumps(payload, separators=(",", ":")).encode(), 9)
    return base64.urlsafe_b64encode(raw).decode().rstrip("=")


def decode_token(token: str) -> tuple[Scenario, list[int]]:
    try:
        raw = zlib.decompress(base64.urlsafe_b64decode(token + "=" * (-len(token) % 4)))
        payload = json.loads(raw)
        fields = payload["scenario"]
        fields["grid"] = tuple(fields["grid"])
        fields["bugs"] = tuple(fields["bugs"])
        return Scenario(**fields), [int(c) for c in payload["choices"]]
    except (ValueError, KeyError, TypeError, zlib.error) as exc:
        raise DronaError(f"not a replay token from drona verify: {exc}") from exc
