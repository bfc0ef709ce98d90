"""The safe-trajectory checker: independent of the planner and simple enough to trust.

It is a direct reading of the paper's Eq. 2-6 plus one rule the paper lacks,
written as plain loops over steps with no clever data structures, so that it
can judge the planner, the systematic tester's executions and live fleets.

For a trajectory ``mine`` starting at step ``n`` and every other trajectory:

* **Obstacles**: every cell is in the grid and free, and consecutive cells
  are one motion primitive apart.
* **Collisions** (Eq. 6): for every step ``t >= n`` of mine and every step
  ``p`` of the other with ``|t - p| <= delta`` the two cells differ. Before its
  first step a drone sits at its first cell, after its last at its last cell,
  forever: checking up to ``max(ends) + delta + 1`` covers "forever".
* **Swaps**: no two drones exchange adjacent cells within one step, even when
  ``delta == 0`` (Eq. 5 alone lets two drones pass through each other).
* **Completion**: the trajectory ends at the goal; staying there forever is
  covered by the collision rule.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass

from drona_gcs.errors import UnsafeTrajectory
from drona_gcs.motion import Trajectory
from drona_gcs.workspace import Cell, Workspace


class ViolationKind(enum.Enum):
    OUT_OF_BOUNDS = "out_of_bounds"  #: a cell outside the grid
    OBSTACLE = "obstacle"  #: a cell covered by a static obstacle
    JUMP = "jump"  #: consecutive cells are not one primitive apart
    COLLISION = "collision"  #: same cell as another drone within the skew window
    SWAP = "swap"  #: two drones exchanged adjacent cells in one step
    GOAL = "goal"  #: the trajectory does not end at its goal


@dataclass(frozen=True)
class Violation:
    kind: ViolationKind
    step: int
    cell: Cell
    other: str | None = None
    other_step: int | None = None

    def __str__(self) -> str:
        text = f"{self.kind.value} at step {self.step} in cell {list(self.cell)}"
        if self.other is not None:
            text += f" with drone {self.other!r} at its step {self.other_step}"
        return text


def check_trajectory(workspace: Workspace, mine: Trajectory, others: Mapping[str, Trajectory],
                     delta: int, goal: Cell | None = None) -> list[Violation]:
    """Every violation of the safe-trajectory property by ``mine``; empty when safe."""
    found = check_path(workspace, mine)
    if goal is not None and mine.last != goal:
        found.append(Violation(ViolationKind.GOAL, mine.end_step, mine.last))
    for other_id, other in others.items():
        found.extend(check_pair(mine, other, delta, other_id, from_step=mine.start_step))
    return found


def assert_safe(workspace: Workspace, mine: Trajectory, others: Mapping[str, Trajectory],
                delta: int, goal: Cell | None = None) -> None:
    """Raise :class:`UnsafeTrajectory` unless ``mine`` is safe."""
    violations = check_trajectory(workspace, mine, others, delta, goal)
    if violations:
        raise UnsafeTrajectory(violations)


def check_path(workspace: Workspace, traj: Trajectory) -> list[Violation]:
    """Obstacles, bounds and continuity of one trajectory."""
    found: list[Violation] = []
    for k, cell in enumerate(traj.cells):
        step = traj.start_step + k
        if not workspace.in_bounds(cell):
            found.append(Violation(ViolationKind.OUT_OF_BOUNDS, step, cell))
        elif cell in workspace.obstacles:
            found.append(Violation(ViolationKind.OBSTACLE, step, cell))
        if k and sum(abs(a - b) for a, b in zip(cell, traj.cells[k - 1], strict=True)) > 1:
            found.append(Violation(ViolationKind.JUMP, step, cell))
    return found


def check_pair(mine: Trajectory, other: Trajectory, delta: int, other_id: str = "other",
               from_step: int | None = None, until: int | None = None) -> list[Violation]:
    """Collisions and swaps of ``mine`` against ``other`` for my steps ``from_step <= t <= until``.

    By default ``until`` is where both drones have been still for longer than
    the window, which covers "forever"; a monitor that sees trajectories grow
    step by step passes the last step it can judge.
    """
    n = mine.start_step if from_step is None else from_step
    # Both still from there on: one step past it tells whether they share a cell for good.
    horizon = max(mine.end_step, other.end_step, n - 1) + delta + 1 if until is None else until
    found: list[Violation] = []
    theirs = set(other.cells)  # both a collision and a swap put me in a cell of theirs
    if theirs.isdisjoint(mine.cells):
        return found  # every cell I am in at any step is one of mine
    for t in range(n, horizon + 1):
        here = mine.at(t)
        if here not in theirs:
            continue
        nxt = mine.at(t + 1)
        for p in range(t - delta, t + delta + 1):
            if here == other.at(p):
                found.append(Violation(ViolationKind.COLLISION, t, here, other_id, p))
            if here != nxt and other.at(p) == nxt and other.at(p + 1) == here:
                found.append(Violation(ViolationKind.SWAP, t, here, other_id, p))
    return found


def check_fleet(workspace: Workspace, trajectories: Mapping[str, Trajectory], delta: int) -> list[Violation]:
    """Check every pair of a fleet's trajectories (for example the cells actually flown)."""
    found: list[Violation] = []
    ids = list(trajectories)
    for i, a in enumerate(ids):
        found.extend(check_path(workspace, trajectories[a]))
        for b in ids[i + 1:]:
            start = min(trajectories[a].start_step, trajectories[b].start_step)
            for v in check_pair(trajectories[a], trajectories[b], delta, b, from_step=start):
                found.append(Violation(v.kind, v.step, v.cell, f"{a}~{b}", v.other_step))
    return found
