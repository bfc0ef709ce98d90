"""How many tasks the drones of one host start at one boundary.

Every drone of a host decides at the same boundary, before any load shows: given mail at once, 64 drones
of a process started 64 tasks together, their rounds put the process seconds behind, and its vehicles and
its peers' news went late with it (found over 128 agents on 2 cores). A host starts only as many tasks
at a boundary as it can coordinate within the lag bound it holds itself to.

The cost of a task to each host: every peer handles its proposal and its decision, and its drone handles
every peer's ack, 3 (N - 1) messages in all. With every host starting ``k`` tasks a boundary, each host
handles about ``3 k (N - 1)`` of them in all; each takes what handling one took lately (measured on the
loop, waits for the CPU included: a host short of CPU starts fewer).

The rounds started together also wait on each other: Protocol 1 settles them one after the other, in
line, and a round's messages cross the network and every host's loop. So a host also keeps its rounds
within a latency target, as a congestion window does: a boundary whose rounds all ended within it lets
one more task start (if one more, as many rounds later, still fits), and a round that took longer cuts
the starts in the ratio of the target to what it took.
"""

from __future__ import annotations

import math

#: Messages one task makes each host handle per peer: its proposal, its decision, and the acks.
MESSAGES_PER_PEER = 3
#: Weight of the newest handling time in the running mean (about the last 50 messages).
SMOOTHING = 0.02
KEEP_UP_TAU = 0.25  #: a host behind by more than this share of tau starts no task
ROUND_TAU = 0.2  #: the share of tau a round should take, task to plan flown (100 ms at tau 0.5 s)


class TaskBudget:
    """The tasks a host's drones may start at one boundary (shared by the host's agents). The drones turned
    away with mail to carry go first, the longest turned away first: the drones ask in the same order at
    every boundary, and the first ones must not take every start."""

    def __init__(self, bound_s: float, round_target_s: float = math.inf) -> None:
        self.bound_s = bound_s  #: how far behind the host lets itself fall
        self.round_target_s = round_target_s  #: how long its rounds may take (inf: any time)
        self.handling_s: float | None = None  #: running mean of handling one protocol message
        self.window = 1  #: the tasks a boundary that kept the rounds within their target lately
        self._longest_s = 0.0  #: the longest round that ended since the last boundary
        self._step: int | None = None
        self._started = 0  #: tasks started at ``_step``
        self._asked: set[str] = set()  #: the drones that asked at ``_step``
        self._waiting_since: dict[str, int] = {}  #: drones with mail turned away: since when

    def handled(self, seconds: float) -> None:
        """A protocol message took ``seconds`` to handle."""
        mean = self.handling_s
        self.handling_s = seconds if mean is None else mean + SMOOTHING * (seconds - mean)

    @classmethod
    def of_period(cls, tau_s: float) -> TaskBudget:
        return cls(KEEP_UP_TAU * tau_s, ROUND_TAU * tau_s)

    def round_ended(self, took_s: float) -> None:
        """A round of this host's ended (a plan flown, or none found) ``took_s`` after its task started."""
        self._longest_s = max(self._longest_s, took_s)

    def per_boundary(self, peers: int) -> int | None:
        """How many tasks may start at one boundary with ``peers`` peers (None: no bound, with none). One
        until a message has been handled: the first tasks' messages measure the host."""
        if peers <= 0:
            return None
        if self.handling_s is None:
            return 1
        cpu = max(1, math.floor(self.bound_s / (MESSAGES_PER_PEER * peers * max(self.handling_s, 1e-9))))
        return cpu if math.isinf(self.round_target_s) else min(cpu, self.window)

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
            self._adjust_window()
            self._step, self._started, self._asked = step, 0, set()

    def _adjust_window(self) -> None:
        """A round's latency grows with the rounds in line with it: one more start a boundary only if the
        longest round, one part in ``window`` longer, stays within the target; fewer once one did not."""
        longest, self._longest_s = self._longest_s, 0.0
        if longest > self.round_target_s:
            self.window = max(1, math.floor(self.window * self.round_target_s / longest))
        elif self._started >= self.window and 0 < longest * (self.window + 1) / self.window <= self.round_target_s:
            self.window += 1
