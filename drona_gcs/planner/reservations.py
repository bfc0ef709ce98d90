"""Space-time reservations of the other drones, kept across plans.

The table is keyed by absolute step, so it survives from one plan to the
next: when a plan comes with the other drones' trajectories, only those that
changed since the last plan are removed and re-added (a few hundred dict
operations) instead of rebuilding a table proportional to the fleet.

A trajectory ``(m, [c_0 .. c_L])`` of another drone reserves, for my steps:

* cell ``c_k`` at every step in ``[m+k-delta, m+k+delta]`` (Eq. 6);
* its first cell at every step ``<= m + delta`` (it sits there before ``m``): ``pre``;
* its last cell at every step ``>= m + L - delta`` (it stays there): ``perm``;
* with ``delta == 0``, the reverse of each of its moves at the same step
  (no head-on swaps); with ``delta >= 1`` the vertex windows already forbid them.

Vertex keys are ``step * num_cells + cell``, the same encoding as the search's
states, so a conflict test is one dict lookup.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from itertools import pairwise

from drona_gcs.motion import Trajectory
from drona_gcs.workspace import Workspace

#: The last step of a safe interval that never ends (the largest int compiled code keeps unboxed).
FOREVER = (1 << 62) - 1
#: The safe intervals of a cell nobody ever reserves (one shared tuple, so ``is`` tells). Typed as
#: any length: mypyc keeps a fixed-length tuple unboxed and boxes a new one on every use.
ALWAYS_FREE: tuple[tuple[int, int], ...] = ((-FOREVER, FOREVER),)


@dataclass(frozen=True)
class _Entry:
    trajectory: Trajectory
    vertex_keys: tuple[int, ...]
    swap_keys: tuple[int, ...]
    first: int
    last: int
    pre_until: int  #: first cell reserved for every step <= this
    perm_from: int  #: last cell reserved for every step >= this
    finite_until: int  #: no reservation but ``perm`` after this step
    cell_last_step: dict[int, int]  #: per cell, the last step it is reserved (finite part; vertex mode)
    spans: tuple[tuple[int, int, int], ...]  #: ``(cell, first, last)``: runs of vertex steps (interval mode)


class ReservationTable:
    def __init__(self, workspace: Workspace, delta: int, vertex_keys: bool = True) -> None:
        self.workspace = workspace
        self.delta = delta
        self.n = workspace.num_cells
        #: Which of two views the table keeps: ``vertex`` keys for the space-time search, or
        #: ``spans`` and their safe intervals for the interval search. Keeping both would cost
        #: the updates of both on every plan.
        self.keeps_vertex = vertex_keys
        self.vertex: dict[int, int] = {}
        self.swaps: dict[int, int] = {}
        self.pre: dict[int, int] = {}
        self.perm: dict[int, int] = {}
        # Every drone's pre_until / perm_from by cell; pre and perm keep the max / min of each list.
        self._pre_all: dict[int, list[int]] = {}
        self._perm_all: dict[int, list[int]] = {}
        #: per cell, the ``(first, last)`` step runs of its vertex reservations (for safe intervals)
        self.spans: dict[int, list[tuple[int, int]]] = {}
        #: cache of :meth:`safe_intervals` by cell (None: not worked out); a list, for the search's
        #: inner loop, where indexing costs a fraction of a dict's ``get``
        self.interval_cache: list[tuple[tuple[int, int], ...] | None] = [None] * self.n
        #: No step before this one is asked about (:meth:`look_from`): safe intervals leave out
        #: the runs that end before it.
        self.horizon = -FOREVER
        self._entries: dict[str, _Entry] = {}

    # ----------------------------------------------------------- updates
    def sync(self, others: Mapping[str, Trajectory]) -> None:
        """Make the table hold exactly ``others``, touching only what changed."""
        for drone in [d for d in self._entries if d not in others]:
            self.remove(drone)
        for drone, traj in others.items():
            entry = self._entries.get(drone)
            if entry is None or (entry.trajectory is not traj and entry.trajectory != traj):
                self.set(drone, traj)

    def set(self, drone: str, traj: Trajectory) -> None:
        if drone in self._entries:
            self.remove(drone)
        entry = self._reserve(traj)
        self._entries[drone] = entry
        _add(self.vertex, entry.vertex_keys)
        _add(self.swaps, entry.swap_keys)
        spans, cache = self.spans, self.interval_cache
        for cell, lo, hi in entry.spans:
            found = spans.get(cell)
            if found is None:
                spans[cell] = [(lo, hi)]
            else:
                found.append((lo, hi))
            # Recomputed when next asked: a plan passes most of these cells, the next search
            # asks for few of them, and cutting the new run out of each cached list cost more.
            cache[cell] = None
        cache[entry.first] = cache[entry.last] = None  # their bounds before and after change too
        _join(self._pre_all, self.pre, entry.first, entry.pre_until, max)
        _join(self._perm_all, self.perm, entry.last, entry.perm_from, min)

    def remove(self, drone: str) -> None:
        entry = self._entries.pop(drone)
        _sub(self.vertex, entry.vertex_keys)
        _sub(self.swaps, entry.swap_keys)
        spans, cache = self.spans, self.interval_cache
        for cell, lo, hi in entry.spans:
            found = spans[cell]
            if len(found) == 1:  # mostly: nobody else passes here
                del spans[cell]
            else:
                found.remove((lo, hi))
            # Time comes back only where no other drone holds it: recomputed when next asked.
            cache[cell] = None
        cache[entry.first] = cache[entry.last] = None  # their bounds before and after change too
        _leave(self._pre_all, self.pre, entry.first, entry.pre_until, max)
        _leave(self._perm_all, self.perm, entry.last, entry.perm_from, min)

    def _reserve(self, traj: Trajectory) -> _Entry:
        nx, nxy = self.workspace.nx, self.workspace.nx * self.workspace.ny
        ids = [x + nx * y + nxy * z for x, y, z in traj.cells]
        n, d, m = self.n, self.delta, traj.start_step
        inner = ids[1:-1]
        vertex: list[int] = []
        cell_last: dict[int, int] = {}
        spans: tuple[tuple[int, int, int], ...] = ()
        if self.keeps_vertex:
            for offset in range(-d, d + 1):
                base = m + offset + 1
                vertex.extend([(base + k) * n + cell for k, cell in enumerate(inner)])
            cell_last = dict(zip(inner, range(m + 1 + d, m + 1 + d + len(inner)), strict=True))
            cell_last.setdefault(ids[0], m + d)
        else:
            spans = _spans(inner, m + 1, d)
        swaps: list[int] = []
        if d == 0:  # forbid my b -> a move while the other moves a -> b
            swaps = [((m + k) * n + b) * n + a
                     for k, (a, b) in enumerate(pairwise(ids)) if a != b]
        end = traj.end_step
        return _Entry(traj, tuple(vertex), tuple(swaps), ids[0], ids[-1], m + d, end - d,
                      max(end - 1 + d, m + d), cell_last, spans)

    def look_from(self, step: int) -> None:
        """Only steps from ``step`` on are asked about until the next call.

        Other drones' trajectories come whole, and by the time a drone plans, about
        half of each lies in the past. The safe intervals then leave out the runs
        that end before ``step``, and a cell whose reservations are all past is
        :data:`ALWAYS_FREE`, which the search takes on its fast path. Moving the
        horizon on keeps the cache (what was cut for an earlier step is still right
        for a later one); moving it back empties the cache.
        """
        if step < self.horizon:
            self.interval_cache = [None] * self.n
        self.horizon = step

    # ----------------------------------------------------------- queries
    def static_from(self, step: int) -> int:
        """The first step from which only ``perm`` reservations remain (>= ``step``)."""
        latest = max((e.finite_until for e in self._entries.values()), default=step - 1)
        return max(step, latest + 1)

    def goal_free_from(self, cell: int) -> int | None:
        """The earliest step from which ``cell`` stays unreserved forever; None if never. For a
        table of safe intervals, any step up to the :attr:`horizon` when it is free from there on."""
        if self.keeps_vertex:
            if cell in self.perm:
                return None
            last = -FOREVER
            for entry in self._entries.values():
                step = entry.cell_last_step.get(cell)
                if step is not None and step > last:
                    last = step
            return last + 1
        runs = self.safe_intervals(cell)
        if not runs or runs[-1][1] != FOREVER:
            return None  # a drone parks there for good
        return runs[-1][0]

    def pre_keys(self, step: int) -> list[int]:
        """Vertex keys, from ``step`` on, of drones still sitting at their first cell."""
        return [t * self.n + cell for cell, until in self.pre.items() for t in range(step, until + 1)]

    def parking_after(self, step: int) -> dict[int, int]:
        """Cells where a drone parks for good at some step after ``step``, with that step."""
        return {cell: start for cell, start in self.perm.items() if start > step}

    def blocked_throughout(self, step: int) -> frozenset[int]:
        """Cells reserved at every step from ``step`` on (drones parked for good)."""
        return frozenset(c for c, start in self.perm.items() if start <= step)

    def safe_intervals(self, cell: int) -> tuple[tuple[int, int], ...]:
        """The maximal runs ``(first, last)`` of steps in which ``cell`` is free, in order.

        Runs are open-ended (:data:`FOREVER`) at both ends where nobody sits there
        before or after. Runs that end before :attr:`horizon` are left out, and a
        cell free from the horizon on is :data:`ALWAYS_FREE`: the answer holds for
        every step from the horizon on. Cached until a reservation of the cell
        changes: a plan changes one drone's trajectory, while searches keep asking
        for the same cells.
        """
        found = self.interval_cache[cell]
        if found is None:
            found = self.interval_cache[cell] = self._free_runs(cell)
        return found

    def _free_runs(self, cell: int) -> tuple[tuple[int, int], ...]:
        if self.keeps_vertex:
            raise ValueError("safe intervals need a table built with vertex_keys=False")
        spans, pre, perm = self.spans.get(cell), self.pre.get(cell), self.perm.get(cell)
        horizon = self.horizon
        if pre is None and perm is None:
            if spans is None:
                return ALWAYS_FREE  # most cells: nobody ever comes by
            if len(spans) == 1:  # the commonest of the rest: one drone passes by
                lo, hi = spans[0]
                if hi < horizon:
                    return ALWAYS_FREE
                return ((-FOREVER, lo - 1), (hi + 1, FOREVER)) if lo > horizon else ((hi + 1, FOREVER),)
        blocked = sorted(spans) if spans is not None else []
        end = FOREVER if perm is None else perm - 1
        out: list[tuple[int, int]] = []
        free_from = -FOREVER if pre is None else pre + 1
        for lo, hi in blocked:
            if lo > free_from:
                if lo > end:
                    break
                if lo > horizon:  # else the run ends before the horizon
                    out.append((free_from, lo - 1))
            if hi >= free_from:
                free_from = hi + 1
        if free_from <= end and end >= horizon:
            if not out and free_from <= horizon and end == FOREVER:
                return ALWAYS_FREE  # every reservation is past
            out.append((free_from, end))
        return tuple(out)

    def conflicts(self, cell: int, step: int) -> bool:
        """Whether being in ``cell`` at ``step`` clashes with a reservation (``step`` not before
        the :attr:`horizon`, for a table of safe intervals)."""
        if not self.keeps_vertex:
            assert step >= self.horizon, f"step {step} is before the horizon {self.horizon}"
            return not free_at(self.safe_intervals(cell), step)
        return (step * self.n + cell in self.vertex or self.perm.get(cell, step + 1) <= step
                or self.pre.get(cell, step - 1) >= step)


def free_at(intervals: tuple[tuple[int, int], ...], step: int) -> bool:
    """Whether ``step`` lies in one of ``intervals``."""
    return any(lo <= step <= hi for lo, hi in intervals)


def _spans(cells: list[int], first_step: int, delta: int) -> tuple[tuple[int, int, int], ...]:
    """``(cell, first, last)`` for each run of equal cells: the steps their vertex keys cover."""
    out: list[tuple[int, int, int]] = []
    since, last = 0, len(cells) - 1
    for k, cell in enumerate(cells):
        if k == last or cells[k + 1] != cell:  # the run that began at `since` ends here
            out.append((cell, first_step + since - delta, first_step + k + delta))
            since = k + 1
    return tuple(out)


def _add(table: dict[int, int], keys: tuple[int, ...] | list[int]) -> None:
    get = table.get
    for key in keys:
        table[key] = get(key, 0) + 1


def _sub(table: dict[int, int], keys: tuple[int, ...] | list[int]) -> None:
    for key in keys:
        left = table[key] - 1
        if left:
            table[key] = left
        else:
            del table[key]


def _join(everyone: dict[int, list[int]], summary: dict[int, int], cell: int, value: int,
          pick: Callable[[Iterable[int]], int]) -> None:
    """Add one drone's ``value`` at ``cell``; ``summary[cell]`` is ``pick`` (max or min) of them all."""
    values = everyone.setdefault(cell, [])
    values.append(value)
    summary[cell] = pick(values)


def _leave(everyone: dict[int, list[int]], summary: dict[int, int], cell: int, value: int,
           pick: Callable[[Iterable[int]], int]) -> None:
    """Take back what :func:`_join` added."""
    values = everyone[cell]
    values.remove(value)
    if values:
        summary[cell] = pick(values)
    else:
        del everyone[cell], summary[cell]
