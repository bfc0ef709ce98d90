"""The paper's planner workload (section 6, Table 2), as a seeded, clock-free generator.

* A W x W grid with 20% obstacle cells; pockets cut off from the main free
  region are filled in, so every free cell can reach every other.
* R drones parked at random distinct free cells.
* A stream of tasks: the drone whose trajectory ends first gets the next task
  at that step, with a random free goal that is not another drone's final
  cell, planned against every other drone's current trajectory.

The caller times the planning; this module only says what to plan and
records the outcome, so the same stream can drive any planner.
"""

from __future__ import annotations

import random
from collections.abc import Mapping
from dataclasses import dataclass, field

from drona_gcs.motion import Trajectory
from drona_gcs.workspace import Cell, Workspace


def random_workspace(width: int, height: int, rng: random.Random, obstacle_ratio: float = 0.2,
                     layers: int = 1) -> Workspace:
    """A random grid with ``obstacle_ratio`` of its cells blocked and its pockets filled."""
    cells = [(x, y, z) for z in range(layers) for y in range(height) for x in range(width)]
    blocked = set(rng.sample(cells, round(obstacle_ratio * len(cells))))
    rough = Workspace(size=(width, height, layers), obstacles=frozenset(blocked))
    pockets = set(rough.free_cells) - rough.main_region
    return Workspace.build(size=(width, height, layers), obstacles=frozenset(blocked | pockets),
                           name=f"random-{width}x{height}x{layers}")


@dataclass(frozen=True)
class Task:
    drone: str
    start: Cell
    goal: Cell
    start_step: int
    others: Mapping[str, Trajectory]


@dataclass
class TaskStream:
    """Drones on a workspace receiving random tasks, one at a time."""

    workspace: Workspace
    drones: int
    rng: random.Random
    trajectories: dict[str, Trajectory] = field(default_factory=dict)

    def __post_init__(self) -> None:
        starts = self.rng.sample(list(self.workspace.main_region), self.drones)
        starts.sort()
        self.trajectories = {f"d{i}": Trajectory.stationary(c, 0) for i, c in enumerate(starts)}
        self._free = sorted(self.workspace.main_region)

    def next_task(self) -> Task:
        drone = min(self.trajectories, key=lambda d: (self.trajectories[d].end_step, d))
        mine = self.trajectories[drone]
        taken = {t.last for t in self.trajectories.values()}
        goal = self.rng.choice(self._free)
        while goal in taken:
            goal = self.rng.choice(self._free)
        others = {d: t for d, t in self.trajectories.items() if d != drone}
        return Task(drone, mine.last, goal, mine.end_step, others)

    def complete(self, task: Task, trajectory: Trajectory | None) -> None:
        """Record the plan; on failure the drone holds one more step and tries again later."""
        if trajectory is None:
            trajectory = Trajectory(task.start_step, (task.start, task.start))
        self.trajectories[task.drone] = trajectory
