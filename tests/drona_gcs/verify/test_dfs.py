"""The exhaustive search: its reductions lose nothing the plain search finds, and it says how deep it got."""

from __future__ import annotations

import contextlib
import itertools
import random
from collections.abc import Callable, Iterator

import pytest

from drona_gcs.errors import ProtocolViolation
from drona_gcs.verify.dfs import Reductions
from drona_gcs.verify.explore import Explorer, Scenario
from drona_gcs.verify.monitors import Violation
from drona_gcs.verify.por import effect_of, independent
from drona_gcs.verify.world import World

#: Scenarios, each with the bound both searches go to (10,000 states or more each): a third drone and the
#: field's faults (duplicates, vehicles down) multiply the schedules, so those go less deep.
SEARCHED = [
    (Scenario(drones=2, requests=2, delta=1, seed=0, max_delay=0, faults=False), 10),
    (Scenario(drones=3, requests=2, delta=1, seed=4, max_delay=0, faults=False), 9),
    (Scenario(drones=2, requests=1, delta=1, seed=1, max_delay=0), 7),
    (Scenario(drones=2, requests=1, delta=1, seed=5, max_delay=1), 7),
    (Scenario(drones=2, requests=2, delta=0, seed=2, max_delay=0, faults=False), 10),
]
SMALL = [scenario for scenario, _ in SEARCHED]


def _after_calls(n: int) -> Callable[[], bool]:
    """A stop predicate that says stop on its n-th call: a time limit that is the same on any machine."""
    calls = itertools.count(1)
    return lambda: next(calls) >= n


@pytest.mark.parametrize(("scenario", "depth"), SEARCHED,
                         ids=[f"{s.drones}d-seed{s.seed}-faults{int(s.faults)}-delay{s.max_delay}" for s in SMALL])
def test_reduced_and_plain_search_agree(scenario: Scenario, depth: int) -> None:
    explorer = Explorer(scenario)
    plain = explorer.exhaustive(depth, deepen=depth, reductions=Reductions.none())
    reduced = explorer.exhaustive(depth, deepen=depth)
    assert (plain.violation is None) == (reduced.violation is None), (plain.violation, reduced.violation)
    if plain.violation is None:
        assert plain.exhausted and reduced.exhausted and reduced.complete_depth == plain.complete_depth == depth
        # Sleep sets prune moves, never states: both saw every state within the bound.
        assert reduced.states == plain.states
        assert reduced.transitions < plain.transitions


def test_a_seeded_bug_is_still_found_by_the_reduced_search() -> None:
    scenario = Scenario(drones=2, requests=2, delta=1, seed=0, max_delay=0, faults=False,
                        bugs=("answer-while-coordinating",))
    explorer = Explorer(scenario)
    outcome = explorer.exhaustive(40)
    assert outcome.violation is not None and outcome.violation.monitor in {"a", "b"}
    assert outcome.complete_depth < len(outcome.choices) <= 40
    assert explorer.replay(outcome.choices).trace == outcome.trace


def test_iterative_deepening_reports_the_depth_it_completed() -> None:
    explorer = Explorer(Scenario(drones=2, requests=2, delta=1, seed=0, max_delay=0, faults=False))
    full = explorer.exhaustive(30, deepen=10)
    assert full.exhausted and full.complete_depth == 30 and full.violation is None
    assert explorer.exhaustive(30, deepen=30).complete_states == full.complete_states
    # Stopped in the middle of the bound 20 search (after the bounds 2, 4, 8, 10 of both): every
    # schedule to 10 was explored, not to 20.
    calls = itertools.count()
    ten = explorer.exhaustive(10, stop=lambda: next(calls) < 0, deepen=10)
    cut = explorer.exhaustive(30, stop=_after_calls(next(calls) + 50), deepen=10)
    assert not cut.exhausted and cut.complete_depth == 10 and cut.complete_states == ten.complete_states
    assert explorer.exhaustive(30, stop=lambda: True).complete_depth == 0


def _states(scenario: Scenario, walks: int, length: int) -> Iterator[World]:
    """States met on random walks, each a fresh copy."""
    explorer = Explorer(scenario)
    for seed in range(walks):
        world, rng = explorer.world(), random.Random(seed)
        with contextlib.suppress(Violation, ProtocolViolation):
            for _ in range(length):
                moves = world.enabled()
                if world.finished or not moves:
                    break
                yield world.clone()
                world.apply(rng.choice(moves))


def _after(world: World, *moves: tuple[str, int]) -> tuple[object, World | None]:
    """The verdict and the world after ``moves``: the violation's monitor (or "disabled", if a move
    was not enabled when its turn came), or None and the world."""
    world = world.clone()
    try:
        for move in moves:
            if move not in world.enabled():
                return "disabled", None
            world.apply(move)
    except Violation as exc:
        return exc.monitor, None
    except ProtocolViolation:
        return "crash", None
    return None, world


def _canonical(world: World) -> object:
    return world.state_key_with(tuple(world.stack_key(d) for d in world.config.drones))


@pytest.mark.parametrize("scenario", SMALL[:3], ids=["2d", "3d", "faults"])
def test_moves_called_independent_commute_with_the_same_verdicts(scenario: Scenario) -> None:
    """What the sleep sets rest on: both orders of two independent moves end in one state, or both
    meet a violation."""
    checked = 0
    for world in itertools.islice(_states(scenario, walks=20, length=150), 800):
        moves = world.enabled()
        effects = {}
        for move in moves:
            _, after = _after(world, move)
            if after is not None:
                effects[move] = (effect_of(world, after, move), after.finished)
        for t, u in itertools.combinations(effects, 2):
            (et, t_finished), (eu, _) = effects[t], effects[u]
            if not independent(eu, et, world, t_finished, liveness_open=False):
                continue
            (v1, w1), (v2, w2) = _after(world, t, u), _after(world, u, t)
            assert "disabled" not in (v1, v2) and (v1 is None) == (v2 is None), (t, u, v1, v2)
            if w1 is not None and w2 is not None:
                assert _canonical(w1) == _canonical(w2), (t, u)
                checked += 1
    assert checked > 30


def test_clone_for_copies_what_the_move_changes() -> None:
    for world in itertools.islice(_states(SMALL[2], walks=4, length=60), 120):
        before = world.state_key()
        for move in world.enabled():
            _, whole = _after(world, move)
            part = world.clone_for(move)
            with contextlib.suppress(Violation, ProtocolViolation):
                part.apply(move)
            assert world.state_key() == before, move
            if whole is not None:
                assert _canonical(part) == _canonical(whole), move


def test_the_searchs_key_keeps_the_flown_cells_in_drone_order() -> None:
    """The order in which drones first stepped is no part of the state: worlds that differ only in
    it have one key."""
    for world in itertools.islice(_states(SMALL[1], walks=3, length=80), 100):
        key = world.state_key()
        world.monitors.history = dict(reversed(world.monitors.history.items()))
        assert world.state_key() == key == _canonical(world)
