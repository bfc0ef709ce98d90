"""When two moves of the world commute: the independence relation behind the search's sleep sets.

A move's :class:`Effect` is what it did from one state, read off the world before and
after it (:func:`effect_of`). Two moves are *independent* at a state (:func:`independent`)
when each leaves alone what the other reads, neither disables the other, and the monitors
judge them alike in either order. Then both orders end in the same state and report the same
violations, and the search needs to try only one. Each rule below says which part of
:meth:`World.apply` it stands for; :func:`independent` lists the cases.

What a move reads and writes (from ``World.apply`` and ``Monitors``):

* a *drone's private state*: its stack, clock (``steps``), battery, and its entries in the
  monitors (history, committed plan, waiting and carried mail). A delivery touches the
  receiver's, a step the stepping drone's, an injection the drone given the mail. A move
  that touches another's drone is dependent on it.
* monitor (a) runs when a drone starts a plan: it reads every drone's committed plan and
  writes its own. Two moves that both planned are dependent. A move planned when it changed
  its drone's committed plan (each plan is a new trajectory object).
* the bag of messages in flight: a move adds its messages and a delivery takes its own; the
  order of the bag is not part of the state (the key sorts it). A move that posts a message
  due by step ``d`` disables every step to a step above ``d`` (the scheduler's deadline).
* monitor (b) reads every drone's flown cells, but it only judges a step once every drone
  has flown its whole window: what it decides about a step is fixed by then, so two steps
  judge the same steps alike in either order (only which of the two judges a step differs).
* the environment's queue, the vehicles down, the fault budget: a move that changes any of
  them (a cancel, a vehicle down, mail handed back), and any move but a delivery, a step, an
  injection and a duplicate, is dependent on every move. A duplicate
  spends the shared budget: two duplicates, or a duplicate and the delivery of its
  message, are dependent.
* monitor (d) reads every clock and ``last_injection_step``; it can fire only once
  ``min(steps) - last_injection_step`` exceeds ``liveness_steps``, and ``min(steps)`` is below
  the depth. When the bound is deeper than ``liveness_steps``, injections and steps are all
  dependent (the search passes ``liveness_open``).
* a finished world is a leaf of the search: a move after which the world may be finished is
  dependent on every other, since the other could not follow it.
"""

from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass

from drona_gcs.verify.world import Transition, World

MoveId = Hashable
#: The moves whose effects are tracked finely; any other (a cancel, a vehicle down, an agent
#: crashed or restarted, and any kind added later) is dependent on every move.
_TRACKED = frozenset({"deliver", "step", "inject", "duplicate"})


@dataclass(frozen=True)
class Effect:
    """What one move did from one state, as far as independence cares."""

    drones: frozenset[str]  #: whose private state it read and wrote
    shared: bool  #: it changed state every move may read (queue, vehicles down, cancels)
    planned: bool  #: monitor (a) may have run: it read every committed plan
    message: MoveId | None  #: the message in flight it delivered or duplicated
    duplicated: bool
    posted: int  #: messages it sent
    earliest: int | None  #: the smallest deadline among them
    clock: int | None  #: a step: the step the clock moved to (a step needs it within every deadline)
    injects: int  #: requests it took from the environment


def move_id(world: World, move: Transition) -> MoveId:
    """A name for ``move`` that does not depend on the path to ``world``: a message by what it
    says, not by its number (two copies of a message are one move: they lead to one state)."""
    kind, arg = move
    return (kind, *_content(world, arg)) if kind in ("deliver", "duplicate") else move


def _content(world: World, seq: int) -> tuple[Hashable, ...]:
    m = next(m for m in world.inflight if m.seq == seq)
    return (m.sender, m.to, m.message, m.deadline)


def effect_of(before: World, after: World, move: Transition) -> Effect:
    kind, arg = move
    drones = before.touched_by(move)
    if kind == "inject":  # to the drone the mail went to, wherever the service sent it
        drones = frozenset(d for d in drones if after.stacks[d] is not before.stacks[d]
                           and after.stack_key(d) != before.stack_key(d))
    one = len(drones) == 1 or kind == "duplicate" or (kind == "step" and arg < 0)  # else: where did it go?
    shared = kind not in _TRACKED or not one
    shared = shared or _untracked_change(before, after, kind, drones)
    posted = [m for m in after.inflight if m.seq > before.sent]
    # Monitor (a) runs on a StartExecuting, which commits the plan's trajectory: a new object, as
    # the planner builds one per plan (and so does the protocol's own record of it).
    planned = any(after.monitors.committed.get(d) is not before.monitors.committed.get(d)
                  or after.stacks[d].protocol.trajectory is not before.stacks[d].protocol.trajectory
                  for d in drones)
    message = _content(before, arg) if kind in ("deliver", "duplicate") else None
    clock = after.steps[before.config.drones[arg]] if kind == "step" and arg >= 0 else None
    if kind == "step" and arg < 0:
        clock = min(after.steps.values())
    return Effect(drones, shared, planned, message, kind == "duplicate", len(posted),
                  min((m.deadline for m in posted), default=None), clock, after.injected - before.injected)


#: What of the world the effects track; a change to anything else makes a move shared.
_WORLD_TRACKED = frozenset({"stacks", "steps", "battery", "net", "monitors", "trace", "injected",
                            "last_injection_step", "config"})
#: Monitors' fields that only grow by commutative adds (sets of mail ids) or that (b) advances alike in
#: either order of two steps (see the module's docstring).
_MONITORS_COMMUTING = frozenset({"config", "judged", "delivered", "settled"})


def _untracked_change(before: World, after: World, kind: str, drones: frozenset[str]) -> bool:
    """Whether the move changed world state beyond its drones' (the queue of handed-back mail, the
    vehicles down or crashed, the fault budget, and whatever is added later)."""
    old = vars(before)
    for name, value in vars(after).items():
        if name in _WORLD_TRACKED or (name == "used" and kind == "duplicate"):
            continue
        if old.get(name) != value:
            return True
    old = vars(before.monitors)
    for name, value in vars(after.monitors).items():
        if name in _MONITORS_COMMUTING:
            continue
        was = old.get(name)
        if isinstance(value, dict) and isinstance(was, dict):
            if any(value.get(k) is not was.get(k) and value.get(k) != was.get(k)
                   for k in value.keys() | was.keys() if k not in drones):
                return True
        elif value is not was and value != was:
            return True
    return False


def independent(u: Effect, t: Effect, before: World, t_finished: bool, liveness_open: bool) -> bool:
    """Whether ``u`` and ``t``, both enabled at ``before``, commute there with the same verdicts.
    ``t_finished``: the world is finished after ``t``."""
    if u.shared or t.shared or u.drones & t.drones:
        return False  # the environment's queue, faults, or the same drone's state
    if u.planned and t.planned:
        return False  # monitor (a): each reads the plan the other commits
    if (u.message is not None and u.message == t.message) or (u.duplicated and t.duplicated):
        return False  # a duplicate of a delivered message, or two spending one budget
    if _disables(u, t) or _disables(t, u):
        return False
    if liveness_open and (u.injects or t.injects) and (u.clock is not None or t.clock is not None):
        return False  # monitor (d) could fire within the bound
    if liveness_open and u.clock is not None and t.clock is not None:
        return False
    return not (t_finished or may_finish(before, u))


def _disables(a: Effect, b: Effect) -> bool:
    """``a`` posts a message due before the step ``b`` makes."""
    return a.earliest is not None and b.clock is not None and b.clock > a.earliest


def may_finish(before: World, u: Effect) -> bool:
    """Whether the world may be finished after ``u``: every request given, nothing in flight
    (what :attr:`World.finished` needs, and more)."""
    left = len(before.inflight) + u.posted + (1 if u.duplicated else -1 if u.message is not None else 0)
    return before.injected + u.injects == len(before.config.requests) and left == 0
