"""Motion primitives, motion plans and timed trajectories (paper section 2.2).

A motion primitive moves a drone by at most one cell in one period tau.
``post(l, g)`` is where primitive ``g`` applied at ``l`` leaves the drone,
``intermediate(l, g)`` the cells it may pass through (both ends included:
primitives move along one axis, so nothing else is crossed), and
``cost(g)`` its cost, 1 for every primitive by default, hold included.

A :class:`MotionPlan` (Definition 2.1) is a start cell and a sequence of
primitives; applied from step ``n`` it gives a :class:`Trajectory`
(Definition 2.2): the cells ``l_n .. l_{n+k}``. A drone sits at its first cell
before its trajectory starts and at its last cell forever after.
"""

from __future__ import annotations

import enum
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

from drona_gcs.errors import ProblemError
from drona_gcs.workspace import Cell, Workspace


class Primitive(enum.Enum):
    """One motion primitive; the value is its name in JSON."""

    HOLD = "hold"  #: stay in the cell for one period
    XP = "+x"  #: one cell towards +x
    XM = "-x"  #: one cell towards -x
    YP = "+y"  #: one cell towards +y
    YM = "-y"  #: one cell towards -y
    ZP = "+z"  #: one layer up
    ZM = "-z"  #: one layer down

    @property
    def vector(self) -> Cell:
        return _VECTORS[self]


_VECTORS: dict[Primitive, Cell] = {
    Primitive.HOLD: (0, 0, 0), Primitive.XP: (1, 0, 0), Primitive.XM: (-1, 0, 0),
    Primitive.YP: (0, 1, 0), Primitive.YM: (0, -1, 0), Primitive.ZP: (0, 0, 1), Primitive.ZM: (0, 0, -1),
}
_BY_VECTOR = {v: p for p, v in _VECTORS.items()}


def primitive_between(a: Cell, b: Cell) -> Primitive:
    """The primitive that moves from ``a`` to ``b``; they must be equal or adjacent."""
    step = (b[0] - a[0], b[1] - a[1], b[2] - a[2])
    try:
        return _BY_VECTOR[step]
    except KeyError:
        raise ProblemError(f"cells {list(a)} and {list(b)} are not one primitive apart") from None


@dataclass(frozen=True)
class MotionModel:
    """The primitives available in a workspace and what each costs."""

    workspace: Workspace
    costs: Mapping[Primitive, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for prim, cost in self.costs.items():
            if not cost >= 0:
                raise ProblemError(f"the cost of primitive {prim.value!r} must be >= 0, got {cost}")

    @property
    def primitives(self) -> tuple[Primitive, ...]:
        """hold, +/-x, +/-y, and +/-z only when the grid has more than one layer."""
        planar = (Primitive.HOLD, Primitive.XP, Primitive.XM, Primitive.YP, Primitive.YM)
        return planar + ((Primitive.ZP, Primitive.ZM) if self.workspace.nz > 1 else ())

    def cost(self, prim: Primitive) -> float:
        return self.costs.get(prim, 1.0)

    def post(self, cell: Cell, prim: Primitive) -> Cell:
        dx, dy, dz = prim.vector
        return (cell[0] + dx, cell[1] + dy, cell[2] + dz)

    def intermediate(self, cell: Cell, prim: Primitive) -> tuple[Cell, ...]:
        end = self.post(cell, prim)
        return (cell,) if end == cell else (cell, end)

    def allowed(self, cell: Cell, prim: Primitive) -> bool:
        """True when every cell the primitive passes through is free."""
        return prim in self.primitives and all(self.workspace.is_free(c) for c in self.intermediate(cell, prim))

    def plan_cost(self, plan: Iterable[Primitive]) -> float:
        return sum(self.cost(p) for p in plan)


def parse_costs(raw: Mapping[str, float]) -> dict[Primitive, float]:
    """Primitive costs from JSON/YAML names, e.g. ``{"hold": 0.5, "+z": 2}``."""
    out: dict[Primitive, float] = {}
    for name, cost in raw.items():
        try:
            out[Primitive(name)] = float(cost)
        except ValueError:
            known = [p.value for p in Primitive]
            raise ProblemError(f"unknown primitive {name!r} in costs; known: {known}") from None
    return out


@dataclass(frozen=True)
class Trajectory:
    """Timed trajectory: ``cells[k]`` is occupied at step ``start_step + k``."""

    start_step: int
    cells: tuple[Cell, ...]

    def __post_init__(self) -> None:
        if not self.cells:
            raise ProblemError("a trajectory needs at least one cell")

    @classmethod
    def stationary(cls, cell: Cell, step: int) -> Trajectory:
        return cls(step, (cell,))

    @property
    def end_step(self) -> int:
        """The step at which the last cell is reached."""
        return self.start_step + len(self.cells) - 1

    @property
    def first(self) -> Cell:
        return self.cells[0]

    @property
    def last(self) -> Cell:
        return self.cells[-1]

    def at(self, step: int) -> Cell:
        """Where the drone is at ``step``: first cell before, last cell after."""
        k = step - self.start_step
        if k <= 0:
            return self.cells[0]
        return self.cells[k] if k < len(self.cells) else self.cells[-1]

    def primitives(self) -> tuple[Primitive, ...]:
        return tuple(primitive_between(a, b) for a, b in zip(self.cells, self.cells[1:], strict=False))

    def spliced(self, later: Trajectory) -> Trajectory:
        """This trajectory until ``later`` starts (holding its last cell if it ends before), then ``later``."""
        if later.first != self.at(later.start_step):
            raise ProblemError(f"a trajectory from {list(later.first)} at step {later.start_step} cannot follow "
                               f"one at {list(self.at(later.start_step))} then")
        if later.start_step <= self.start_step:
            return later
        return Trajectory(self.start_step, (*(self.at(s) for s in range(self.start_step, later.start_step)),
                                            *later.cells))

    def suffix_from(self, step: int) -> Trajectory:
        """The part from ``step`` on (the drone's position at ``step`` first)."""
        if step <= self.start_step:
            return self
        k = min(step - self.start_step, len(self.cells) - 1)
        return Trajectory(step, self.cells[k:])


@dataclass(frozen=True)
class MotionPlan:
    """A start cell and the primitives applied from it (Definition 2.1)."""

    start: Cell
    primitives: tuple[Primitive, ...]

    def trajectory(self, start_step: int, model: MotionModel) -> Trajectory:
        """Definition 2.2: apply the plan from ``start_step``."""
        cells = [self.start]
        for prim in self.primitives:
            cells.append(model.post(cells[-1], prim))
        return Trajectory(start_step, tuple(cells))
