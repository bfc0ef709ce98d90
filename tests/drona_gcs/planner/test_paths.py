"""The planner's second path (seal pruning, and the time-layered heuristic for mixed costs) is as exact as the first."""

from __future__ import annotations

import random

import pytest

from drona_gcs.errors import NoPlanFound
from drona_gcs.motion import Primitive, Trajectory
from drona_gcs.planner import SafePlanner
from drona_gcs.safety import check_trajectory
from drona_gcs.workload import TaskStream, random_workspace


@pytest.mark.parametrize(("width", "drones", "delta"), [(12, 10, 0), (16, 16, 1), (20, 24, 0)])
def test_forced_long_path_finds_the_same_costs(width: int, drones: int, delta: int) -> None:
    rng = random.Random(f"paths-{width}-{drones}-{delta}")
    ws = random_workspace(width, width, rng)
    quick, slow = SafePlanner(ws, delta), SafePlanner(ws, delta)
    slow.seal_after = -10**9  # every search restarts at once with seal pruning and layers
    stream = TaskStream(ws, drones, rng)
    outcomes = {"ok": 0, "no_plan": 0}
    for _ in range(120):
        task = stream.next_task()
        results: list[Trajectory | None] = []
        costs: list[float | None] = []
        for planner in (quick, slow):
            try:
                plan = planner.plan(task.start, task.goal, task.start_step, task.others)
            except NoPlanFound:
                results.append(None)
                costs.append(None)
                continue
            assert check_trajectory(ws, plan.trajectory, task.others, delta, task.goal) == []
            results.append(plan.trajectory)
            costs.append(plan.cost)
        assert costs[0] == costs[1], f"task {task}: {costs}"
        outcomes["ok" if results[0] else "no_plan"] += 1
        stream.complete(task, results[0])
    assert outcomes["ok"] > 100  # the stream is mostly feasible; both paths agree on the rest


@pytest.mark.parametrize(("delta", "costs", "spied"),
                         [(1, {}, "find_seal"), (0, {}, "TimeLayers"), (0, {Primitive.HOLD: 0.5}, "TimeLayers")],
                         ids=["unit-intervals", "unit-delta0-space-time", "mixed-space-time"])
def test_the_forced_planner_really_takes_the_second_path(monkeypatch: pytest.MonkeyPatch, delta: int,
                                                         costs: dict[Primitive, float], spied: str) -> None:
    # Safe intervals (unit costs, delta >= 1): seal pruning; space-time search (delta 0 or mixed
    # costs): seal pruning and the time-layered heuristic.
    import drona_gcs.planner as planner_module

    calls: list[bool] = []
    real = getattr(planner_module, spied)

    def spy(*args: object, **kwargs: object) -> object:
        calls.append(True)
        return real(*args, **kwargs)

    monkeypatch.setattr(planner_module, spied, spy)
    ws = random_workspace(12, 12, random.Random(5))
    slow = SafePlanner(ws, delta, costs=costs)
    slow.seal_after = -10**9
    assert slow.intervals == (spied == "find_seal")
    start, goal = min(ws.main_region), max(ws.main_region)
    straight = SafePlanner(ws, delta).plan(start, goal, 0, {}).trajectory
    # Another drone flies the same corridor head-on: the straight path is no longer free.
    oncoming = {"a": Trajectory(0, tuple(reversed(straight.cells[1:-1])))}
    plan = slow.plan(start, goal, 0, oncoming)
    assert calls
    assert check_trajectory(ws, plan.trajectory, oncoming, delta, goal) == []


def test_layers_with_nobody_about_to_park() -> None:
    from drona_gcs.planner.layers import TimeLayers

    ws = random_workspace(8, 8, random.Random(1))
    planner = SafePlanner(ws, 0)
    goal = ws.cell_id(max(ws.main_region))
    now = planner.graph.distances(goal, frozenset())
    layers = TimeLayers(planner.graph, planner.table, goal, 0, now)
    assert layers.thresholds == [] and layers.at(50) is now
