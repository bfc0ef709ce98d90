"""How many tasks the drones of one host start at one boundary.

Every drone of a host decides at the same boundary, before any load shows: given mail at once, 64 drones
of a process started 64 tasks together, their rounds put the process seconds behind, and its vehicles and
its peers' news went late with it (found over 128 agents on 2 cores). A host starts only as many tasks
at a boundary as it can coordinate within the lag bound it holds itself to.

The cost of a task to each host: every peer handles its proposal and its decision, and its drone handles
every peer's ack, 3 (N - 1) messages in all. With every host starting ``k`` tasks a boundary, each host
handles about ``3 k (N - 1)`` of them in all; each takes what handling one took lately (measured on the
loop, waits for the CPU included: a host short of CPU starts fewer).
"""

from __future__ import annotations

import math

#: Messages one task makes each host handle per peer: its proposal, its decision, and the acks.
MESSAGES_PER_PEER = 3
#: Weight of the newest handling time in the running mean (about the last 50 messages).
SMOOTHING = 0.02


class TaskBudget:
    """The tasks a host's drones may start at one boundary (shared by the host's agents). The drones turned
    away with mail to carry go first, the longest turned away first: the drones ask in the same order at
    every boundary, and the first ones must not take every start."""

    def __init__(self, bound_s: float) -> None:
        self.bound_s = bound_s  #: how far behind the host lets itself fall
        self.handling_s: float | None = None  #: running mean of handling one protocol message
        self._step: int | None = None
        self._started = 0  #: tasks started at ``_step``
        self._asked: set[str] = set()  #: the drones that asked at ``_step``
        self._waiting_since: dict[str, int] = {}  #: drones with mail turned away: since when

    def handled(self, seconds: float) -> None:
        """A protocol message took ``seconds`` to handle."""
        mean = self.handling_s
        self.handling_s = seconds if mean is None else mean + SMOOTHING * (seconds - mean)

    def per_boundary(self, peers: int) -> int | None:
        """How many tasks may start at one boundary with ``peers`` peers (None: no bound, with none). One
        until a message has been handled: the first tasks' messages measure the host."""
        if peers <= 0:
            return None
        if self.handling_s is None:
            return 1
        return max(1, math.floor(self.bound_s / (MESSAGES_PER_PEER * peers * max(self.handling_s, 1e-9))))

    def may_start(self, step: int, peers: int, drone: str, waiting: bool) -> bool:
        """Whether ``drone`` may start a task at boundary ``step``; ``waiting``: it has mail to carry. Those
        turned away earlier, still to ask at this boundary, go first."""
        self._at(step)
        self._asked.add(drone)
        limit = self.per_boundary(peers)
        turned_away_at = self._waiting_since.pop(drone, step)  # asking with nothing to carry leaves the line
        since = turned_away_at if waiting else step + 1
        ahead = sum(1 for other, was in self._waiting_since.items() if was < since and other not in self._asked)
        if limit is None or limit - self._started > ahead:
            return True
        if waiting:
            self._waiting_since[drone] = since
        return False

    def started(self, step: int) -> None:
        """A task started at boundary ``step``."""
        self._at(step)
        self._started += 1

    def _at(self, step: int) -> None:
        if step != self._step:  # a drone that did not ask at the last boundary waits for no start
            self._waiting_since = {d: was for d, was in self._waiting_since.items() if d in self._asked}
            self._step, self._started, self._asked = step, 0, set()
