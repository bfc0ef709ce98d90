"""Whether two trajectories break the separation rule: the protocol's own quick yes or no.

:func:`drona_gcs.safety.check_pair` states the rule as plain loops and lists every violation, for
the audit and the planner's tests. A drone asks the question for every proposal it holds and every
ack it gets, and needs only the answer: this finds it from where the other drone is at each step,
indexed once, and stops at the first meeting; a plan that ended more than Delta steps before is only
its last cell (an idle drone answers with its last plan). The two agree (tested on random walks).
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence

from drona_gcs.motion import Trajectory
from drona_gcs.workspace import Cell


def meets(mine: Trajectory, other: Trajectory, delta: int, from_step: int) -> bool:
    """``bool(check_pair(mine, other, delta, from_step=from_step))`` for ``delta >= 0``: a collision or
    a swap at a step of mine from ``from_step`` on, within ``delta`` steps of the other's."""
    cells = other.cells
    start, end = other.start_step, other.end_step
    if end + delta < from_step:  # by then the other is only its last cell (for good: so am I, later on)
        return _enters(mine, cells[-1], from_step)
    if set(cells).isdisjoint(mine.cells):
        return False
    first, last = cells[0], cells[-1]
    steps: dict[Cell, list[int]] = {}  #: the steps the other is in each cell, within its plan
    moves: dict[tuple[Cell, Cell], list[int]] = {}  #: the steps it leaves a cell for the next
    for k, cell in enumerate(cells):
        steps.setdefault(cell, []).append(start + k)
        if k:
            moves.setdefault((cells[k - 1], cell), []).append(start + k - 1)
    for t in range(from_step, max(mine.end_step, end) + delta + 2):
        here = mine.at(t)
        there = steps.get(here)
        if there is None:
            continue  # neither a collision nor a swap puts me in a cell the other never is in
        lo, hi = t - delta, t + delta
        if (here == first and lo <= start) or (here == last and hi >= end) or _any_within(there, lo, hi):
            return True
        ahead = mine.at(t + 1)
        if ahead != here and _any_within(moves.get((ahead, here), ()), lo, hi):
            return True
    return False


def _enters(mine: Trajectory, cell: Cell, from_step: int) -> bool:
    """Whether I am in ``cell`` at ``from_step`` or later: the other rests there from more than ``delta``
    steps before ``from_step`` on, so only being there meets it."""
    first = min(max(from_step - mine.start_step, 0), len(mine.cells) - 1)
    return cell in mine.cells[first:]


def _any_within(ascending: Sequence[int], lo: int, hi: int) -> bool:
    i = bisect.bisect_left(ascending, lo)
    return i < len(ascending) and ascending[i] <= hi
