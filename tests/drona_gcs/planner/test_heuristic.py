"""The distance heuristic against a plain breadth-first search, with cells cut out for one plan.

A parked drone's cell is cut from the graph for one search: no path to the
goal may run through it, and it reads as unreachable. The next search with
other cells blocked must not see the old cut, and ``whole()`` gives back the
graph as built.
"""

from __future__ import annotations

from collections import deque

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drona_gcs.planner.grid import GridIndex
from drona_gcs.planner.heuristic import UNREACHABLE, DistanceGraph
from drona_gcs.workspace import Workspace


def plain_distances(grid: GridIndex, goal: int, cut: set[int]) -> dict[int, int]:
    """Steps from each cell to ``goal``, never passing through a cell of ``cut``."""
    found, queue = {goal: 0}, deque([goal])
    while queue:
        cell = queue.popleft()
        for before, _ in grid.reverse[cell]:
            if before not in found and before not in cut:
                found[before] = found[cell] + 1
                queue.append(before)
    return found


@st.composite
def grids_with_cuts(draw: st.DrawFn) -> tuple[GridIndex, int, frozenset[int]]:
    nx, ny, nz = draw(st.integers(2, 7)), draw(st.integers(2, 7)), draw(st.integers(1, 2))
    cells = [(x, y, z) for x in range(nx) for y in range(ny) for z in range(nz)]
    obstacles = draw(st.sets(st.sampled_from(cells), max_size=len(cells) // 4))
    free = [c for c in cells if c not in obstacles]
    ws = Workspace(size=(nx, ny, nz), obstacles=frozenset(obstacles))
    goal = ws.cell_id(draw(st.sampled_from(free)))
    cut = draw(st.sets(st.sampled_from([ws.cell_id(c) for c in free]), max_size=len(free) // 2))
    return GridIndex.build(ws), goal, frozenset(cut)


@settings(max_examples=150, deadline=None)
@given(grids_with_cuts())
def test_distances_avoid_the_cut_cells_and_the_next_search_sees_none_of_them(
        case: tuple[GridIndex, int, frozenset[int]]) -> None:
    grid, goal, cut = case
    graph = DistanceGraph(grid)
    expected = plain_distances(grid, goal, set(cut) - {goal})
    heuristic = graph.distances(goal, cut)
    for cell, free in enumerate(grid.free):
        if not free:
            continue
        want = UNREACHABLE if cell in cut and cell != goal else expected.get(cell, UNREACHABLE)
        assert heuristic.get(cell) == want, f"cell {grid.coords[cell]}"
    whole = plain_distances(grid, goal, set())
    after = graph.distances(goal, frozenset())
    assert all(after.get(c) == whole.get(c, UNREACHABLE) for c, free in enumerate(grid.free) if free)


@settings(max_examples=100, deadline=None)
@given(grids_with_cuts(), st.lists(st.sets(st.integers(0, 97)), min_size=1, max_size=4))
def test_successive_cuts_each_see_only_their_own_cells(case: tuple[GridIndex, int, frozenset[int]],
                                                         picks: list[set[int]]) -> None:
    grid, goal, first = case
    free = [c for c, ok in enumerate(grid.free) if ok]
    graph = DistanceGraph(grid)
    built = graph.matrix.copy()
    for cut in [first, *(frozenset(free[i % len(free)] for i in pick) for pick in picks)]:
        expected = plain_distances(grid, goal, set(cut) - {goal})
        heuristic = graph.distances(goal, cut)
        for cell in free:
            want = UNREACHABLE if cell in cut and cell != goal else expected.get(cell, UNREACHABLE)
            assert heuristic.get(cell) == want, f"cell {grid.coords[cell]} with {sorted(cut)} cut"
    whole = graph.whole()
    assert (whole != built).nnz == 0
    assert (whole.indices == built.indices).all()


def test_a_cell_outside_the_grid_is_refused_before_anything_is_cut() -> None:
    grid = GridIndex.build(Workspace(size=(4, 4, 1)))
    graph = DistanceGraph(grid)
    built = graph.matrix.copy()
    with pytest.raises(ValueError, match=r"0\.\.15"):
        graph.distances(0, frozenset({1, 2, 23}))  # 23 comes last: 1 and 2 would be cut already
    assert (graph.whole().indices == built.indices).all()
    assert graph.distances(0, frozenset({5})).get(5) == UNREACHABLE
