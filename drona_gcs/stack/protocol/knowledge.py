"""What a drone's protocol knows of itself and of the fleet, and what follows from it: what it answers
with, what it holds for good, whether it may plan. Its state changes in one place, :meth:`Knowledge._enter`."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, replace

from drona_gcs.motion import Trajectory
from drona_gcs.planner import Plan
from drona_gcs.stack.messages import CurrentTraj, PlanProposal, ReqForCurrentTraj, Task, TaskId
from drona_gcs.stack.protocol.actions import Action, Grounded, Holding, Present, Send
from drona_gcs.stack.protocol.events import VehicleLost
from drona_gcs.stack.protocol.state import State, Taking
from drona_gcs.stack.transitions import checked
from drona_gcs.workspace import Cell

#: plan(start, goal, start_step, others, max_length) -> Plan, e.g. SafePlanner.plan
PlanFunction = Callable[[Cell, Cell, int, Mapping[str, Trajectory], int | None], Plan]


@dataclass(frozen=True)
class Proposed:
    """My plan, made and waiting for every member to hold it (state CONFIRMING)."""

    proposal: PlanProposal
    psi: tuple[tuple[str, Trajectory], ...]  #: what it avoided
    starts: int  #: the step its new part starts: it is flown only if every member holds it before
    rerouting: bool  #: a new rest of the plan I fly (which I fly on meanwhile)
    #: made against what I knew, nobody asked (see :meth:`.rounds.Rounds._on_new_task`): dropped, a round asks
    direct: bool = False

    def avoiding(self, drone: str, trajectory: Trajectory) -> Proposed:
        """The same plan, known to keep clear of ``trajectory`` of ``drone`` too (a member's ack said it flies
        that, or I held its proposal while confirming): what the plan avoided, for whoever checks it."""
        return replace(self, psi=(*((k, t) for k, t in self.psi if k != drone), (drone, trajectory)))


@dataclass
class Knowledge:
    """What Protocol 1 for drone ``me`` knows, and the views of it its handlers share. ``peers`` maps
    each peer to where it starts."""

    me: str
    location: Cell
    peers: Mapping[str, Cell]
    plan: PlanFunction
    lead_steps: int = 1
    delta: int = 0  #: the planner's skew window, in steps: a plan keeps that clear of every other drone
    hover_lead_steps: int | None = None  #: ``lead_steps`` for a drone in the air, which climbs no more
    #: a new task's plan is made against what I know and proposed at once (a round asks if it is not held)
    propose_at_once: bool = True
    epoch: int = 0  #: my agent's incarnation, larger at each restart: my holds are counted within it
    _state: State = field(default=State.WAIT_FOR_TASK, init=False)  #: read as :attr:`state`
    #: the event being taken, while a handler runs: what :meth:`_enter` checks a change against
    _taking: Taking | None = field(default=None, init=False, repr=False, compare=False)
    task: Task | None = None
    trajectory: Trajectory | None = None
    members: set[str] = field(default_factory=set)
    received: dict[str, Trajectory] = field(default_factory=dict)  #: R_recv with Psi
    pending: dict[str, TaskId] = field(default_factory=dict)  #: R_pend, with their task ids
    #: the requests in R_pend while a direct proposal of mine waits: taken anew by the round that may follow
    deferred: dict[str, ReqForCurrentTraj] = field(default_factory=dict)
    ghosts: dict[str, Trajectory] = field(default_factory=dict)  #: departed drones, kept as obstacles
    known: dict[str, Trajectory] = field(default_factory=dict)  #: last trajectory heard of each peer
    newest: dict[str, TaskId] = field(default_factory=dict)  #: the newest request id seen from each drone
    lost: VehicleLost | None = None  #: my vehicle is lost: what I hold besides my trajectory
    peer_holds: dict[str, tuple[Cell, ...]] = field(default_factory=dict)  #: what this round's answers hold
    #: this round's answers that came with their sender's proposal, undecided then: sender -> its task
    pledged: dict[str, TaskId] = field(default_factory=dict)
    down: Cell | None = None  #: my vehicle came down here by itself: I plan nothing more
    peers_down: dict[str, Cell] = field(default_factory=dict)  #: peers whose vehicle came down, and where
    #: peers that braked, with the plan cut short they hold at the end of, until their next plan
    braked: dict[str, Trajectory] = field(default_factory=dict)
    #: peers that braked, then planned anew from where they hold: that cell, and the step that plan starts
    held_until: dict[str, tuple[Cell, int]] = field(default_factory=dict)
    proposed: Proposed | None = None  #: my plan, until every member holds it (CONFIRMING)
    acked: set[str] = field(default_factory=set)  #: the members that hold it
    proposals: dict[str, PlanProposal] = field(default_factory=dict)  #: peers' plans not yet decided
    decided: dict[str, TaskId] = field(default_factory=dict)  #: each peer's newest decided proposal
    flown: dict[str, Trajectory] = field(default_factory=dict)  #: each peer's newest plan decided flown
    #: departed drones' proposals, undecided when they left: each may fly it, so its rest is held for good
    maybe_flown: dict[str, Trajectory] = field(default_factory=dict)
    #: cells a member holds for good for a drone gone here too (its refusal said): held here as well
    hearsay: dict[str, frozenset[Cell]] = field(default_factory=dict)
    released: set[str] = field(default_factory=set)  #: departed drones the operator took out of the fleet
    off_since: int | None = None  #: my clock is beyond the fleet's bound, since this step
    #: my vehicle late: the plan it may still be on, held from ``off_since`` until it is on time (a plan
    #: ended by my steps is not yet flown by it)
    trailing: Trajectory | None = None
    outliers: frozenset[str] = frozenset()  #: peers whose clock is beyond the fleet's bound
    #: cells a peer whose steps are not mine (an outlier; any, with my clock off) was to fly before its
    #: latest news, each held to a step of mine: by its clock, it may have left one only just
    left_behind: dict[Cell, int] = field(default_factory=dict)
    peers_lost: dict[str, tuple[Cell, ...]] = field(default_factory=dict)  #: peers' lost vehicles, where they may be
    peers_late: set[str] = field(default_factory=set)  #: of those, the late ones and clocks off (``PeerLost.for_now``)
    holds_told: int = 0  #: how many holds I told, in this incarnation
    holds_heard: dict[str, tuple[int, int]] = field(default_factory=dict)  #: the newest ``PeerLost.seq`` of each
    #: members back since they left, not heard from since: held where they may be until they say (Present)
    unreported: set[str] = field(default_factory=set)
    cut: Trajectory | None = None  #: my last brake: the plan I cut short, held at its end
    #: the task whose direct proposal was dropped undecided (a round asks instead): peers hold it until the
    #: task's decision, which a round ending in no plan must then send too
    unsettled: TaskId | None = None
    asked_at: int = 0  #: the step this round last asked the members that have not answered
    asked_again: int = 0  #: how many times this round asked again

    def __post_init__(self) -> None:
        self.members = set(self.peers) - {self.me}
        self.known = {p: Trajectory.stationary(c, 0) for p, c in self.peers.items() if p != self.me}

    @property
    def state(self) -> State:
        """Where Protocol 1 is: changed only by :meth:`_enter`, as :data:`.machine.TRANSITIONS` allows."""
        return self._state

    def _enter(self, target: State) -> None:
        """The one place the state changes: to a state the table's entry for the event being taken allows."""
        taking, machine = self._taking, f"drone {self.me!r}"
        if taking is None:  # a change outside any event: no table allows it
            self._state = checked(machine, self._state, None, target, frozenset())
        else:
            self._state = checked(machine, taking.state, taking.event, target, taking.targets)

    def heard(self, drone: str, trajectory: Trajectory, now: int) -> None:
        """A peer announced the plan it now flies (outside any round of mine): known for where
        it rests and, should it leave, where it may have stopped. Never planned with: Psi is
        only what the peers answer."""
        reporting = self._reported(drone)
        if drone in self.members and (reporting or trajectory.start_step >= self.known[drone].start_step):
            self.known[drone] = self._news(drone, trajectory, now)

    def current_trajectory(self, now: int) -> Trajectory:
        """What I answer with: my plan while executing; idle, my location.

        Idle after a plan, the location is that plan's last cell, and the plan
        itself says so *and* where I was in the last steps, which a peer whose
        clock is up to Delta behind still needs; so I answer with the plan.
        """
        if self.trajectory is not None:
            return self.trajectory
        return Trajectory.stationary(self.location, now)

    @property
    def coordinating(self) -> bool:
        """A round is under way: collecting every peer's trajectory, to plan."""
        return self.state in (State.COORDINATING, State.REROUTING)

    @property
    def holds_seq(self) -> tuple[int, int]:
        """``Holding.seq`` of my last holds: a re-send repeats it."""
        return self.epoch, self.holds_told

    def holds(self) -> tuple[Cell, ...]:
        """Cells my lost vehicle may be in, besides my trajectory: the rest of my plan from when it
        was last seen, where it was seen, and where I rest (none while my vehicle answers). A vehicle
        may trail its plan by up to lambda: the cells of the window before it was seen count too."""
        cells: list[Cell] = []
        for since, seen in ((self.lost.since, self.lost.seen) if self.lost else (None, None),
                            (self.off_since, self.location)):
            if since is None or seen is None:
                continue
            cells += [seen, self.location]
            for plan in (self.trajectory, self.trailing if since == self.off_since else None):
                if plan is not None:
                    cells += plan.suffix_from(since - self.delta - 1).cells
        return tuple(dict.fromkeys(cells))

    def ghost_obstacles(self, sparing: Cell | None = None) -> dict[str, Trajectory]:
        """Departed drones, for planning. One that left in the middle of a plan may have stopped
        anywhere along the rest of it (its agent died; its autopilot holds), so every cell of that
        rest is held for good, as if a drone rested there.

        ``sparing``: the cell this drone is in. Had the departed drone stopped there, it would
        still be there and we would have met it already; so it is not there, and the cell must
        not hold us in place for good (we may have come in after it flew through).
        """
        held: dict[str, Trajectory] = {}
        departed = [*self.ghosts.items(), *((f"{d}?maybe", t) for d, t in self.maybe_flown.items())]
        for drone, trajectory in departed:
            for i, cell in enumerate(dict.fromkeys(trajectory.cells)):
                if cell == sparing:
                    continue
                name = drone if cell == trajectory.last else f"{drone}#{i}"
                held[name] = Trajectory.stationary(cell, trajectory.start_step)
        for drone, cells in self.hearsay.items():
            for i, cell in enumerate(sorted(cells)):
                if cell != sparing:
                    held[f"{drone}!{i}"] = Trajectory.stationary(cell, 0)
        return held

    @property
    def airborne_lead(self) -> int:
        """Steps from now to the start of a plan for a drone in the air."""
        return min(self.hover_lead_steps or self.lead_steps, self.lead_steps)

    def lead_for(self, task: Task) -> int:
        """Steps from now to the start of ``task``'s plan: a landed drone climbs first."""
        return self.lead_steps if task.hovering_since is None else self.airborne_lead

    def in_quorum(self) -> bool:
        """In touch with a strict majority of the fleet, or half of it with its first drone (by name):
        two sides of a partition cannot both be (the operator's releases aside)."""
        fleet = ({self.me} | set(self.peers)) - self.released
        touch = (self.members | {self.me}) & fleet
        return 2 * len(touch) > len(fleet) or (2 * len(touch) == len(fleet) and min(fleet) in touch)

    def _no_majority(self) -> str:
        return f"in touch with {len(self.members) + 1} of the fleet's drones: no majority"

    def _request(self, now: int) -> ReqForCurrentTraj:
        assert self.task is not None
        return ReqForCurrentTraj(self.task.id, self.me, self.current_trajectory(now), tuple(sorted(self.members)),
                                 self.holds(), self.task.clear)

    def _current(self, event: ReqForCurrentTraj) -> bool:
        """Note ``event`` as its sender's newest request; False if a newer one came first, or its plan was
        decided already (its round is over)."""
        newest, decided = self.newest.get(event.sender), self.decided.get(event.sender)
        if newest is not None and newest.newer_than(event.task_id):
            return False
        if decided is not None and not event.task_id.newer_than(decided):
            return False
        self.newest[event.sender] = event.task_id
        held = self.proposals.get(event.sender)
        if held is not None and held.direct and held.task_id == event.task_id:
            del self.proposals[event.sender]  # it asks instead: that proposal is never flown
        pledged = self.pledged.get(event.sender)
        if pledged is not None and event.task_id.newer_than(pledged):
            del self.pledged[event.sender]  # a new round of its: the one I waited on is over
        return True

    def _news(self, drone: str, trajectory: Trajectory, now: int) -> Trajectory:
        """What ``drone`` sent, unless its vehicle came down since (then it stays where it came down), or
        it braked on that plan or an older one (then it holds where it braked): its answer may have been
        overtaken by that news. A plan made after the brake starts later, and ends it."""
        self._leave_behind(drone, now)
        down = self.peers_down.get(drone)
        if down is not None:
            return Trajectory.stationary(down, trajectory.start_step)
        cut = self.braked.get(drone)
        if cut is not None and trajectory.start_step <= cut.start_step:
            return cut
        if cut is None or not rests_after(trajectory, cut):
            if cut is not None and trajectory.first == cut.last:  # it waits there until that plan starts
                self.held_until[drone] = (cut.last, trajectory.start_step)
            self.braked.pop(drone, None)
        return trajectory

    def _reported(self, drone: str) -> bool:
        """News of ``drone``: if it is back and had not said where it is, forget where it might have been
        while it was gone (what it says now is the truth, however old its plan). Whether it had not."""
        if drone not in self.unreported:
            return False
        self.unreported.discard(drone)
        for gone in (self.ghosts, self.maybe_flown, self.hearsay, self.peers_down, self.peers_lost, self.braked,
                     self.held_until):
            gone.pop(drone, None)
        self.peers_late.discard(drone)
        return True

    def _present(self, drone: str, now: int) -> list[Action]:
        """What ``drone``, back, is told of me: my vehicle down or lost, or the plan I fly (a brake or not),
        and where my vehicle may be if it is late or my clock off (told to all, as when it went off)."""
        if self.down is not None and self.trajectory is not None:
            return [Grounded(self.trajectory)]  # a restarted agent missed the news: it never moves
        if self.lost is not None:
            return [Holding(self.holds(), seq=self.holds_seq)]
        braked = self.trajectory is not None and self.trajectory == self.cut
        held = self.holds()
        told = Holding(held, for_now=True, seq=self.holds_seq)
        return [Present(drone, self.current_trajectory(now), braked), *([told] * bool(held))]

    def _leave_behind(self, drone: str, now: int) -> None:
        """News of ``drone``, whose steps are not mine: what it was to fly, or may have flown while gone, stays
        held ``2 max(Delta, 1)`` steps. It left a cell before it sent the news; a clock found off keeps within
        ``max(Delta, 1)`` steps of the fleet's by the bound that found it, so the news comes at most that many
        of my steps after it left, and as many more keep us apart."""
        if drone == self.me or (self.off_since is None and drone not in self.outliers):
            return
        until = now + 2 * max(self.delta, 1)
        flights = [t for t in (self.known.get(drone), self.received.get(drone), self.maybe_flown.get(drone),
                               self.ghosts.get(drone)) if t is not None]
        cells = {c for t in flights for c in t.cells} | self.hearsay.get(drone, frozenset())
        self.left_behind = {c: u for c, u in self.left_behind.items() if u >= now}
        for cell in cells:
            self.left_behind[cell] = max(until, self.left_behind.get(cell, until))

    def _left_behind_obstacles(self, now: int, sparing: Cell) -> dict[str, Trajectory]:
        """The cells left behind still held, for a plan: held for good (the plan starts later anyway)."""
        return {f"~{i}": Trajectory.stationary(cell, now) for i, (cell, until) in
                enumerate(sorted(self.left_behind.items())) if until >= now and cell != sparing}

    def _held_for_outliers(self, sparing: Cell) -> dict[str, Trajectory]:
        """Every cell of what a peer whose clock is off answered, for good (its steps are not ours), but the
        one I am in (were it there, we would have met)."""
        return {f"{p}@{i}": Trajectory.stationary(cell, 0) for p in sorted(self.outliers & set(self.received))
                for i, cell in enumerate(dict.fromkeys(self.received[p].cells)) if cell != sparing}

    def _braked_holds(self) -> dict[str, Trajectory]:
        """Where each member that braked holds, from when a plan flown must keep out of it (its arrival less
        my lead: see :meth:`Flight._held_on_plan`): a plan made now keeps out of it as long, or it would
        brake short of it as soon as flown, where the braked drone still has to pass (found by the tester)."""
        held = {}
        for p, cut in sorted(self.braked.items()):
            if p in self.members:
                since = max(cut.start_step, cut.end_step - self.lead_steps)
                way = tuple(cut.at(t) for t in range(cut.start_step, since))
                held[f"{p}~braked"] = Trajectory(cut.start_step, (*way, cut.last))
        return held

    def _undecided(self) -> dict[str, Trajectory]:
        """Members' plans not decided yet (but the one a member answered with), which they may fly."""
        return {f"{p}?": proposal.trajectory for p, proposal in sorted(self.proposals.items())
                if p in self.members and proposal.trajectory != self.received.get(p)}

    def _held_by_peers(self, now: int) -> dict[str, Trajectory]:
        """The cells this round's answers hold besides their trajectories, as obstacles for good."""
        return {f"{peer}~{i}": Trajectory.stationary(cell, now) for peer, cells in self.peer_holds.items()
                if peer in self.members for i, cell in enumerate(cells)}

    def _release_pending(self, trajectory: Trajectory, proposal: PlanProposal | None = None) -> Iterable[Action]:
        pending, self.pending, self.deferred = self.pending, {}, {}
        holds = self.holds()
        return [Send(peer, CurrentTraj(self.me, trajectory, task_id, holds, proposal))
                for peer, task_id in pending.items()]


def rests_after(trajectory: Trajectory, cut: Trajectory) -> bool:
    """Whether ``trajectory`` is a peer's rest where its brake ``cut`` ends (one whose clock is off says
    so at once), not a new plan: the brake still overtakes older answers."""
    return trajectory.cells == (cut.last,) and trajectory.start_step >= cut.start_step


def cut_overtakes(cut: Trajectory, older: Trajectory) -> bool:
    """Whether a peer's brake ``cut`` is news over ``older``, what I held of it: a plan that starts later
    ended the brake, and a brake only ever shortens a plan (of two cuts of one plan, the shorter is
    the newer)."""
    return older.start_step < cut.start_step or (older.start_step == cut.start_step and older.end_step > cut.end_step)
