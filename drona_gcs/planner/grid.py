"""Integer-indexed view of a workspace for the planners' inner loops.

Cells become ids (``Workspace.cell_id``) and each free cell gets its list of
``(next_id, cost, primitive)`` moves, precomputed once per workspace and cost
table, so the searches never build tuples or check bounds.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from itertools import pairwise

from drona_gcs.motion import MotionModel, Primitive, Trajectory
from drona_gcs.workspace import Cell, Workspace

Move = tuple[int, float, Primitive]


@dataclass(frozen=True, eq=False)
class GridIndex:
    """Free-cell adjacency of one workspace under one cost table."""

    workspace: Workspace
    model: MotionModel
    moves: tuple[tuple[Move, ...], ...]  #: moves[c]: forward moves out of free cell c (no hold)
    reverse: tuple[tuple[tuple[int, float], ...], ...]  #: reverse[c]: (pred, cost) of moves into c
    free: tuple[bool, ...]
    coords: tuple[Cell, ...]
    hold_cost: float
    min_cost: float
    uniform_cost: float | None  #: the common cost when every primitive costs the same (> 0)
    successors: tuple[tuple[tuple[int, float], ...], ...]  #: (next, cost) of every move and the hold
    moves_only: tuple[tuple[tuple[int, float], ...], ...]  #: the same without the hold
    next_cells: tuple[tuple[int, ...], ...]  #: the cells of ``moves_only`` alone (uniform-cost searches)
    #: the primitive of each difference of cell ids along a move (0: hold)
    by_difference: dict[int, Primitive]

    @classmethod
    def build(cls, workspace: Workspace, costs: Mapping[Primitive, float] | None = None) -> GridIndex:
        model = MotionModel(workspace, dict(costs or {}))
        n = workspace.num_cells
        coords = tuple(workspace.cell_of_id(i) for i in range(n))
        free = tuple(c not in workspace.obstacles for c in coords)
        movers = [p for p in model.primitives if p is not Primitive.HOLD]
        moves: list[tuple[Move, ...]] = []
        reverse: list[list[tuple[int, float]]] = [[] for _ in range(n)]
        for i, cell in enumerate(coords):
            out: list[Move] = []
            if free[i]:
                for prim in movers:
                    nxt = model.post(cell, prim)
                    if workspace.is_free(nxt):
                        j = workspace.cell_id(nxt)
                        out.append((j, model.cost(prim), prim))
                        reverse[j].append((i, model.cost(prim)))
            moves.append(tuple(out))
        all_costs = [model.cost(p) for p in model.primitives]
        uniform = all_costs[0] if len(set(all_costs)) == 1 and all_costs[0] > 0 else None
        hold = model.cost(Primitive.HOLD)
        moves_only = tuple(tuple((j, cost) for j, cost, _ in out) for out in moves)
        successors = tuple((*m, (i, hold)) if free[i] else m for i, m in enumerate(moves_only))
        # Cell ids are x + nx*y + nx*ny*z, so a primitive is one id difference wherever it
        # applies (a size-1 axis has no moves along it, so no two primitives share one).
        steps = {(j - i, prim) for i, out in enumerate(moves) for j, _, prim in out} | {(0, Primitive.HOLD)}
        by_difference = dict(steps)
        assert len(by_difference) == len(steps), "two primitives share an id difference"
        return cls(workspace, model, tuple(moves), tuple(tuple(r) for r in reverse), free, coords,
                   hold, min(all_costs), uniform, successors, moves_only,
                   tuple(tuple(j for j, _ in m) for m in moves_only), by_difference)

    def trajectory(self, start_step: int, ids: list[int]) -> tuple[Trajectory, tuple[Primitive, ...]]:
        """The trajectory through cell ids ``ids`` (consecutive ones a move or a hold apart),
        and its primitives, without comparing coordinates step by step."""
        coords, prim = self.coords, self.by_difference
        primitives = tuple([prim[b - a] for a, b in pairwise(ids)])
        return Trajectory(start_step, tuple([coords[c] for c in ids])), primitives

    def axis_costs(self) -> tuple[float, float, float, float, float, float]:
        """Costs of +x, -x, +y, -y, +z, -z, for the Manhattan lower bound."""
        c = self.model.cost
        return (c(Primitive.XP), c(Primitive.XM), c(Primitive.YP), c(Primitive.YM),
                c(Primitive.ZP), c(Primitive.ZM))
