"""The decentralized coordination protocol (paper Protocol 1), one per drone.

Theory of operation
-------------------
A drone with a new task asks every peer for its current trajectory
(``ReqForCurrentTraj``), waits for all of them, plans against what it got
(Psi), starts executing, and answers the peers that waited on it with its new
trajectory. A request whose task id is lower (a higher priority) than mine is
answered at once with my current location; otherwise the requester waits in
``R_pend`` and gets my new trajectory once I have planned. Idle, I answer with
my location; executing, with my trajectory. What the paper leaves open is
settled here, and one message it sends is saved (the second point):

* **Task ids** are ``(HLC stamp, drone, seq)`` (see :mod:`.messages`): globally
  unique and totally ordered with no central counter, so ties cannot happen.
* **A request carries the requester's trajectory, and is its answer to the
  drones before it in line.** A drone ahead of me in line (a lower task id)
  that coordinates when my request comes holds me in ``R_pend`` and takes the
  trajectory my request carries as my answer; so when its own request comes, I
  do not answer it. Sound: my trajectory cannot change before that drone has
  planned, since I wait for its new plan (unless it leaves, and is then held
  as an obstacle as every departed drone is). Complete: my request went to
  every member (broadcast, or sent when one joins), and that drone gets it
  while it coordinates, because task ids come from hybrid logical clocks that
  observe every stamp received (``DroneStack`` does): had my request reached
  it before its task began, its task would rank below mine. (With ids that are
  not HLCs a drone could wait for good.) A requester that is no member is alive
  all the same (it restarted, or I saw it leave while it lived on): it is a
  member again, and I send it my request if I coordinate. Answering it at once
  and planning without it, as before, let it plan with my old location while I
  planned without it (found by the tester's crash and restart; a request is sent
  by a live agent, and the lease that makes a drone leave outlasts any message
  it sent before). Without the second point, a fleet given tasks at once sent
  an answer for every pair of drones before the first could plan (496 for 32
  drones).
* **A higher priority's request while coordinating, after it answered me**
  (a current request: see the next point). The answer may be its location
  from before its task (ids that are not HLCs allow that), about to be
  stale since it plans before me: I drop it
  from Psi and ask it again; it holds me in ``R_pend``, takes my trajectory
  from that request and sends its new trajectory once planned. (With HLC ids
  the answer is the new plan it sent once planned, its request having come
  late; asked again, it answers with that plan. Without HLC ids this protects
  only answers that came in order: the second request carries the same task
  id, so an old answer still on its way would count as the new one.)
* **A request older than the newest one seen from its sender is dropped**, in
  every state. A drone's ids only grow (its HLC) and it starts a task only once
  its last round is over (planned or failed), so that request's round is over:
  its sender ignores any answer to it, and the trajectory it carries may be out
  of date. Sound: dropping adds nothing to Psi; taking it would put that
  trajectory there or, ranking below mine, have my plan answer (``R_pend``) a
  request its sender no longer waits on. Complete: a drone waits only on
  answers to its newest request, which was handled when it came. Taken as
  current, a late request ranking above mine passed for the point above: I
  asked its sender again while it, in a later round ranking below mine, took
  my request as my answer, and both waited for good. "Older" compares the
  sender's epoch (its agent's incarnation) first: a restarted agent's clock may
  be behind the stamps its old one had seen, and its first request may come
  before its join does.
* **A request names the peers its round waits for** (``asked``). One that does not
  name me is not my answer, even from a drone behind me in line: it plans without
  me (it saw me leave, and has not seen me back), so its trajectory may change
  before I plan. I send it my request, which makes me a member again there (see
  above), and wait for its answer. Taken as its answer, I planned with its old
  location while it flew a new plan (found by the tester's crash and restart).
* **Psi is rebuilt for every task.** Answers from an earlier round describe
  plans that may have been replaced since; planning with them is the race the
  paper's model checker found (the tester seeds this bug).
* **A plan starts ``lead_steps`` after now**, because planning, messaging and
  the executor's hand-over take time, and a landed drone climbs into the grid;
  a drone in the air (its task ``hovering_since``) climbs no more and starts
  ``hover_lead_steps`` after now. The executor refuses a trajectory whose
  start it has already passed. Other drones' executors may be up to beta
  ahead or behind, and their vehicles up to lambda late into each cell (a later
  vehicle raises an alarm and plans nothing more); the planner's window,
  Delta = ceil((beta + lambda) / tau), covers exactly that.
* **A plan is flown only once every member holds it** (``CONFIRMING``). Planned, I send it to
  everyone (``PlanProposal``); each member holds it besides what it knew of me and says so
  (``PlanAck``, with what it flies now); once every member has, I fly it and tell everyone
  (``PlanDecision``), then answer the peers that waited. If the boundary before its start comes
  first, or the fleet changes meanwhile (a peer leaves, comes back, comes down, brakes), I drop it,
  say so, and the task fails (it is tried again). Why: a peer that left before it heard of my plan
  holds me, for good, on the cells of what it last knew I fly; had I flown a plan it never heard of,
  it planned into my cells (found by the tester's partitions, and in the field). A peer that held my
  proposal when I left holds its cells too (``maybe_flown``). The same holds for requests: until
  decided, I answer nobody.
* **Only a majority plans.** A partition's two sides each see the other leave; each planning around
  where it last knew the other, both could plan into one cell. I plan only in touch with a strict
  majority of the fleet, or half of it with its first drone by name (``in_quorum``): at most one side
  can. The other side flies only plans every member held, whose cells are held for good here. A
  drone the operator released counts no more (its vehicle is out of the air), until it joins again.
* **A plan is checked where views meet.** Views of the fleet may differ (a leave seen here, not
  there). A member acks a proposal only if it keeps clear of what it flies, and of what it knows a
  drone flies or proposed that the proposer held as gone (``_clashes``); the proposer, in turn, flies
  it only if it keeps clear of what each ack says the member flies. Two majorities overlap in a drone
  that sees both plans. A member that will not hold a plan says so (``PlanRefusal``), naming the cells
  it holds for good for each drone the proposer held as gone; the proposer drops the plan at once and
  holds those cells too (``hearsay``, until that drone is back or released), so its next plan keeps
  clear of them. Without it, a drone that knew less of where a gone drone had stopped proposed the
  same plan until its mail was given up (a member frozen while a drone died).
  Confirming, I ack no proposal: mine was made without it. A message that says what a drone I held
  as gone flies (an answer, an ack, a decision, a request) proves it alive: a member again, there.
* **Membership can change.** ``PeerLeft`` means the drone's liveliness was
  lost: it is no longer waited for, and it stays in Psi as an obstacle:
  safety first. Since it may have stopped anywhere along the rest of its
  last known trajectory, every cell of that rest is held for good. ``PeerJoined``
  (again) makes it a peer; if I am coordinating, I ask it too.
* **A peer that leaves across the plan I fly.** Plans made before its leave was
  noticed avoided only its plan, and its vehicle may hold anywhere on the rest of
  it. If the rest of mine, from when a new one could start (``lead_steps`` on),
  crosses one of those cells, I report ``Threatened``; the task planner asks for a
  new plan to the same goal (``Reroute``) and I coordinate it as any task
  (``REROUTING``), answering with the plan I fly on meanwhile. The new plan starts
  where that one is at its start step, and the two joined are what I then answer
  with. No plan (or the old one ended first): I fly on what I have. Sound as any
  round: my new rest avoids every answer, and a drone ahead of me in line plans
  against the plan I fly, which I do not change before it has planned. A cell
  crossed within ``lead_steps`` cannot be helped this way (found by the tester).
* **A vehicle that comes down by itself** (a failsafe, a pilot) stays where it came
  down. I then answer with that cell for good, tell every peer (``Grounded``), end a
  round under way with no plan and plan nothing more, and tell each peer that joins
  (a restarted agent missed the news). A peer told (``PeerDown``)
  holds that cell for good in every plan, takes it over any answer of mine the news
  overtook, and plans anew the rest of the plan it flies if that crosses it. Where I
  braked before no longer holds: held, it walled off a cell plans did not avoid, and a
  drone planned into it and braked, for good (found by the tester with a clock off).
* **Too close to plan around it: brake.** If the plan I fly enters that cell (or one a
  departed drone may hold) before a new
  rest could start (within ``lead_steps``), or a round to plan around it has not ended when
  the next step would enter it (``NextStep``), I cut my plan at the cell before and hold
  there (``Braked``), announced as any new plan is; the leg is then decided anew from there.
  A cell held for good is never entered once I know of it. The hold is not coordinated:
  a peer whose plan enters my cell after the step I was to leave it meets me there unless
  it hears of it first. Plans keep Delta steps between drones, and the news travels in
  well under a period on a real link, so it does; with news slower than the window (the
  tester's ``max_delay`` allows it), it may not, and the tester judges that flight.
* **A clock beyond the fleet's bound** (``ClockBound``, from the runtime's clock check). Mine off
  (most peers' clocks disagree with it), my steps are not the fleet's: I fly the plan I have to its
  end, or short of the first cell of any peer's plan (whenever it flies there), and hold there, plan
  nothing, and name every cell of that in my answers (``holds``), which peers hold for good. A peer's
  off: its proposals get no ack of mine, and every cell of what it answers is held for good; the plan
  I fly steers clear of every cell of its plan, as of a vehicle down (its steps are not ours). Nobody
  waits for it: it answers as ever.
* **The operator may release a departed drone** (``Released``): having seen its vehicle
  out of the air for good, it tells every drone to hold none of its cells.
* **My vehicle can be lost** (its link closed or silent). It may then be anywhere on
  my trajectory from when it was last seen, or where it was seen: I keep answering with
  my trajectory and also name those cells (``holds``), which every peer holds for good
  in the Psi of its next plans; I plan nothing meanwhile (a task fails at once). Every peer is
  told at once (``Holding``; ``PeerLost`` there), and steers clear of them as of a vehicle down. Once
  the vehicle is back and seen in a cell, I rest there with no plan (``Relocated``):
  the holds end with the next answers I give. Plans made before the loss avoided only my
  trajectory: what a vehicle does while nobody hears it is beyond any protocol.
* **No plan found:** I stay where I am, answer my pending peers with my
  location, and report ``TaskFailed`` so the task planner retries or
  reassigns the task. Nothing is dropped.
* **Messages** may be delayed, duplicated and reordered. Every reply names
  the request it answers (``in_reply_to``); replies to anything but my current
  request are ignored, and duplicates only overwrite an entry with itself. A round still
  waiting :data:`ASK_AGAIN_STEPS` after it asked asks the silent members again (a request
  or answer lost must not hold it for good).

Every transition is in :data:`TRANSITIONS`; an event a state does not take
raises :class:`~drona_gcs.errors.ProtocolViolation` naming both.
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field

from drona_gcs.errors import GoalCutOff, NoPlanFound, ProblemError, ProtocolViolation
from drona_gcs.motion import Trajectory
from drona_gcs.planner import Plan
from drona_gcs.safety import check_pair
from drona_gcs.stack.messages import (
    CurrentTraj,
    Message,
    PlanAck,
    PlanDecision,
    PlanProposal,
    PlanRefusal,
    ReqForCurrentTraj,
    Task,
    TaskId,
)
from drona_gcs.workspace import Cell

#: steps a round waits for answers before it asks the members that have not answered again
ASK_AGAIN_STEPS = 4
#: plan(start, goal, start_step, others, max_length) -> Plan, e.g. SafePlanner.plan
PlanFunction = Callable[[Cell, Cell, int, Mapping[str, Trajectory], int | None], Plan]


class State(enum.Enum):
    WAIT_FOR_TASK = "WaitForTaskRequest"  #: idle at its location, answering with it
    COORDINATING = "CoordinateAndGeneratePlan"  #: collecting every peer's trajectory
    EXECUTING = "WaitForPlanCompletion"  #: flying its plan, answering with it
    REROUTING = "RerouteWhileExecuting"  #: flying its plan, collecting trajectories to plan its rest anew
    CONFIRMING = "ConfirmPlan"  #: planned; flies the plan once every member holds it


# ------------------------------------------------------------------ events
@dataclass(frozen=True)
class NewTask:
    task: Task


@dataclass(frozen=True)
class PlanCompleted:
    """The executor finished the trajectory (the paper's Reset)."""


@dataclass(frozen=True)
class PeerLeft:
    drone: str
    #: the earliest step it may have gone silent at (a lost link is noticed only when its lease
    #: expires); None: now
    silent_since: int | None = None


@dataclass(frozen=True)
class PeerJoined:
    drone: str
    cell: Cell  #: where it is now, as it announced
    trajectory: Trajectory | None = None  #: the plan it announced it is flying, if any

    def announced(self, now: int) -> Trajectory:
        return self.trajectory if self.trajectory is not None else Trajectory.stationary(self.cell, now)


@dataclass(frozen=True)
class VehicleLost:
    """My vehicle stopped answering at step ``since``; it was last seen in ``seen``."""

    since: int
    seen: Cell


@dataclass(frozen=True)
class Relocated:
    """My vehicle is back and seen in ``cell`` (or landed below it): I rest there, with no plan."""

    cell: Cell


@dataclass(frozen=True)
class VehicleDown:
    """My vehicle came down by itself in ``cell`` (a failsafe, a pilot): it stays there for good."""

    cell: Cell


@dataclass(frozen=True)
class PeerDown:
    """``drone`` announced its vehicle came down in ``cell``: it stays there for good."""

    drone: str
    cell: Cell


@dataclass(frozen=True)
class PeerLost:
    """``drone``'s vehicle is lost: it may be in any of ``cells`` for good (none: it is back)."""

    drone: str
    cells: tuple[Cell, ...]


@dataclass(frozen=True)
class PeerBraked:
    """``drone`` cut the plan it flies short (:class:`Braked`): ``trajectory`` holds at its end until
    its next plan."""

    drone: str
    trajectory: Trajectory


@dataclass(frozen=True)
class PeerAnnounced:
    """``drone`` announced the plan it flies now, outside any round of mine (see :meth:`CoordinationProtocol.heard`)."""

    drone: str
    trajectory: Trajectory


@dataclass(frozen=True)
class Released:
    """The operator saw ``drone``, gone, out of the air for good (landed, or taken away): no cell is
    held for it any more, until it joins again."""

    drone: str


@dataclass(frozen=True)
class ClockBound:
    """The clock check's verdict: my clock is beyond the fleet's bound (``mine_off``: I hold where my plan
    ends, plan nothing, and every peer holds that for good), or these peers' are (``outliers``)."""

    mine_off: bool
    outliers: frozenset[str] = frozenset()


@dataclass(frozen=True)
class NextStep:
    """The executor is about to take the boundary after ``now``: a last look at the cell it enters."""


@dataclass(frozen=True)
class Reroute:
    """A new plan to the goal of the one I fly, asked for after :class:`Threatened`."""

    task: Task


Event = (NewTask | PlanCompleted | PeerLeft | PeerJoined | ReqForCurrentTraj | CurrentTraj | VehicleLost
         | Relocated | Reroute | VehicleDown | PeerDown | PeerBraked | PeerAnnounced | Released | NextStep
         | PlanProposal | PlanAck | PlanRefusal | PlanDecision | ClockBound | PeerLost)


# ----------------------------------------------------------------- actions
@dataclass(frozen=True)
class Send:
    to: str
    message: Message


@dataclass(frozen=True)
class Broadcast:
    message: Message


@dataclass(frozen=True)
class StartExecuting:
    task: Task
    trajectory: Trajectory
    psi: Mapping[str, Trajectory]  #: what the plan avoided, for the consistency monitor


@dataclass(frozen=True)
class TaskFailed:
    task: Task
    reason: str
    cut_off: bool = False  #: no path at all joins start and goal (see GoalCutOff)


@dataclass(frozen=True)
class Threatened:
    """The rest of the plan I fly crosses cells a departed drone may hold for good: the task
    planner should ask for a new plan to the same goal (:class:`Reroute`)."""

    departed: str  #: the peer that left, or whose vehicle came down
    cells: tuple[Cell, ...]  #: the cells of my plan it may hold


@dataclass(frozen=True)
class RerouteFailed:
    """No new plan avoids the departed drone: I fly the plan I have (what else is there)."""

    task: Task
    reason: str


@dataclass(frozen=True)
class Grounded:
    """Tell every peer my vehicle came down: it stays in ``trajectory.last`` for good."""

    trajectory: Trajectory


@dataclass(frozen=True)
class Braked:
    """I cut my plan short of a cell held for good (a vehicle down's, a departed drone's): ``trajectory``
    is what I fly now, holding at its end; every peer is told as of a new plan."""

    trajectory: Trajectory
    held: Cell  #: the cell it stops short of


@dataclass(frozen=True)
class Holding:
    """Tell every peer the cells my lost vehicle may be in, for good (none: it is back, see ``Relocated``)."""

    cells: tuple[Cell, ...]


@dataclass(frozen=True)
class Present:
    """Tell ``to``, which joined (again), what I fly now: news of me it missed while apart (a brake, a new
    plan) would otherwise be lost for good. ``braked``: a plan I cut short, announced as any brake."""

    to: str
    trajectory: Trajectory
    braked: bool


Action = (Send | Broadcast | StartExecuting | TaskFailed | Threatened | RerouteFailed | Grounded | Braked | Holding
          | Present)


@dataclass(frozen=True)
class Proposed:
    """My plan, made and waiting for every member to hold it (state CONFIRMING)."""

    proposal: PlanProposal
    psi: tuple[tuple[str, Trajectory], ...]  #: what it avoided
    starts: int  #: the step its new part starts: it is flown only if every member holds it before
    rerouting: bool  #: a new rest of the plan I fly (which I fly on meanwhile)


@dataclass
class CoordinationProtocol:
    """Protocol 1 for drone ``me``. ``peers`` maps each peer to where it starts."""

    me: str
    location: Cell
    peers: Mapping[str, Cell]
    plan: PlanFunction
    lead_steps: int = 1
    delta: int = 0  #: the planner's skew window, in steps: a plan keeps that clear of every other drone
    hover_lead_steps: int | None = None  #: ``lead_steps`` for a drone in the air, which climbs no more
    state: State = State.WAIT_FOR_TASK
    task: Task | None = None
    trajectory: Trajectory | None = None
    members: set[str] = field(default_factory=set)
    received: dict[str, Trajectory] = field(default_factory=dict)  #: R_recv with Psi
    pending: dict[str, TaskId] = field(default_factory=dict)  #: R_pend, with their task ids
    ghosts: dict[str, Trajectory] = field(default_factory=dict)  #: departed drones, kept as obstacles
    known: dict[str, Trajectory] = field(default_factory=dict)  #: last trajectory heard of each peer
    newest: dict[str, TaskId] = field(default_factory=dict)  #: the newest request id seen from each drone
    lost: VehicleLost | None = None  #: my vehicle is lost: what I hold besides my trajectory
    peer_holds: dict[str, tuple[Cell, ...]] = field(default_factory=dict)  #: what this round's answers hold
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
    #: departed drones' proposals, undecided when they left: each may fly it, so its rest is held for good
    maybe_flown: dict[str, Trajectory] = field(default_factory=dict)
    #: cells a member holds for good for a drone gone here too (its refusal said): held here as well
    hearsay: dict[str, frozenset[Cell]] = field(default_factory=dict)
    released: set[str] = field(default_factory=set)  #: departed drones the operator took out of the fleet
    off_since: int | None = None  #: my clock is beyond the fleet's bound, since this step
    outliers: frozenset[str] = frozenset()  #: peers whose clock is beyond the fleet's bound
    peers_lost: dict[str, tuple[Cell, ...]] = field(default_factory=dict)  #: peers' lost vehicles, where they may be
    #: members back since they left, not heard from since: held where they may be until they say (Present)
    unreported: set[str] = field(default_factory=set)
    cut: Trajectory | None = None  #: my last brake: the plan I cut short, held at its end
    asked_at: int = 0  #: the step this round last asked the members that have not answered

    def __post_init__(self) -> None:
        self.members = set(self.peers) - {self.me}
        self.known = {p: Trajectory.stationary(c, 0) for p, c in self.peers.items() if p != self.me}

    # ------------------------------------------------------------- driver
    def handle(self, event: Event, now: int) -> list[Action]:
        """Take one event at local step ``now``; return what to do."""
        admitted = self._alive(event, now)
        handler = TRANSITIONS[self.state].get(type(event))
        if handler is None:
            raise ProtocolViolation(f"drone {self.me!r}: state {self.state.value} does not take "
                                    f"{type(event).__name__}")
        return [*admitted, *handler(self, event, now)]

    def _alive(self, event: Event, now: int) -> list[Action]:
        """A message that says what a drone I hold as gone flies proves it alive (its lease outlasts what
        it sent before): a member again, there. (A request does so in :meth:`_admit`.) So does an
        announcement of its, which may come before its return does."""
        if isinstance(event, (PeerAnnounced, PeerBraked)):
            sender = event.drone
        elif isinstance(event, (CurrentTraj, PlanAck, PlanDecision)):
            sender = event.sender
        else:
            return []
        if sender in self.members or sender == self.me or sender not in self.peers:
            return []
        return self.handle(PeerJoined(sender, event.trajectory.last, event.trajectory), now)

    def _on_announced(self, event: PeerAnnounced, now: int) -> list[Action]:
        self.heard(event.drone, event.trajectory)
        return []

    def heard(self, drone: str, trajectory: Trajectory) -> None:
        """A peer announced the plan it now flies (outside any round of mine): known for where
        it rests and, should it leave, where it may have stopped. Never planned with: Psi is
        only what the peers answer."""
        reporting = self._reported(drone)
        if drone in self.members and (reporting or trajectory.start_step >= self.known[drone].start_step):
            self.known[drone] = self._news(drone, trajectory)

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
            if self.trajectory is not None:
                cells += self.trajectory.suffix_from(since - self.delta - 1).cells
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
        departed = [*self.ghosts.items(), *((f"{d}?", t) for d, t in self.maybe_flown.items())]
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

    # ----------------------------------------------------------- handlers
    def _on_new_task(self, event: NewTask, now: int) -> list[Action]:
        return self._begin_round(event.task, State.COORDINATING, now)

    def _begin_round(self, task: Task, state: State, now: int) -> list[Action]:
        self.task, self.state, self.asked_at = task, state, now
        self._forget_answers()
        self.pending = {}
        if not self.in_quorum():  # nothing to ask: no plan could be flown
            return self._no_plan(NoPlanFound(self._no_majority()), now)
        actions: list[Action] = [Broadcast(self._request(now))]
        return actions + self._plan_if_ready(now)

    def _no_majority(self) -> str:
        return f"in touch with {len(self.members) + 1} of the fleet's drones: no majority"

    def _forget_answers(self) -> None:
        """A new round starts from no answers: last round's trajectories may have changed since."""
        self.received, self.peer_holds = {}, {}

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
        return True

    def _on_request(self, event: ReqForCurrentTraj, now: int) -> list[Action]:
        if event.sender == self.me or not self._current(event):
            return []
        return [*self._admit(event, now), *self._answer(event, now)]

    def _admit(self, event: ReqForCurrentTraj, now: int) -> list[Action]:
        """A request from a drone that is no member: it is alive (it restarted, or its leave was
        noticed while it lived on), so it is a member again, where its request puts it."""
        if event.sender in self.members:
            return []
        actions = self._on_peer_joined(PeerJoined(event.sender, event.trajectory.last, event.trajectory), now)
        self.newest[event.sender] = event.task_id  # joining forgot it: this request is its newest
        return actions

    def _answer(self, event: ReqForCurrentTraj, now: int) -> list[Action]:
        if event.sender == self.me:
            return []
        return [Send(event.sender, CurrentTraj(self.me, self.current_trajectory(now), event.task_id, self.holds()))]

    def _on_request_while_coordinating(self, event: ReqForCurrentTraj, now: int) -> list[Action]:
        assert self.task is not None
        if event.sender == self.me or not self._current(event):
            return []
        admitted = self._admit(event, now)  # my request goes to it now
        if self._outranks(event.task_id, self.task.id):
            if admitted:
                return admitted  # it may not have had my request: it gets it now, and answers once planned
            # It plans before me, and takes my request (which went to every member) as my answer.
            self.peer_holds.pop(event.sender, None)
            if self.received.pop(event.sender, None) is not None:
                # What it told me is about to change. Ask again.
                return [Send(event.sender, self._request(now))]
            return []
        if self.me not in event.asked:
            # It plans without me (it saw me leave, or never saw me join): what its request carries
            # may change before I plan. It gets my request, admits me, and answers it.
            return admitted or [Send(event.sender, self._request(now))]
        self.pending[event.sender] = event.task_id
        # It waits for my plan, so the trajectory its request carries is its answer.
        self.received[event.sender] = self.known[event.sender] = self._news(event.sender, event.trajectory)
        self.peer_holds[event.sender] = event.holds
        return [*admitted, *self._plan_if_ready(now)]

    def _outranks(self, theirs: TaskId, mine: TaskId) -> bool:
        return theirs < mine

    def _on_reply(self, event: CurrentTraj, now: int) -> list[Action]:
        assert self.task is not None
        if event.in_reply_to != self.task.id or event.sender not in self.members:
            return []  # an answer to an older request, or from a drone that left
        self.received[event.sender] = self.known[event.sender] = self._news(event.sender, event.trajectory)
        self.peer_holds[event.sender] = event.holds
        return self._plan_if_ready(now)

    def _news(self, drone: str, trajectory: Trajectory) -> Trajectory:
        """What ``drone`` sent, unless its vehicle came down since (then it stays where it came down), or
        it braked on that plan or an older one (then it holds where it braked): its answer may have been
        overtaken by that news. A plan made after the brake starts later, and ends it."""
        down = self.peers_down.get(drone)
        if down is not None:
            return Trajectory.stationary(down, trajectory.start_step)
        cut = self.braked.get(drone)
        if cut is not None and trajectory.start_step <= cut.start_step:
            return cut
        if cut is None or not _rests_after(trajectory, cut):
            if cut is not None and trajectory.first == cut.last:  # it waits there until that plan starts
                self.held_until[drone] = (cut.last, trajectory.start_step)
            self.braked.pop(drone, None)
        return trajectory

    def _ignore(self, event: Event, now: int) -> list[Action]:
        return []  # a late reply to a round that is over

    def _on_completed(self, event: PlanCompleted, now: int) -> list[Action]:
        """I rest at my plan's end. Out of the fleet's bound, my steps are not the fleet's: peers hold for
        good every cell of the plan they last heard of, so I tell them at once that I rest in one, and
        answer with it from now on."""
        assert self.trajectory is not None
        self.location, self.state, self.task = self.trajectory.last, State.WAIT_FOR_TASK, None
        return self._tell_rest(now) if self.off_since is not None else []

    def _tell_rest(self, now: int) -> list[Action]:
        """With my clock off, I say at once that I rest in my location alone, and answer with it."""
        self.trajectory = Trajectory.stationary(self.location, now)
        return [Present(peer, self.trajectory, braked=False) for peer in sorted(self.peers) if peer != self.me]

    def _on_completed_while_rerouting(self, event: PlanCompleted, now: int) -> list[Action]:
        """The plan ended before its new rest was planned: the round is moot, and I rest at its end."""
        assert self.task is not None and self.trajectory is not None
        failed = RerouteFailed(self.task, "the plan ended first")
        self.location, self.state, self.task = self.trajectory.last, State.WAIT_FOR_TASK, None
        return [*self._release_pending(self.trajectory), failed]

    def _on_vehicle_down(self, event: VehicleDown, now: int) -> list[Action]:
        """My vehicle is on the ground in ``event.cell`` for good: that is my trajectory from now, every
        peer is told, and a round under way ends with no plan."""
        task = self.task if self.coordinating else None
        rerouting = self.state is State.REROUTING
        self.down, self.location = event.cell, event.cell
        self.trajectory = Trajectory.stationary(event.cell, now)
        self.state, self.task = State.WAIT_FOR_TASK, None
        actions: list[Action] = [Grounded(self.trajectory), *self._release_pending(self.trajectory)]
        if task is not None and rerouting:
            actions.append(RerouteFailed(task, "my vehicle is down"))
        elif task is not None:
            actions.append(TaskFailed(task, "my vehicle is down"))
        return actions

    def _on_peer_down(self, event: PeerDown, now: int) -> list[Action]:
        """A peer's vehicle is on the ground for good: an obstacle for every plan from now, and for
        the plan I fly (which avoided its plan, not this) if that crosses it."""
        if event.drone == self.me or event.drone not in self.peers:
            return []
        self._reported(event.drone)
        self.peers_down[event.drone] = event.cell
        self.proposals.pop(event.drone, None)
        self.braked.pop(event.drone, None)  # it stays where it came down: where it braked is free
        self.held_until.pop(event.drone, None)
        stays = Trajectory.stationary(event.cell, now)
        self.known[event.drone] = stays
        if event.drone in self.received:
            self.received[event.drone] = stays
        return self._steer_clear(event.drone, now)

    def _steer_clear(self, drone: str, now: int) -> list[Action]:
        """News of ``drone`` holding cells for good, which plans made before did not avoid: if the plan
        I fly enters one before a new rest could start, brake; if later, report ``Threatened`` to have
        the rest planned anew (a round under way plans against it, and ``NextStep`` brakes should it
        end too late)."""
        if self.state not in (State.EXECUTING, State.REROUTING) or self.trajectory is None:
            return []
        entry = self._entry(now)
        if entry is not None and entry <= now + self.lead_steps:
            return self._brake(entry)
        if entry is None or self.state is State.REROUTING:
            return []
        crossed = self._held_on_plan(now)
        return [Threatened(drone, tuple(dict.fromkeys(self.trajectory.at(t) for t in crossed)))]

    def _entry(self, now: int) -> int | None:
        """The first step after ``now`` at which the plan I fly enters a cell held for good (``None``
        if already in one: stopping would not part us)."""
        assert self.trajectory is not None
        crossed = self._held_on_plan(now)
        return None if not crossed or crossed[0] == now else next((t for t in crossed if t > now), None)

    def _held_on_plan(self, now: int) -> list[int]:
        """The steps from ``now`` on at which the plan I fly is in a cell held for good: a vehicle down's,
        one a departed drone may hold, one of the plan of a peer whose clock is off (or of any peer's, with
        mine off: our steps are not the same), or one a braked peer holds from when it gets there (less my
        lead, a margin for its clock) until the plan it made since starts (and Delta more)."""
        assert self.trajectory is not None
        trajectory = self.trajectory
        here = trajectory.at(now)
        held = {*self.peers_down.values(), *(t.last for t in self.ghost_obstacles(sparing=here).values()),
                *(c for cells in self.peers_lost.values() for c in cells if c != here),
                *(c for flight in self._timeless() for c in flight.cells if c != here)}

        def taken(step: int) -> bool:
            cell = trajectory.at(step)
            return cell in held or any(cut.last == cell and step >= cut.end_step - self.lead_steps
                                       for cut in self.braked.values()) or any(
                c == cell and step <= until + self.delta for c, until in self.held_until.values())

        return [t for t in range(now, max(now, trajectory.end_step) + 1) if taken(t)]

    def _timeless(self) -> list[Trajectory]:
        """What peers fly, or may, in steps that are not mine: every cell of it is held. A peer's whose
        clock is off; with mine off, every peer's, and every plan proposed."""
        if self.off_since is None:
            return [self.known[p] for p in sorted(self.outliers & self.known.keys())]
        return [*self.known.values(), *(proposal.trajectory for proposal in self.proposals.values())]

    def _brake(self, entry: int) -> list[Action]:
        """Cut the plan I fly at the cell before step ``entry``, and hold there (one step more, so that
        the executor, at ``entry - 1`` at the latest, takes it as the plan it flies). A round to plan
        its rest anew ends: the next plan starts from where I hold, later than this one, so that
        peers can tell the cut from older answers and the next plan from the cut."""
        assert self.trajectory is not None
        flown, start = self.trajectory, self.trajectory.start_step
        cells = tuple(flown.at(t) for t in range(start, max(entry, start + 1)))
        self.trajectory = self.cut = Trajectory(start, (*cells, cells[-1]))
        actions: list[Action] = [Braked(self.trajectory, flown.at(entry))]
        if self.state is State.REROUTING and self.task is not None:
            actions += [*self._release_pending(self.trajectory), RerouteFailed(self.task, "braked")]
            self.state = State.EXECUTING
        return actions

    def _on_next_step_while_coordinating(self, event: NextStep, now: int) -> list[Action]:
        return self._ask_again(now)

    def _ask_again(self, now: int) -> list[Action]:
        """A round still waiting :data:`ASK_AGAIN_STEPS` after it asked asks again the members that have not
        answered: one request lost (a link just back drops what it carries before its routes are up) would
        hold a round for good. A copy is harmless: it is answered, or held for an answer, again."""
        if now - self.asked_at < ASK_AGAIN_STEPS:
            return []
        self.asked_at = now
        request = self._request(now)
        return [Send(p, request) for p in sorted(self.members - set(self.received))]

    def _on_next_step(self, event: NextStep, now: int) -> list[Action]:
        if self.trajectory is None:
            return []
        entry = self._entry(now)
        return self._brake(entry) if entry == now + 1 else []

    def _on_peer_braked(self, event: PeerBraked, now: int) -> list[Action]:
        """A peer holds where it braked, which plans made before (mine among them) did not avoid: it
        overrides what it answered of that plan, and the plan I fly steers clear of it as of a vehicle
        down (brake, or plan its rest anew)."""
        drone, cut = event.drone, event.trajectory
        if drone == self.me or drone not in self.members:
            return []
        held = self.braked.get(drone)
        if held is not None and not _cut_overtakes(cut, held):
            return []  # it cut that plan again since, shorter
        known = self.known[drone]
        resting = _rests_after(known, cut)  # it said it rests where it braked: the brake holds on
        if not self._reported(drone) and cut.start_step < known.start_step and not resting:
            answered = self.received.get(drone)
            if answered is not None and _cut_overtakes(cut, answered):
                self.received[drone] = cut  # my round's answer was of the plan it cut
            return []  # a plan of its made since ended the brake
        self.braked[drone] = cut
        if not resting:
            self.known[drone] = cut
        if drone in self.received:
            self.received[drone] = self._news(drone, self.received[drone])
        return self._steer_clear(drone, now)

    def _on_released(self, event: Released, now: int) -> list[Action]:
        """Forget where a departed drone may be: its ghost, its vehicle down, its brake."""
        if event.drone == self.me or event.drone in self.members or event.drone not in self.peers:
            raise ProblemError(f"{event.drone} is not a drone gone from the fleet: nothing to release")
        for held in (self.ghosts, self.maybe_flown, self.peers_down, self.braked, self.known, self.peers_lost,
                     self.hearsay, self.held_until):
            held.pop(event.drone, None)
        self.released.add(event.drone)
        return []

    def _on_reroute(self, event: Reroute, now: int) -> list[Action]:
        return self._begin_round(event.task, State.REROUTING, now)

    def _on_peer_left(self, event: PeerLeft, now: int) -> list[Action]:
        if event.drone not in self.members:
            return []
        self.members.discard(event.drone)
        # The newest of what it answered and what it announced (an answer of a round over is old).
        answered, known = self.received.pop(event.drone, None), self.known[event.drone]
        last = answered if answered is not None and answered.start_step > known.start_step else known
        # What it had flown before it went silent is behind it, less the window (its clock may be
        # behind, its vehicle late): only the rest of its plan is where it may have stopped. (The
        # lead, as before, held cells a drone flew through seconds earlier: mail there was stuck.)
        silent = now if event.silent_since is None else min(now, event.silent_since)
        since = silent - self.delta - 1
        if event.drone in self.unreported:  # gone again before it said where it is: held as it was, and here
            self.unreported.discard(event.drone)
            self.hearsay[event.drone] = self.hearsay.get(event.drone, frozenset()) | set(last.suffix_from(since).cells)
        else:
            self.ghosts[event.drone] = last.suffix_from(since)
        proposal = self.proposals.pop(event.drone, None)
        if proposal is not None:
            self.maybe_flown[event.drone] = proposal.trajectory.suffix_from(since)
        self.pending.pop(event.drone, None)
        self.peer_holds.pop(event.drone, None)
        return self._plan_if_ready(now) if self.coordinating else self._steer_clear(event.drone, now)

    def _on_peer_joined(self, event: PeerJoined, now: int) -> list[Action]:
        """A drone back (a partition healed, its agent restarted). Where it may be stays held until it says
        what it flies now: a brake of its, announced while we were apart, never reached us. It is told
        what I fly now, for the same reason."""
        if event.drone == self.me:
            return []
        if event.drone in self.members:  # met as I start (my agent restarted), or back already (a message)
            return [self._present(event.drone, now)]
        self.members.add(event.drone)
        self.released.discard(event.drone)
        self.proposals.pop(event.drone, None)
        self.newest.pop(event.drone, None)  # it may have restarted, and its clock with it
        self.known[event.drone] = event.announced(now)
        self.unreported.add(event.drone)
        told = self._present(event.drone, now)
        if self.coordinating and self.task is not None:
            return [told, Send(event.drone, self._request(now))]
        return [told]

    def _present(self, drone: str, now: int) -> Action:
        """What ``drone``, back, is told of me: my vehicle down or lost, or the plan I fly (a brake or not)."""
        if self.down is not None and self.trajectory is not None:
            return Grounded(self.trajectory)  # a restarted agent missed the news: it never moves
        if self.lost is not None:
            return Holding(self.holds())
        return Present(drone, self.current_trajectory(now), self.trajectory is not None and self.trajectory == self.cut)

    def _reported(self, drone: str) -> bool:
        """News of ``drone``: if it is back and had not said where it is, forget where it might have been
        while it was gone (what it says now is the truth, however old its plan). Whether it had not."""
        if drone not in self.unreported:
            return False
        self.unreported.discard(drone)
        for gone in (self.ghosts, self.maybe_flown, self.hearsay, self.peers_down, self.peers_lost, self.braked,
                     self.held_until):
            gone.pop(drone, None)
        return True

    def _on_clock_bound(self, event: ClockBound, now: int) -> list[Action]:
        """My clock is off (every cell of the rest of my plan is held for good in my answers), or back
        within; ``outliers``' proposals get no ack of mine, and their plans are held for good."""
        newly_off = event.mine_off and self.off_since is None
        if newly_off:
            self.off_since = now
        elif not event.mine_off:
            self.off_since = None
        new, self.outliers = event.outliers - self.outliers, event.outliers
        if newly_off and self.state in (State.EXECUTING, State.REROUTING) and self.trajectory is not None:
            entry = self._entry(now)  # no rest can be planned anew with my clock off: stop short
            return self._brake(entry) if entry is not None else []
        if newly_off and self.trajectory is not None:  # at rest after a plan peers hold for good
            return self._tell_rest(now)
        return self._steer_clear(", ".join(sorted(new)), now) if new else []  # once, clear of them all

    def _on_vehicle_lost(self, event: VehicleLost, now: int) -> list[Action]:
        """Every peer is told at once where my vehicle may be: plans made before avoided only my plan."""
        self.lost = event
        return [Holding(self.holds())]

    def _on_relocated(self, event: Relocated, now: int) -> list[Action]:
        back: list[Action] = [Holding(())] if self.lost is not None else []
        self.location, self.trajectory, self.task, self.lost = event.cell, None, None, None
        self.state = State.WAIT_FOR_TASK
        return back

    def _on_peer_lost(self, event: PeerLost, now: int) -> list[Action]:
        """A peer's vehicle is lost, and may be in these cells for good: the plan I fly steers clear of
        them as of a vehicle down (brake, or plan its rest anew); every plan from now avoids them."""
        if event.drone == self.me or event.drone not in self.peers:
            return []
        self._reported(event.drone)
        if not event.cells:
            self.peers_lost.pop(event.drone, None)
            return []
        self.peers_lost[event.drone] = event.cells
        return self._steer_clear(event.drone, now)

    # ------------------------------------------------------------- planning
    def _plan_if_ready(self, now: int) -> list[Action]:
        if not self.members.issubset(self.received):
            return []
        assert self.task is not None
        task = self.task
        flying = self.trajectory if self.state is State.REROUTING else None
        start_step = now + self.lead_for(task)
        if flying is not None:  # later than the plan it replaces: peers order plans so, and a landed drone climbs
            start_step = max(start_step, flying.start_step + 1)
        here = flying.at(now) if flying is not None else self.location
        start = flying.at(start_step) if flying is not None else self.location
        psi = {**self.ghost_obstacles(sparing=here), **self._held_by_peers(now),
               **{p: self.received[p] for p in sorted(self.members)},
               **self._undecided(), **self._held_for_outliers(sparing=here),
               **{f"{p}!": Trajectory.stationary(c, now) for p, c in sorted(self.peers_down.items())},
               **{f"{p}~lost{i}": Trajectory.stationary(c, now) for p, cells in sorted(self.peers_lost.items())
                  for i, c in enumerate(cells) if c != here}}
        max_length = task.max_length(start_step)
        try:
            if not self.in_quorum():
                raise NoPlanFound(self._no_majority())
            if self.lost is not None:
                raise NoPlanFound("my vehicle is lost")
            if self.off_since is not None:
                raise NoPlanFound("my clock is beyond the fleet's bound")
            if self.down is not None:
                raise NoPlanFound("my vehicle is down")
            if max_length is not None and max_length < 0:
                raise NoPlanFound("the battery no longer affords the task")
            plan = self.plan(start, task.goal, start_step, psi, max_length)
        except NoPlanFound as exc:
            return self._no_plan(exc, now)
        trajectory = flying.spliced(plan.trajectory) if flying is not None else plan.trajectory
        proposal = PlanProposal(self.me, task.id, trajectory, tuple(sorted(self.members)))
        self.proposed = Proposed(proposal, tuple(psi.items()), plan.trajectory.start_step, flying is not None)
        self.state, self.acked = State.CONFIRMING, set()
        return [Broadcast(proposal), *self._go_if_held(now)]

    def _no_plan(self, exc: NoPlanFound, now: int) -> list[Action]:
        """I stay: my last plan (or my location) is still the truth, including the recent steps a peer up
        to Delta behind me still needs."""
        task = self.task
        assert task is not None
        if self.state is State.REROUTING and self.trajectory is not None:
            self.state = State.EXECUTING
            return [*self._release_pending(self.trajectory), RerouteFailed(task, str(exc))]
        self.state, self.task = State.WAIT_FOR_TASK, None
        failed = TaskFailed(task, str(exc), isinstance(exc, GoalCutOff))
        return [*self._release_pending(self.current_trajectory(now)), failed]

    # ------------------------------------------------------ confirming
    def _go_if_held(self, now: int) -> list[Action]:
        """Every member holds my plan: fly it, tell them so, and answer the peers that waited for it."""
        proposed = self.proposed
        if proposed is None or not self.members <= self.acked:
            return []
        assert self.task is not None
        trajectory = proposed.proposal.trajectory
        self.proposed, self.trajectory, self.state = None, trajectory, State.EXECUTING
        return [StartExecuting(self.task, trajectory, dict(proposed.psi)),
                Broadcast(PlanDecision(self.me, self.task.id, trajectory, flown=True)),
                *self._release_pending(trajectory)]

    def _abandon(self, reason: str, now: int) -> list[Action]:
        """Not every member held my plan in time (or the fleet changed since it was made): I fly what I
        flew before, as every peer still thinks I might, and tell them so."""
        proposed, task = self.proposed, self.task
        assert proposed is not None and task is not None
        self.proposed = None
        if proposed.rerouting:
            self.state = State.EXECUTING
            failed: Action = RerouteFailed(task, reason)
        else:
            self.state, self.task = State.WAIT_FOR_TASK, None
            failed = TaskFailed(task, reason)
        flown = self.current_trajectory(now)
        return [Broadcast(PlanDecision(self.me, task.id, flown, flown=False)), *self._release_pending(flown), failed]

    def _on_ack(self, event: PlanAck, now: int) -> list[Action]:
        """A member holds my plan (it checked it against what it knows: see :meth:`_clashes`), and says what
        it flies and holds: a plan across that is dropped (the acker's check runs on its clock)."""
        proposed = self.proposed
        if proposed is None or event.task_id != proposed.proposal.task_id:
            return []
        mine, since = proposed.proposal.trajectory, max(now, proposed.starts)
        theirs = [event.trajectory, *(Trajectory.stationary(c, 0) for c in event.holds)]
        if any(check_pair(mine, other, self.delta, from_step=since) for other in theirs):
            return self._abandon(f"{event.sender} flies or holds across it", now)
        self.acked.add(event.sender)
        return self._go_if_held(now)

    def _on_request_while_confirming(self, event: ReqForCurrentTraj, now: int) -> list[Action]:
        """My plan is made: every requester gets it once decided (within the lead). One from a drone I hold
        as gone is news of the fleet (see :meth:`_on_news_while_confirming`)."""
        if event.sender not in self.members and event.sender != self.me:
            return self._on_news_while_confirming(event, now)
        if event.sender == self.me or not self._current(event):
            return []
        self.pending[event.sender] = event.task_id
        return []

    def _on_next_step_while_confirming(self, event: NextStep, now: int) -> list[Action]:
        """The next boundary would pass my plan's start: too late to fly it."""
        assert self.proposed is not None
        rerouting = self.proposed.rerouting
        if self.proposed.starts <= now + 1:
            actions = self._abandon("not every peer held my plan in time", now)
        elif rerouting and self._entry(now) == now + 1:
            actions = self._abandon("braked", now)
        else:
            return []
        return _failure_last(actions, self._on_next_step(event, now) if rerouting else [])

    def _on_completed_while_confirming(self, event: PlanCompleted, now: int) -> list[Action]:
        """The plan flown ended before its new rest could be: I rest at its end (no plan flown: nothing)."""
        assert self.proposed is not None
        if not self.proposed.rerouting:
            return []
        return _failure_last(self._abandon("the plan ended first", now), self._on_completed(event, now))

    def _on_news_while_confirming(self, event: Event, now: int) -> list[Action]:
        """The fleet changed under my plan (a peer left, came back, came down, braked; my vehicle is lost or
        down): it avoided what no longer holds. I drop it, then take the news as I would flying."""
        if not self._changes_fleet(event):  # a peer I hold as gone already, or old news: nothing my plan did not avoid
            if isinstance(event, ClockBound):
                return self._on_clock_bound(event, now)
            return self._on_peer_lost(event, now) if isinstance(event, PeerLost) else []
        actions = self._abandon(f"{type(event).__name__} came before every peer held my plan", now)
        return _failure_last(actions, self.handle(event, now))

    def _changes_fleet(self, event: Event) -> bool:
        if isinstance(event, PeerJoined):  # it may fly a plan that I held it as gone through
            return event.drone not in self.members and event.drone != self.me
        if isinstance(event, ReqForCurrentTraj):
            return True
        if isinstance(event, PeerLeft):
            return event.drone in self.members
        if isinstance(event, PeerDown):
            return event.drone in self.peers and event.drone != self.me
        if isinstance(event, PeerBraked):
            return event.drone in self.members and (event.trajectory.start_step >= self.known[event.drone].start_step
                                                    or self._planned_before(event.drone, event.trajectory))
        if isinstance(event, ClockBound):
            return event.mine_off or bool(event.outliers - self.outliers)
        if isinstance(event, PeerLost):
            return event.drone in self.peers and event.drone != self.me and bool(event.cells)
        return True

    def _planned_before(self, drone: str, cut: Trajectory) -> bool:
        """Whether the plan I propose avoided what ``drone`` flew before its brake ``cut`` (its rest, heard
        since, can come before the brake)."""
        assert self.proposed is not None
        used = dict(self.proposed.psi).get(drone)
        return used is not None and _cut_overtakes(cut, used)

    # -------------------------------------------------- peers' proposals
    def _on_proposal(self, event: PlanProposal, now: int) -> list[Action]:
        """A member's plan, not flown yet: I hold it besides what I knew, until decided, and say so."""
        sender = event.sender
        decided = self.decided.get(sender)
        if sender == self.me or sender not in self.members or (
                decided is not None and not event.task_id.newer_than(decided)):
            return []  # decided already, or from a drone I hold as departed (it will not fly it)
        held = self.proposals.get(sender)
        if held is None or not held.task_id.newer_than(event.task_id):
            self.proposals[sender] = event
        if self.state is State.CONFIRMING or sender in self.outliers:
            return []  # not flown: it runs out of time (an outlier's steps are not ours)
        if self.off_since is None and self._clashes(event, now):
            # (my clock off, my steps say nothing: the cells my ack holds for good do)
            return [Send(sender, PlanRefusal(self.me, event.task_id, self._gone_there(event, now)))]
        return [Send(sender, PlanAck(self.me, event.task_id, self.current_trajectory(now), self.holds()))]

    def _clashes(self, proposal: PlanProposal, now: int) -> bool:
        """Whether ``proposal`` comes within the window of what I fly, or enters a cell where a drone its
        sender held as gone may be for good, as I know it: a member of mine may stop anywhere on the rest
        of what it flies or proposed (were it gone), a departed drone anywhere on its rest. A partition
        leaves views apart, and two plans made by majorities that overlap meet at a drone that holds
        both, here. (Confirming, I hold none: mine was made without it.)"""
        theirs = proposal.trajectory
        cells = {c for _, rest in self._gone_there(proposal, now) for c in rest}
        flown = [self.current_trajectory(now), *(Trajectory.stationary(c, 0) for c in {*self.holds(), *cells})]
        since = max(now, theirs.start_step)  # what it flew already was held before
        return any(check_pair(theirs, other, self.delta, from_step=since) for other in flown)

    def _gone_there(self, proposal: PlanProposal, now: int) -> tuple[tuple[str, tuple[Cell, ...]], ...]:
        """Each drone ``proposal``'s sender held as gone, with every cell it may be in for good as I know
        it, but where the proposer is (had it stopped there, they would have met)."""
        sender, here = proposal.sender, proposal.trajectory.at(now)
        gone_there = (self.members | set(self.ghosts)) - set(proposal.members) - {sender, self.me}
        found = []
        for p in sorted(gone_there):
            proposal_held = self.proposals.get(p)
            rests = [self.ghosts.get(p) or self.known[p].suffix_from(now - self.lead_steps), self.maybe_flown.get(p),
                     proposal_held.trajectory if proposal_held is not None else None]
            cells = {c for rest in rests if rest is not None for c in rest.cells} | self.hearsay.get(p, frozenset())
            found.append((p, tuple(sorted(cells - {here}))))
        return tuple(found)

    def _on_refusal(self, event: PlanRefusal, now: int) -> list[Action]:
        """A member will not hold my plan. Where it names cells a drone I hold as gone may be in, I hold
        them too from now (our views of where it stopped differ: its is the wider), so the next plan keeps
        clear of them; and I drop this one now rather than at its start."""
        proposed = self.proposed
        if proposed is None or event.task_id != proposed.proposal.task_id:
            return []
        for drone, cells in event.gone:
            if drone in self.peers and drone not in self.members and drone != self.me:
                self.hearsay[drone] = self.hearsay.get(drone, frozenset()) | frozenset(cells)
        return self._abandon(f"{event.sender} will not hold it: it flies, holds or knows of a drone across it",
                             now)

    def _on_decision(self, event: PlanDecision, now: int) -> list[Action]:
        sender = event.sender
        decided = self.decided.get(sender)
        if sender == self.me or (decided is not None and not event.task_id.newer_than(decided)):
            return []
        self.decided[sender] = event.task_id
        held = self.proposals.get(sender)
        if held is not None and not held.task_id.newer_than(event.task_id):
            del self.proposals[sender]
        if event.flown:
            self.heard(sender, event.trajectory)
            if sender in self.received:  # what it answered this round, or its request carried, is old
                self.received[sender] = self._news(sender, event.trajectory)
        return []

    def _held_for_outliers(self, sparing: Cell) -> dict[str, Trajectory]:
        """Every cell of what a peer whose clock is off answered, for good (its steps are not ours), but the
        one I am in (were it there, we would have met)."""
        return {f"{p}@{i}": Trajectory.stationary(cell, 0) for p in sorted(self.outliers & set(self.received))
                for i, cell in enumerate(dict.fromkeys(self.received[p].cells)) if cell != sparing}

    def _undecided(self) -> dict[str, Trajectory]:
        """Members' plans not decided yet (but the one a member answered with), which they may fly."""
        return {f"{p}?": proposal.trajectory for p, proposal in sorted(self.proposals.items())
                if p in self.members and proposal.trajectory != self.received.get(p)}

    def _held_by_peers(self, now: int) -> dict[str, Trajectory]:
        """The cells this round's answers hold besides their trajectories, as obstacles for good."""
        return {f"{peer}~{i}": Trajectory.stationary(cell, now) for peer, cells in self.peer_holds.items()
                if peer in self.members for i, cell in enumerate(cells)}

    def _release_pending(self, trajectory: Trajectory) -> Iterable[Action]:
        pending, self.pending = self.pending, {}
        holds = self.holds()
        return [Send(peer, CurrentTraj(self.me, trajectory, task_id, holds)) for peer, task_id in pending.items()]


def _rests_after(trajectory: Trajectory, cut: Trajectory) -> bool:
    """Whether ``trajectory`` is a peer's rest where its brake ``cut`` ends (one whose clock is off says
    so at once), not a new plan: the brake still overtakes older answers."""
    return trajectory.cells == (cut.last,) and trajectory.start_step >= cut.start_step


def _cut_overtakes(cut: Trajectory, older: Trajectory) -> bool:
    """Whether a peer's brake ``cut`` is news over ``older``, what I held of it: a plan that starts later
    ended the brake, and a brake only ever shortens a plan (of two cuts of one plan, the shorter is
    the newer)."""
    return older.start_step < cut.start_step or (older.start_step == cut.start_step and older.end_step > cut.end_step)


def _failure_last(abandoned: list[Action], then: list[Action]) -> list[Action]:
    """A dropped plan's actions, then what the news did (a brake, a threat), then the failure: the task
    planner decides what next knowing all of it (a reroute asked twice in one batch was refused)."""
    failed = [a for a in abandoned if isinstance(a, (TaskFailed, RerouteFailed))]
    return [*(a for a in abandoned if a not in failed), *then, *failed]


# Handlers take (protocol, event of the row's type, now); Callable[..., ...] since each takes its own type.
_Handler = Callable[..., list[Action]]

#: Everything that moves the protocol between states: TRANSITIONS[state][event type] -> handler.
#: An event missing from its state's row is a protocol violation.
TRANSITIONS: dict[State, dict[type, _Handler]] = {
    State.WAIT_FOR_TASK: {
        NewTask: CoordinationProtocol._on_new_task,  # -> COORDINATING
        ReqForCurrentTraj: CoordinationProtocol._on_request,  # answered with my location
        CurrentTraj: CoordinationProtocol._ignore,
        PeerLeft: CoordinationProtocol._on_peer_left,
        PeerJoined: CoordinationProtocol._on_peer_joined,
        VehicleLost: CoordinationProtocol._on_vehicle_lost,
        Relocated: CoordinationProtocol._on_relocated,
        VehicleDown: CoordinationProtocol._on_vehicle_down,  # -> WAIT_FOR_TASK
        PeerDown: CoordinationProtocol._on_peer_down,
        PeerBraked: CoordinationProtocol._on_peer_braked,
        PeerAnnounced: CoordinationProtocol._on_announced,
        Released: CoordinationProtocol._on_released,
        PlanProposal: CoordinationProtocol._on_proposal,  # held, and acknowledged
        PlanAck: CoordinationProtocol._ignore,  # a late one
        PlanRefusal: CoordinationProtocol._ignore,  # a late one
        PlanDecision: CoordinationProtocol._on_decision,
        ClockBound: CoordinationProtocol._on_clock_bound,
        PeerLost: CoordinationProtocol._on_peer_lost,
        NextStep: CoordinationProtocol._ignore,
    },
    State.COORDINATING: {
        ReqForCurrentTraj: CoordinationProtocol._on_request_while_coordinating,
        CurrentTraj: CoordinationProtocol._on_reply,  # -> CONFIRMING, or WAIT_FOR_TASK if no plan
        PeerLeft: CoordinationProtocol._on_peer_left,
        PeerJoined: CoordinationProtocol._on_peer_joined,
        VehicleLost: CoordinationProtocol._on_vehicle_lost,  # the round ends in no plan
        VehicleDown: CoordinationProtocol._on_vehicle_down,  # -> WAIT_FOR_TASK
        PeerDown: CoordinationProtocol._on_peer_down,
        PeerBraked: CoordinationProtocol._on_peer_braked,
        PeerAnnounced: CoordinationProtocol._on_announced,
        Released: CoordinationProtocol._on_released,
        PlanProposal: CoordinationProtocol._on_proposal,  # held, and acknowledged
        PlanAck: CoordinationProtocol._ignore,  # a late one
        PlanRefusal: CoordinationProtocol._ignore,  # a late one
        PlanDecision: CoordinationProtocol._on_decision,
        ClockBound: CoordinationProtocol._on_clock_bound,
        PeerLost: CoordinationProtocol._on_peer_lost,
        NextStep: CoordinationProtocol._on_next_step_while_coordinating,  # nothing is flown yet: ask again
    },
    State.EXECUTING: {
        ReqForCurrentTraj: CoordinationProtocol._on_request,  # answered with my trajectory
        CurrentTraj: CoordinationProtocol._ignore,
        PlanCompleted: CoordinationProtocol._on_completed,  # -> WAIT_FOR_TASK
        Reroute: CoordinationProtocol._on_reroute,  # -> REROUTING
        PeerLeft: CoordinationProtocol._on_peer_left,  # may report Threatened
        PeerJoined: CoordinationProtocol._on_peer_joined,
        VehicleLost: CoordinationProtocol._on_vehicle_lost,
        Relocated: CoordinationProtocol._on_relocated,  # -> WAIT_FOR_TASK
        VehicleDown: CoordinationProtocol._on_vehicle_down,  # -> WAIT_FOR_TASK
        PeerDown: CoordinationProtocol._on_peer_down,  # may brake, or report Threatened
        PeerBraked: CoordinationProtocol._on_peer_braked,  # may brake, or report Threatened
        PeerAnnounced: CoordinationProtocol._on_announced,
        Released: CoordinationProtocol._on_released,
        PlanProposal: CoordinationProtocol._on_proposal,  # held, and acknowledged
        PlanAck: CoordinationProtocol._ignore,  # a late one
        PlanRefusal: CoordinationProtocol._ignore,  # a late one
        PlanDecision: CoordinationProtocol._on_decision,
        ClockBound: CoordinationProtocol._on_clock_bound,
        PeerLost: CoordinationProtocol._on_peer_lost,
        NextStep: CoordinationProtocol._on_next_step,  # may brake
    },
    State.REROUTING: {  # a round as COORDINATING's, while the plan is flown on
        ReqForCurrentTraj: CoordinationProtocol._on_request_while_coordinating,
        CurrentTraj: CoordinationProtocol._on_reply,  # -> CONFIRMING the new rest, or EXECUTING the old one
        PlanCompleted: CoordinationProtocol._on_completed_while_rerouting,  # -> WAIT_FOR_TASK
        PeerLeft: CoordinationProtocol._on_peer_left,
        PeerJoined: CoordinationProtocol._on_peer_joined,
        VehicleLost: CoordinationProtocol._on_vehicle_lost,  # the round ends with the plan flown
        VehicleDown: CoordinationProtocol._on_vehicle_down,  # -> WAIT_FOR_TASK
        PeerDown: CoordinationProtocol._on_peer_down,  # may brake
        PeerBraked: CoordinationProtocol._on_peer_braked,  # may brake, or report Threatened
        PeerAnnounced: CoordinationProtocol._on_announced,
        Released: CoordinationProtocol._on_released,
        PlanProposal: CoordinationProtocol._on_proposal,  # held, and acknowledged
        PlanAck: CoordinationProtocol._ignore,  # a late one
        PlanRefusal: CoordinationProtocol._ignore,  # a late one
        PlanDecision: CoordinationProtocol._on_decision,
        ClockBound: CoordinationProtocol._on_clock_bound,
        PeerLost: CoordinationProtocol._on_peer_lost,
        NextStep: CoordinationProtocol._on_next_step,  # may brake
    },
    State.CONFIRMING: {  # planned: the plan is flown once every member holds it, or dropped
        PlanAck: CoordinationProtocol._on_ack,  # -> EXECUTING once every member's came
        PlanRefusal: CoordinationProtocol._on_refusal,  # -> WAIT_FOR_TASK (or EXECUTING), the plan dropped
        NextStep: CoordinationProtocol._on_next_step_while_confirming,  # too late: -> WAIT_FOR_TASK (or EXECUTING)
        ReqForCurrentTraj: CoordinationProtocol._on_request_while_confirming,  # answered once decided
        CurrentTraj: CoordinationProtocol._ignore,
        PlanCompleted: CoordinationProtocol._on_completed_while_confirming,  # -> WAIT_FOR_TASK
        # The plan avoided what these change: it is dropped, and the news taken as flying.
        PeerJoined: CoordinationProtocol._on_news_while_confirming,
        PeerLeft: CoordinationProtocol._on_news_while_confirming,
        PeerDown: CoordinationProtocol._on_news_while_confirming,
        PeerBraked: CoordinationProtocol._on_news_while_confirming,
        PeerAnnounced: CoordinationProtocol._on_announced,
        VehicleLost: CoordinationProtocol._on_news_while_confirming,
        VehicleDown: CoordinationProtocol._on_news_while_confirming,
        Released: CoordinationProtocol._on_released,
        PlanProposal: CoordinationProtocol._on_proposal,
        PlanDecision: CoordinationProtocol._on_decision,
        ClockBound: CoordinationProtocol._on_news_while_confirming,
        PeerLost: CoordinationProtocol._on_news_while_confirming,
    },
}
