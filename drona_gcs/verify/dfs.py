"""Exhaustive search of a scenario's schedules: iterative deepening, sleep sets, a compact cache.

:func:`search` explores every schedule to a depth bound, then raises the bound by
``deepen``, up to ``max_depth`` or until ``stop()``. ``complete_depth`` in the outcome is
the greatest bound whose every schedule was explored, the figure the paper's Table 3 gives
for ZING. Each bound starts afresh, so a state's depth in the cache is its depth in that
bound's search.

The reductions (:class:`Reductions`; each can be turned off, to measure it and to check it
against the plain search):

* **Sleep sets** (Godefroid, LNCS 1032, 1996) over the independence of :mod:`.por`. A move
  explored from a state is not tried again after a sibling independent of it: that path has
  an explored twin, the same moves with the two swapped, of the same length, which reaches
  the same state and meets the same verdicts (see :mod:`.por`). Sleep sets prune moves,
  never states, and keep path lengths, so a depth bound means what it means without them.
  With the state cache, a state met again is explored again for the moves its earlier visit
  slept and this one does not (Godefroid's sleep sets with state caching), and no earlier
  visit at a greater depth counts.
* **A compact cache**: the cache keeps the 64-bit hash of a state's key, not the key. Two
  states whose keys differ but hash alike would be taken for one, and the second one's
  schedules skipped: under uniform hashing, the chance that any two of ``n`` states collide
  is below ``n**2 / 2**65``: one in 37 million for ``10**6`` states, one in 370,000 for
  ``10**7``. Python's hash is not uniform on every input (``hash(-1) == hash(-2)``): such a
  collision would take two states that differ in nothing else.
* **Copies of one message in flight** (a duplicate) are one move: delivering either leads to
  the same state.
* **A canonical key**: the flown cells enter the key in drone order, not in the order the
  drones first stepped (:meth:`World.state_key_with`), which no monitor or machine reads.

Not done, and why:

* *Symmetry*: drones are not interchangeable. Each has its own start, parking cell, mail and
  battery level; the mixed fleet's last drone runs another configuration; and drone names
  break ties between task ids. Renaming drones maps a state to a state of another scenario,
  never to one of this one, so there is no symmetry to reduce by.
* *Persistent sets*, which would prune states: with a depth bound they are unsound as they
  stand (a schedule of length n that avoids the persistent set is covered only by one of
  length n + 1; Coons et al., OOPSLA 2013), and the paper's figure is a depth.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from drona_gcs.errors import ProtocolViolation
from drona_gcs.verify.monitors import Violation
from drona_gcs.verify.por import Effect, MoveId, effect_of, independent, move_id
from drona_gcs.verify.world import World

if TYPE_CHECKING:
    from drona_gcs.verify.explore import Outcome

DEEPEN = 10  #: how much each round of iterative deepening raises the bound


@dataclass(frozen=True)
class Reductions:
    sleep_sets: bool = True
    compact: bool = True  #: the cache keeps 64-bit hashes, not keys
    same_messages: bool = True  #: copies of one message in flight are one move

    @classmethod
    def none(cls) -> Reductions:
        return cls(False, False, False)


ALL = Reductions()


@dataclass
class _Node:
    world: World
    keys: tuple[Hashable, ...]  #: each stack's key, reused by children that leave the stack alone
    digest: Hashable  #: the state's key, or its hash
    choices: list[int]
    sleep: dict[MoveId, Effect] = field(default_factory=dict)


class _Bounded:
    """One depth-bounded search, with its own cache."""

    def __init__(self, root: World, bound: int, reductions: Reductions, outcome: Outcome,
                 progress: Callable[[Outcome], None]) -> None:
        self.bound, self.reductions, self.outcome, self.progress = bound, reductions, outcome, progress
        self.seen: dict[Hashable, tuple[int, frozenset[MoveId]]] = {}
        self.cut = False  #: some schedule reached the bound unfinished: a deeper bound may see more
        self.liveness_open = bound > root.config.liveness_steps
        keys = tuple(root.stack_key(d) for d in root.config.drones)
        self.stack = [_Node(root, keys, self._digest(root, keys), [])]
        self.violation: tuple[Violation, list[int]] | None = None

    def run(self, stop: Callable[[], bool]) -> bool:
        """True when every schedule to the bound was explored (or a violation found), False at ``stop()``."""
        while self.stack:
            if stop():
                return False
            node = self.stack.pop()
            only = self._admit(node)
            if only is False:
                continue
            depth = len(node.choices)
            if depth == self.bound or node.world.finished:
                self.cut |= not node.world.finished
                self.outcome.schedules += 1
                if self.outcome.schedules % 256 == 0:
                    self.outcome.states = len(self.seen)
                    self.progress(self.outcome)
                continue
            if not self._expand(node, None if only is True else only):
                return True
        self.outcome.states = len(self.seen)
        return True

    def _admit(self, node: _Node) -> frozenset[MoveId] | bool:
        """Record the visit; False if an earlier one covers it, True to explore every move it does not
        sleep, or the moves to explore (those an earlier visit at no greater depth slept)."""
        depth, asleep = len(node.choices), frozenset(node.sleep)
        entry = self.seen.get(node.digest)
        if entry is None or depth < entry[0]:
            self.seen[node.digest] = (depth, asleep)
            return True
        explored_at, slept = entry
        if slept <= asleep:
            return False
        node.sleep = {k: e for k, e in node.sleep.items() if k in slept}
        if explored_at == depth:
            self.seen[node.digest] = (depth, slept & asleep)
        return slept - asleep

    def _expand(self, node: _Node, only: frozenset[MoveId] | None) -> bool:
        """Push the node's children; False on a violation."""
        world, sleep, children = node.world, dict(node.sleep), []
        for mid, index, move in self._moves(world):
            if mid in sleep or (only is not None and mid not in only):
                continue
            child = world.clone_for(move)
            try:
                child.apply(move)
            except (Violation, ProtocolViolation) as exc:
                found = exc if isinstance(exc, Violation) else Violation("crash", str(exc))
                self.violation = (found, [*node.choices, index])
                return False
            self.outcome.transitions += 1
            child_sleep: dict[MoveId, Effect] = {}
            if self.reductions.sleep_sets:
                effect = effect_of(world, child, move)
                finished = child.finished
                child_sleep = {u: e for u, e in sleep.items()
                               if independent(e, effect, world, finished, self.liveness_open)}
                sleep[mid] = effect
            touched = world.touched_by(move)
            keys = tuple(child.stack_key(d) if d in touched else k
                         for d, k in zip(world.config.drones, node.keys, strict=True))
            kid = _Node(child, keys, self._digest(child, keys), [*node.choices, index], child_sleep)
            if not self._covered(kid):
                children.append(kid)
        self.stack.extend(reversed(children))
        return True

    def _moves(self, world: World) -> list[tuple[MoveId, int, tuple[str, int]]]:
        """The enabled moves with their names and indices; one of each name unless told otherwise."""
        out, names = [], set()
        for index, move in enumerate(world.enabled()):
            mid = move_id(world, move)
            if not self.reductions.same_messages:
                mid = (mid, index)
            if mid not in names:
                names.add(mid)
                out.append((mid, index, move))
        return out

    def _covered(self, node: _Node) -> bool:
        entry = self.seen.get(node.digest)
        return entry is not None and entry[0] <= len(node.choices) and entry[1] <= node.sleep.keys()

    def _digest(self, world: World, keys: tuple[Hashable, ...]) -> Hashable:
        key = world.state_key_with(keys)
        return hash(key) if self.reductions.compact else key


def search(make_world: Callable[[], World], replay: Callable[[list[int]], list[str]], max_depth: int,
           outcome: Outcome, stop: Callable[[], bool] = lambda: False,
           progress: Callable[[Outcome], None] = lambda o: None, deepen: int = DEEPEN,
           reductions: Reductions = ALL) -> Outcome:
    """Iterative deepening to ``max_depth``; ``replay(choices)`` gives a violation's trace.

    ``outcome.states`` is the number of distinct states of the deepest bound searched,
    ``outcome.transitions`` the moves tried over every bound."""
    for bound in bounds(max_depth, deepen):
        outcome.states = 0
        run = _Bounded(make_world(), bound, reductions, outcome, progress)
        finished = run.run(stop)
        if run.violation is not None:
            outcome.violation, outcome.choices = run.violation
            outcome.trace = replay(outcome.choices)
            return outcome
        if not finished:
            return outcome
        outcome.complete_depth = bound if run.cut else max_depth
        outcome.complete_states = outcome.states
        if outcome.complete_depth >= max_depth:
            outcome.exhausted = True
            break
    progress(outcome)
    return outcome


def bounds(max_depth: int, deepen: int) -> Iterator[int]:
    """The depth bounds, in order: 2, 4, 8, ... below ``deepen`` (so that a search that cannot finish
    the first big bound still says how deep it got), then ``deepen``, ``2 * deepen``, ... to ``max_depth``."""
    deepen, small = max(deepen, 1), 2
    while small < min(deepen, max_depth):
        yield small
        small *= 2
    yield from range(deepen, max_depth, deepen)
    yield max_depth
