"""Monitors (b) and (g): where the drones are, step by step; no two meet, and each flies its plan."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

from drona_gcs.motion import Trajectory
from drona_gcs.verify.verdicts import Violation, cell_at, cell_text, cells_text
from drona_gcs.workspace import Cell

if TYPE_CHECKING:
    from drona_gcs.verify.config import WorldConfig


@dataclass(frozen=True)
class Meeting:
    """Drone a at ``step`` in ``cell``, and drone b too close: in that cell at ``other_step``, or swapping."""

    kind: str  #: "collision" or "swap"
    step: int
    cell: Cell
    other_step: int


def meetings(a: list[Cell], b: list[Cell], t: int, delta: int) -> list[Meeting]:
    """Where ``a`` (cells flown, one a step from step 0) at step ``t`` meets ``b`` within ``delta`` steps:
    ``a`` in a cell ``b`` is in at such a step, or the two trading cells across one boundary."""

    def at(cells: list[Cell], step: int) -> Cell:
        return cells[min(max(step, 0), len(cells) - 1)]

    here, there = at(a, t), at(a, t + 1)
    found = []
    for p in range(t - delta, t + delta + 1):
        if at(b, p) == here:
            found.append(Meeting("collision", t, here, p))
        if here != there and at(b, p) == there and at(b, p + 1) == here:
            found.append(Meeting("swap", t, here, p))
    return found


class SeparationMonitor:
    """(b) and (g), on the records the monitors keep (see :class:`.monitors.Monitors`)."""

    config: WorldConfig
    history: dict[str, list[Cell]]
    judged: int
    committed: dict[str, Trajectory]
    stopped: dict[str, int]
    told: dict[tuple[str, str], int]
    drifts: tuple[tuple[str, int, tuple[tuple[str, int], ...]], ...]

    def position(self, drone: str, step: int, cell: Cell, steps: dict[str, int], flies: bool = True) -> None:
        """Record where ``drone`` is at ``step``; judge every step whose whole window has been flown.
        ``flies``: its agent and vehicle are in service, so it must be where its plan says (g)."""
        self.history.setdefault(drone, []).append(cell)
        planned = cell_at(self.committed[drone], step)
        if flies and cell != planned:
            raise Violation("g", f"{drone} is in {cell_text(cell)} at step {step}, but its plan "
                                 f"({cells_text(self.committed[drone])}) puts it in {cell_text(planned)}")
        widest = max((self._window(skewed, skewed)[0] for skewed, _, _ in self.drifts), default=self.config.delta)
        while self.judged < min(steps.values()) - widest - 1:
            self.judged += 1
            self._judge(self.judged)

    def _judge(self, t: int) -> None:
        drones = sorted(self.history)
        for i, a in enumerate(drones):
            for b in drones[i + 1:]:
                window, since = self._window(a, b)
                for meeting in meetings(self.history[a], self.history[b], t, window):
                    apart = abs(meeting.step - meeting.other_step) > self.config.delta
                    if apart and (since is None or t < since[a] or meeting.other_step < since[b]):
                        continue  # the two clocks were within Delta then
                    if not self._unforeseeable(meeting, a, b):
                        raise Violation("b", f"{a} and {b}: {meeting.kind} at step {t} in cell "
                                             f"{list(meeting.cell)} with drone {b!r} at its step {meeting.other_step}")

    def _window(self, a: str, b: str) -> tuple[int, dict[str, int] | None]:
        """The window (b) judges ``a`` and ``b`` in, and the steps they were at when it widened (None: Delta)."""
        for skewed, offset, steps in self.drifts:
            if skewed in (a, b):
                return max(self.config.delta, 1) + abs(offset), dict(steps)
        return self.config.delta, None

    def unbound(self, offsets: Mapping[str, int], steps: Mapping[str, int]) -> None:
        """Every drone knows these clocks are off, each by its offset in steps: from ``steps`` on, they
        keep to it."""
        now = tuple(sorted(steps.items()))
        self.drifts = (*self.drifts, *((d, k, now) for d, k in sorted(offsets.items())))

    def _unforeseeable(self, v: Meeting, a: str, b: str) -> bool:
        """A collision with a vehicle down, after it came down, by a drone that entered its cell before
        the news reached it (told at its step ``s``, it must not be there at ``s + 1``). Not so for a
        crashed agent's vehicle, which holds where its plan said it would leave: that is the product's
        to prevent (issue 25), not the network's news."""
        if v.kind != "collision":
            return False
        for down, at, other, when in ((b, v.other_step, a, v.step), (a, v.step, b, v.other_step)):
            since = self.stopped.get(down)
            if since is None or at <= since or self.history[down][since] != v.cell:
                continue
            entered = when
            while entered > 0 and self.history[other][entered - 1] == v.cell:
                entered -= 1
            told = self.told.get((other, down))
            if told is None or told >= entered:
                return True
        return False

