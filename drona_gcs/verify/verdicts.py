"""What every monitor shares: the violation it raises, its own reading of a trajectory (never the
planner's or the protocol's), and the words traces and violations use for cells."""

from __future__ import annotations

from drona_gcs.errors import DronaError
from drona_gcs.motion import Trajectory
from drona_gcs.workspace import Cell


class Violation(DronaError):
    """A monitor saw a property fail; ``monitor`` names which: a .. f."""

    def __init__(self, monitor: str, message: str) -> None:
        self.monitor = monitor
        super().__init__(f"({monitor}) {message}")


def same_future(a: Trajectory, b: Trajectory, since: int) -> bool:
    """Whether two trajectories put the drone in the same cell at every step from ``since`` on (each
    at its first cell before it starts, at its last after it ends)."""
    horizon = max(a.end_step, b.end_step, since)
    return all(cell_at(a, t) == cell_at(b, t) for t in range(since, horizon + 1))


def cell_at(traj: Trajectory, step: int) -> Cell:
    """Where ``traj`` puts its drone at ``step``: its first cell before it starts, its last after it ends."""
    k = min(max(step - traj.start_step, 0), len(traj.cells) - 1)
    return traj.cells[k]


def cell_text(cell: Cell) -> str:
    """A cell as traces and violations print it."""
    return f"[{cell[0]},{cell[1]},{cell[2]}]"


def cells_text(traj: Trajectory, most: int = 10) -> str:
    """A trajectory as traces and violations print it: its start step and its first cells."""
    cells = " ".join(cell_text(c) for c in traj.cells[:most])
    return f"step {traj.start_step}: {cells}{' ...' if len(traj.cells) > most else ''}"


def added(before: Trajectory, after: Trajectory) -> set[Cell]:
    """The cells a new plan adds to what its drone was committed to: from the step the two part on
    (a plan made at rest parts with its first move; a new rest of a plan flown, where it turns off)."""
    step = after.start_step
    while step <= after.end_step and cell_at(after, step) == cell_at(before, step):
        step += 1
    return {cell_at(after, t) for t in range(step, after.end_step + 1)}
