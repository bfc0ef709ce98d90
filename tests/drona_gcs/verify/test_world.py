"""The systematic tester's world model: vehicles down, a clone's task planner, and the model's
service that gives mail handed back.
"""

from __future__ import annotations

import random
from collections.abc import Callable

import pytest

from drona_gcs.verify.explore import Explorer, Scenario, Strategy
from drona_gcs.verify.world import World


def test_a_vehicle_down_stays_where_it_came_down_in_the_model() -> None:
    """The model flew a vehicle down along its plan, so no plan was ever seen to meet it: the
    separation monitor judged where the vehicle was not."""
    world = Explorer(Scenario(drones=3, requests=3, delta=1, seed=1)).world()
    for _ in range(400):
        flying = [i for i, d in enumerate(world.config.drones) if (plan := world.stacks[d].executor.trajectory)
                  is not None and world.steps[d] < plan.end_step - 2]
        if flying:
            break
        world.apply(next(m for m in world.enabled() if m[0] in ("step", "inject", "deliver")))
    drone = world.config.drones[flying[0]]
    where, seen = world.stacks[drone].executor.cell, len(world.monitors.history.get(drone, []))
    world.apply(("down", flying[0]))
    for _ in range(200):
        moves = world.enabled()
        ours = ([m for m in moves if m == ("step", flying[0])]
                or [m for m in moves if m[0] in ("step", "deliver", "inject")])
        if not ours:
            break
        world.apply(ours[0])
    assert len(world.monitors.history[drone]) > seen + 2 and set(world.monitors.history[drone][seen:]) == {where}


def test_a_clones_task_planner_measures_ways_with_the_clones_state() -> None:
    """The exhaustive search clones worlds: a clone's task planner measured ways with the state of the
    stack it was first made for, so dfs explored budgets that ignored every vehicle down since."""
    world = Explorer(Scenario(drones=2, requests=1, delta=1, seed=0, obstacles=0.0)).world()
    child = world.clone_for(world.enabled()[0])
    drone = world.config.drones[0]
    x, y, z = start = world.stacks[drone].executor.cell
    way = 1 if x + 2 < world.config.workspace.nx else -1
    ahead, beyond = (x + way, y, z), (x + 2 * way, y, z)
    child.stacks[drone].protocol.peers_down["d9"] = ahead
    assert world.stacks[drone].mail.distance(start, beyond) == 2
    assert child.stacks[drone].mail.distance(start, beyond) == 4


def test_the_service_gives_mail_handed_back_to_the_drone_with_the_least_in_hand() -> None:
    """Found by sweep 20021: two drones walled in and two more short of a charger handed their mail back,
    and the model's service gave each to the next drone by name. Only d5 flew, one mail after another, past
    the liveness bound. `drona serve` chooses by the fleet's rule (fewest held, idle, nearest): so does
    the model."""
    scenario = Scenario(drones=6, requests=9, delta=1, seed=161326, grid=(8, 8, 1), obstacles=0.2)
    outcome = Explorer(scenario).run(Strategy.RANDOM, schedules=30, max_depth=5000, seed=161326)
    assert outcome.violation is None, str(outcome.violation)


def _drive(world: World, until: Callable[[World], bool], rng: random.Random, moves: int = 3000) -> None:
    """Random moves but faults until ``until`` holds (bounded)."""
    for _ in range(moves):
        if until(world):
            return
        calm = [m for m in world.enabled() if m[0] in ("deliver", "step", "inject")]
        world.apply(rng.choice(calm))
    raise AssertionError("the world never got there")


def _given(world: World) -> bool:
    return bool(world.holder)


def _cleared_there(world: World) -> bool:
    return any(mail in (world.stacks[d].mail.cleared or set()) for mail, d in world.holder.items())


@pytest.mark.parametrize("cleared", [False, True])
def test_the_models_service_requeues_only_uncleared_mail_of_a_drone_cut_off(cleared: bool) -> None:
    """As ``drona serve``: a drone cut off hands back the mail it was not cleared for, and the service
    gives that to another drone; a mail cleared stays the cut-off drone's until the heal."""
    scenario = Scenario(drones=3, requests=1, delta=1, seed=4, partitions=1, faults=False)
    world = Explorer(scenario).world()
    _drive(world, _cleared_there if cleared else _given, random.Random(4))
    mail, drone = next(iter(world.holder.items()))
    world.apply(("partition", world.config.drones.index(drone)))
    if cleared:
        assert world.holder == {mail: drone} and not world.redispatch
    else:
        assert mail not in world.holder and [r.id for _, r, _ in world.redispatch] == [mail]
        held = world.stacks[drone].mail
        assert all(r.id != mail for r in held.queue) and (held.current is None or held.current.id != mail)
