"""The tester's monitors: the properties the paper's model checker verified, and ours.

Each states its property in its own simple code from what the drones did (their
actions) and what the environment did (the mail it gave, the steps it took), and
shares nothing with the code it judges: no production ranking, no protocol query.

(a) every plan avoided every other drone, and each with what that drone was
    committed to when the plan starts: the trajectory it last started executing
    (beyond its end, its last cell), or its start cell before any; as what the drone
    answered, or as its proposal, not decided yet (the plan's Psi names it ``<drone>?``);
    or else the plan that drone is committed to (or cut short since, while this drone has not
    heard of it yet) was made against this one, proposed then; or that drone made its plan while it
    held this drone as gone, then held this plan (acked it) while committed to its own, and the two
    keep clear of each other: the views met there;
(b) no two drones meet in what the executors actually occupy: at no step t is a drone in a cell
    another occupies at a step within Delta of t, nor do two swap cells in that window; a vehicle
    down stays in its cell, and a drone that enters that cell after the vehicle came down
    breaks (b) unless it entered before the news reached it (no protocol could know: the
    stack's part is never to enter it once told). Once every drone knows a drone's clock is
    off by k steps, the window for that drone and any other is max(Delta, 1) + |k|, from the
    steps each was at then (at Delta 0 the clock off steps on its own: a step apart at times);
(c) each drone starts its mail in priority order: never one while a more urgent
    one (higher priority, or equal and sent by the environment earlier) waits, unstarted,
    with a path open to it (around obstacles, vehicles down, drones resting, and every cell of
    the plan of a drone it was told has its clock off);
(d) every request is delivered within a bound once the environment stops (its last request, an
    agent's restart or a partition's heal; but one
    cancelled, lost on board a vehicle that came down, cleared for pickup to an agent that
    crashed (the service cannot tell whether it is on board), or cut off from its drop-off by
    obstacles and the vehicles down: no path from the drone carrying it, or from any drone in
    service through its pickup; a drone off every charger whose battery affords no move is down);
(e) no battery drops below the safe threshold;
(f) a drone carrying mail flies only to its drop-off, or to a charger, or off a way a peer asked
    it to leave (its request named the cell the drone rested on), or short of the rest of its plan
    when a vehicle down, a drone it heard brake, a drone it saw leave, or one it was told has its
    clock off (on any of its last plans) may hold a cell of that rest;
(g) each executor flies its plan: at every step, the cell the plan it last started puts it
    in (its last cell once the plan is over), one cell a period;
(h) one owner per mail: no drone takes a mail on board while another has it on board, and no
    mail is delivered twice.

A violation raises :class:`Violation`, which ends the schedule. (a), (c), (f) and (h) are judged here;
(b) and (g) in :mod:`.separation`, (d) and (e) in :mod:`.liveness`; what they share, in :mod:`.verdicts`.
"""

from __future__ import annotations

from collections.abc import Hashable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from drona_gcs.motion import Trajectory
from drona_gcs.stack.mail import MailDelivered, MailLost, MailPickedUp, MailRejected, MailRequest, MailStarted
from drona_gcs.stack.messages import PlanAck, TaskId
from drona_gcs.stack.protocol import Braked, Grounded, Present, Send, StartExecuting
from drona_gcs.verify.liveness import DeliveryMonitor, Flier, Reach
from drona_gcs.verify.separation import Meeting, SeparationMonitor, meetings
from drona_gcs.verify.verdicts import Violation, added, cell_at, cell_text, cells_text, same_future
from drona_gcs.workspace import Cell

if TYPE_CHECKING:
    from drona_gcs.verify.config import WorldConfig

__all__ = ["RECENT_PLANS", "SKEW_STEPS", "Flier", "Meeting", "Monitors", "Reach", "Violation", "cell_text",
           "cells_text", "same_future"]

#: How many steps beyond Delta the tester puts a clock found off (its scheduler keeps to that offset).
SKEW_STEPS = 1
#: (f) How many of a drone's last plans a peer may still know as what it flies (a decision may be late).
RECENT_PLANS = 3


@dataclass
class Monitors(SeparationMonitor, DeliveryMonitor):
    """Every container holds immutable values only, so that a one-level copy is a clone."""

    config: WorldConfig
    delivered: set[str] = field(default_factory=set)
    settled: set[str] = field(default_factory=set)  #: delivered, cancelled, or lost with its vehicle
    history: dict[str, list[Cell]] = field(default_factory=dict)
    judged: int = -1  #: the last step (b) has judged for every pair
    committed: dict[str, Trajectory] = field(default_factory=dict)  #: (a) each drone's last started plan
    waiting: dict[str, tuple[tuple[int, MailRequest], ...]] = field(default_factory=dict)  #: (c) given, unstarted
    carrying: dict[str, MailRequest] = field(default_factory=dict)  #: (f) mail on board, per drone
    departed: dict[str, frozenset[str]] = field(default_factory=dict)  #: (a) peers each drone saw leave
    down: tuple[tuple[str, Cell], ...] = ()  #: (c) drones whose vehicle came down, and where
    #: (b) vehicles that came down, from which step
    stopped: dict[str, int] = field(default_factory=dict)
    #: (a) what a drone down, or braked, was committed to before; (a, b) who has heard of it, at which
    #: of its own steps: (observer, drone) -> step
    before_news: dict[str, Trajectory] = field(default_factory=dict)
    #: (a) where a drone said it rests, at the end of the plan it is committed to: that plan, told so
    rests: dict[str, Trajectory] = field(default_factory=dict)
    #: (a) what each drone's committed plan was made against of each peer: its proposal where it held one,
    #: else its answer: (drone, peer) -> that trajectory
    made_against: dict[tuple[str, str], Trajectory] = field(default_factory=dict)
    #: (a) the same, for a plan cut short since (braked, or its vehicle came down): until the news is heard
    cut_made_against: dict[tuple[str, str], Trajectory] = field(default_factory=dict)
    #: (a) each drone's last plan started, with the peers it held as gone then
    planned_without: dict[str, tuple[Trajectory, frozenset[str]]] = field(default_factory=dict)
    #: (a) what each drone was committed to when it last held a peer's proposal: (drone, proposer) -> (task, plan)
    held_proposal: dict[tuple[str, str], tuple[TaskId, Trajectory]] = field(default_factory=dict)
    #: (f) the plans drones cut short (braked) and hold at the end of, until their next plan
    cuts: dict[str, Trajectory] = field(default_factory=dict)
    #: (f) each drone's last plans: a peer that heard none since may still hold any as what it flies
    flown: dict[str, tuple[Trajectory, ...]] = field(default_factory=dict)
    told: dict[tuple[str, str], int] = field(default_factory=dict)
    #: (f) the ways each drone was asked to leave since its last plan
    asked_to_clear: tuple[tuple[str, frozenset[Cell]], ...] = ()
    #: (c, f) the drones each drone's clock check found off; (b) each clock every drone knows is off, with
    #: every drone's step then (from which that pair's window widens)
    found_off: dict[str, frozenset[str]] = field(default_factory=dict)
    drifts: tuple[tuple[str, int, tuple[tuple[str, int], ...]], ...] = ()  #: (drone, offset, steps then)

    def __post_init__(self) -> None:
        for drone, start in zip(self.config.drones, self.config.starts, strict=True):
            self.committed[drone] = Trajectory(0, (start,))
        self.reach = Reach(self.config.workspace)  # shared by clones: it only caches

    def key(self) -> Hashable:
        """What of the monitors' own state decides future verdicts (for the DFS's state cache)."""
        return (tuple(sorted((d, t.start_step, t.cells) for d, t in self.committed.items())),
                tuple(sorted((d, tuple(r.id for _, r in w)) for d, w in self.waiting.items())),
                tuple(sorted((d, r.id) for d, r in self.carrying.items())),
                tuple(sorted((d, tuple(sorted(p))) for d, p in self.departed.items())),
                tuple(sorted((d, t.start_step, t.cells) for d, t in self.before_news.items())),
                tuple(sorted((d, t.start_step, t.cells) for d, t in self.rests.items())),
                tuple(sorted((d, t.start_step, t.cells) for d, t in self.made_against.items())),
                tuple(sorted((d, t.start_step, t.cells) for d, t in self.cut_made_against.items())),
                tuple(sorted((d, t.start_step, t.cells, gone) for d, (t, gone) in self.planned_without.items())),
                tuple(sorted((k, task, t.start_step, t.cells) for k, (task, t) in self.held_proposal.items())),
                tuple(sorted((d, t.start_step, t.cells) for d, t in self.cuts.items())),
                tuple(sorted((d, tuple((t.start_step, t.cells) for t in ts)) for d, ts in self.flown.items())),
                tuple(sorted(self.told.items())), tuple(sorted(self.stopped.items())),
                tuple(sorted((d, tuple(sorted(w))) for d, w in self.asked_to_clear)),
                tuple(sorted(self.found_off.items())), self.drifts)

    def given_mail(self, drone: str, request: MailRequest) -> None:
        """The environment gave ``request`` to ``drone`` (again, if another handed it back)."""
        sent = next(i for i, r in enumerate(self.config.requests) if r.id == request.id)
        self.waiting[drone] = (*self.waiting.get(drone, ()), (sent, request))

    def action(self, drone: str, action: object) -> None:
        if isinstance(action, StartExecuting):
            self._consistent(drone, action)
            self._carried_to_its_dropoff(drone, action)
            self._commit(drone, action.trajectory)
            self.made_against.update(self._made_against(drone, action.psi))
            self.planned_without[drone] = (action.trajectory, self.departed.get(drone, frozenset()))
            self.rests.pop(drone, None)
            self.cuts.pop(drone, None)
            self.flown[drone] = (*self.flown.get(drone, ())[-(RECENT_PLANS - 1):], action.trajectory)
        elif isinstance(action, Braked):
            self._news(drone, action.trajectory)
            self.cuts[drone] = action.trajectory
        elif isinstance(action, Present) and not action.braked and action.trajectory != self.committed[drone]:
            self._rests(drone, action.trajectory)
        elif isinstance(action, Grounded) and drone not in dict(self.down):
            self._rests(drone, action.trajectory)  # its battery affords no move: it rests where its plan ended
            self.down = (*self.down, (drone, action.trajectory.last))  # held for good, as a vehicle down
        elif isinstance(action, Send) and isinstance(action.message, PlanAck):
            task = action.message.task_id
            self.held_proposal[(drone, task.drone)] = (task, self.committed[drone])
        elif isinstance(action, MailStarted):
            self._in_order(drone, action.request)
        elif isinstance(action, MailPickedUp):
            self._one_owner(drone, action.request)
            self.carrying[drone] = action.request
        elif isinstance(action, MailDelivered):
            if action.request.id in self.delivered:
                raise Violation("h", f"{drone} delivered {action.request.id}, delivered before")
            self.delivered.add(action.request.id)
            self.settled.add(action.request.id)
            self.carrying.pop(drone, None)
        elif isinstance(action, MailLost):
            self.settled.add(action.request.id)
            self._forget(drone, action.request)
        elif isinstance(action, MailRejected):
            self._forget(drone, action.request)

    def given_up(self, drone: str, request: MailRequest) -> None:
        """The service failed ``request``, held as ``drone``'s: it is not delivered, and not owed (d)."""
        self.settled.add(request.id)
        self._forget(drone, request)

    # (h)
    def _one_owner(self, drone: str, request: MailRequest) -> None:
        others = sorted(d for d, r in self.carrying.items() if r.id == request.id and d != drone)
        if others:
            raise Violation("h", f"{drone} took {request.id} on board, which {others[0]} has on board")

    def cancelled(self, drone: str, request: MailRequest) -> None:
        """The environment took ``request`` back from ``drone``'s queue."""
        self.settled.add(request.id)
        self._forget(drone, request)

    # (a)
    def _commit(self, drone: str, trajectory: Trajectory) -> None:
        """``drone`` flies ``trajectory`` from now: what its last plan was made against no longer counts."""
        self.committed[drone] = trajectory
        self.made_against = {k: t for k, t in self.made_against.items() if k[0] != drone}
        self.cut_made_against = {k: t for k, t in self.cut_made_against.items() if k[0] != drone}

    def _made_against(self, drone: str, psi: Mapping[str, Trajectory]) -> dict[tuple[str, str], Trajectory]:
        """A peer's plan later flown is one ``drone``'s plan was made against when it is the proposal held, or
        (none held) the answer: a round that plans anew what the drone flies can end in that very plan."""
        made = {(drone, key): t for key, t in psi.items() if key in self.config.drones}
        made.update({(drone, key[:-1]): t for key, t in psi.items() if key.endswith("?")})
        return made

    def _consistent(self, drone: str, action: StartExecuting) -> None:
        since = action.trajectory.start_step - self.config.delta - 1
        for peer in self.config.drones:
            if peer == drone:
                continue
            if peer in self.departed.get(drone, ()):
                self._clear_of(drone, action, peer, since)
                continue
            used = action.psi.get(peer)
            if used is None:
                raise Violation("a", f"{drone} planned task {action.task.id} without {peer}")
            proposed = action.psi.get(f"{peer}?")
            if proposed is not None and same_future(proposed, self.committed[peer], since):
                continue
            if self.made_against.get((peer, drone)) == action.trajectory or self._views_met(drone, peer, action):
                continue
            rest = self.rests.get(peer)  # (the same positions: a rest's stamp says nothing)
            if (not same_future(used, self.committed[peer], since) and not (rest and same_future(used, rest, since))
                    and not self._not_told_yet(drone, peer, (used, proposed), since, action.trajectory)):
                raise Violation("a", f"{drone} planned task {action.task.id} with a stale trajectory of "
                                     f"{peer}: used {cells_text(used)}, but {peer} is committed to "
                                     f"{cells_text(self.committed[peer])}")

    def _views_met(self, drone: str, peer: str, action: StartExecuting) -> bool:
        """``peer`` made the plan it is committed to while it held ``drone`` as gone, and held this plan
        (acked it) while committed to that one: where the two views met, the plan keeps clear of it."""
        committed = self.committed[peer]
        made = self.planned_without.get(peer)
        return (made is not None and made[0] == committed and drone in made[1]
                and self.held_proposal.get((peer, drone)) == (action.task.id, committed)
                and keeps_clear(action.trajectory, committed, self.config.delta))

    def _not_told_yet(self, drone: str, peer: str, used: tuple[Trajectory, Trajectory | None], since: int,
                      plan: Trajectory) -> bool:
        """``peer``'s vehicle came down, or it braked, and ``drone`` used (as its answer, or its proposal)
        what it was committed to before, or ``plan`` is what that was made against: fine until the news
        reached it (the plan it flies is then planned anew if it must be)."""
        earlier = self.before_news.get(peer)
        return (earlier is not None and (drone, peer) not in self.told
                and (any(u is not None and same_future(u, earlier, since) for u in used)
                     or self.cut_made_against.get((peer, drone)) == plan))

    def heard_news(self, observer: str, peer: str, step: int) -> None:
        """``observer``, at its step ``step``, heard that ``peer``'s vehicle came down, or that it braked."""
        self.told = {**self.told, (observer, peer): step}

    def _rests(self, drone: str, rest: Trajectory) -> None:
        """``drone`` says it rests where it is, at the end of the plan it is committed to (its clock is off,
        and peers hold every cell of that plan for good; or it is grounded for good): that plan flown, the
        rest stands for it."""
        flown = self.committed[drone]
        moves = set(flown.cells) != {flown.last}  # (a drone at rest says so again: to a peer that joins)
        if rest.cells != (flown.last,) or (moves and rest.start_step < flown.end_step):
            raise Violation("a", f"{drone} says it rests at {cells_text(rest)}, elsewhere than where the plan it "
                                 f"is committed to ends, or before: {cells_text(flown)}")
        self.rests[drone] = rest

    def _news(self, drone: str, now: Trajectory) -> None:
        """``drone`` flies ``now`` instead of what it was committed to, and nobody has heard yet."""
        self.rests.pop(drone, None)
        self.before_news[drone] = self.committed[drone]
        cut = {k: t for k, t in (*self.made_against.items(), *self.cut_made_against.items()) if k[0] == drone}
        self._commit(drone, now)
        self.cut_made_against = {**self.cut_made_against, **cut}
        self.told = {k: v for k, v in self.told.items() if k[1] != drone}

    def _clear_of(self, drone: str, action: StartExecuting, peer: str, since: int) -> None:
        """A peer seen to leave may have stopped anywhere on what it was committed to: a plan made
        since stays out of every such cell (but the one it starts in)."""
        committed = self.committed[peer]
        held = {cell_at(committed, t) for t in range(since, max(since, committed.end_step) + 1)}
        crossed = held & added(self.committed[drone], action.trajectory)
        if crossed:
            raise Violation("a", f"{drone} planned task {action.task.id} through {sorted(crossed)}, where {peer}, "
                                 f"gone, may have stopped: it was committed to {cells_text(committed)}")

    def left(self, observer: str, peer: str) -> None:
        """``observer`` saw ``peer`` leave (its agent's liveliness went)."""
        self.departed[observer] = self.departed.get(observer, frozenset()) | {peer}

    def heard_from(self, observer: str, peer: str) -> None:
        """``observer`` heard from ``peer`` (it joined, or a message of it came): alive."""
        self.departed[observer] = self.departed.get(observer, frozenset()) - {peer}

    def clock_verdict(self, drone: str, off: frozenset[str]) -> None:
        """``drone``'s clock check found the clocks of ``off`` beyond the fleet's bound (its own among them,
        or not)."""
        self.found_off = {**self.found_off, drone: off}

    # (c)
    def _in_order(self, drone: str, started: MailRequest) -> None:
        queue = self.waiting.get(drone, ())
        mine = next((order for order, r in queue if r.id == started.id), None)
        if mine is None:
            return  # started before: a leg flown again is no new start
        before = [r for order, r in queue if (r.priority > started.priority
                  or (r.priority == started.priority and order < mine)) and self._open_to(drone, r)]
        if before:
            raise Violation("c", f"{drone} started mail {started.id} (priority {started.priority}) before "
                                 f"{before[0].id} (priority {before[0].priority})")
        self._forget(drone, started)

    def _open_to(self, drone: str, request: MailRequest) -> bool:
        """Whether a path joins ``drone`` to the mail's pickup and on to its drop-off, around obstacles,
        vehicles down and drones resting (their last plans over): a mail walled off may wait."""
        history = self.history.get(drone) or [self.config.starts[self.config.drones.index(drone)]]
        here, now = history[-1], len(history) - 1
        down = dict(self.down)
        off = {c for p in self.found_off.get(drone, frozenset()) - {drone} for c in self.committed[p].cells}
        walls = frozenset({*off, *(down.get(p, t.cells[-1]) for p, t in self.committed.items()
                                   if p != drone and (t.end_step <= now or p in down))}) - {here}
        return (here in self._distances(request.pickup, walls)
                and request.pickup in self._distances(request.dropoff, walls))

    def restarted(self, drone: str, cell: Cell, step: int) -> None:
        """``drone``'s agent started again, its vehicle holding ``cell``: its plan is to stay (a, g)."""
        self._commit(drone, Trajectory.stationary(cell, step))

    def vehicle_down(self, drone: str, cell: Cell, step: int) -> None:
        """``drone``'s vehicle came down in ``cell`` at ``step``: it stays there, whatever its plan
        said, and plans must avoid it there (a)."""
        self.down = (*self.down, (drone, cell))
        self.stopped[drone] = step
        self._news(drone, Trajectory.stationary(cell, step))

    def _forget(self, drone: str, request: MailRequest) -> None:
        self.waiting[drone] = tuple((o, r) for o, r in self.waiting.get(drone, ()) if r.id != request.id)
        if drone in self.carrying and self.carrying[drone].id == request.id:
            del self.carrying[drone]

    # (f)
    def _carried_to_its_dropoff(self, drone: str, action: StartExecuting) -> None:
        """(f), and the one exception: a peer asked it to leave a way it rested on, for a cell off it."""
        mail = self.carrying.get(drone)
        start, goal = action.trajectory.cells[0], action.trajectory.cells[-1]
        ways = [w for d, w in self.asked_to_clear if d == drone]
        self.asked_to_clear = tuple((d, w) for d, w in self.asked_to_clear if d != drone)
        if mail is None or goal == mail.dropoff or goal in self.config.workspace.charging_stations:
            return
        if any(start in way and goal not in way for way in ways):
            return
        if self._stops_short(drone, action.trajectory):
            return
        raise Violation("f", f"{drone} carries mail {mail.id} (drop-off {cell_text(mail.dropoff)}) but flies to "
                             f"{cell_text(goal)}, neither its drop-off nor a charger, nor off a way it was asked to "
                             f"clear, nor short of a cell held for good")

    def _stops_short(self, drone: str, new: Trajectory) -> bool:
        """The plan flown, made new from some step on, ends short of its goal: fine when the rest of
        the old one crossed a cell a vehicle down, a drone this one heard brake (where it holds), or a
        drone this one saw leave, may hold for good: on what it is committed to, or on what it was
        before a brake this drone has not heard of."""
        old = self.committed[drone]
        horizon = max(new.end_step, old.end_step)  # a stop where it stands is one cell: it parts after it
        parting = next((t for t in range(new.start_step, horizon + 1) if cell_at(new, t) != cell_at(old, t)), None)
        if new.start_step >= old.end_step or parting is None or parting <= new.start_step:
            return False  # not the rest of the plan flown made new
        rest = {cell_at(old, t) for t in range(parting, old.end_step + 1)}
        held = {c for _, c in self.down}
        held |= {cut.last for peer, cut in self.cuts.items() if (drone, peer) in self.told}
        for peer in self.found_off.get(drone, frozenset()) - {drone}:  # its steps are not ours: all of it
            earlier = self.before_news.get(peer)
            held |= {*self.committed[peer].cells, *(earlier.cells if earlier is not None else ())}
            held |= {c for plan in self.flown.get(peer, ()) for c in plan.cells}
        for peer in self.departed.get(drone, ()):
            earlier = self.before_news.get(peer) if (drone, peer) not in self.told else None
            for gone in (self.committed[peer], *([earlier] if earlier is not None else [])):
                held |= set(gone.cells)  # it may have stopped anywhere on it, from when it was last heard
        return bool(rest & held)

    def asked_to_leave(self, drone: str, way: tuple[Cell, ...]) -> None:
        """A peer's request asked the drones resting on ``way`` to leave it, ``drone`` among them: it may
        answer any request since its last plan."""
        asked = (drone, frozenset(way))
        if asked not in self.asked_to_clear:
            self.asked_to_clear = (*self.asked_to_clear, asked)


def keeps_clear(plan: Trajectory, other: Trajectory, delta: int) -> bool:
    """Whether ``plan``, from its start on, never meets ``other`` within ``delta`` steps (as (b) judges)."""
    low, high = plan.start_step - delta, max(plan.end_step, other.end_step) + delta + 2
    mine, theirs = ([cell_at(t, s) for s in range(low, high + 1)] for t in (plan, other))
    return not any(meetings(mine, theirs, s - low, delta) for s in range(plan.start_step, high - delta))
