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

* **Task ids** are ``(HLC stamp and tick, drone, seq)`` (see :mod:`.messages`): globally
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
* **A task may skip the asking** (``propose_at_once``, on by default). What I know of every member
  (its last decision, announcement or answer, and the proposals I hold) stands for its answer: I plan
  against it and propose at once (``PlanProposal.direct``). The confirming below checks that plan where
  it counts: each member acks it only if it keeps clear of what the member flies and proposes, and
  says what it flies, which the plan must keep clear of too (and which it avoided, for whoever checks).
  Not held as it is (a refusal, an ack across it, too late), the task goes on as a round with the same
  id: the proposal is not decided until the round is, so peers hold it meanwhile, and the requests
  that came meanwhile are taken as the round takes any (held for the decision instead, a drone behind
  me in line and I waited on each other until asked again). Acks and refusals name which proposal of
  the task they answer, and a task's direct proposal never replaces its round's at a peer. Two drones
  that proposed at once across each other would each refuse the other's: the one behind in line acks
  the other's and asks instead. Two plans flown that neither waited for were each checked against the
  other by its own drone (the window is symmetric). Without a member unheard from since it came back,
  one whose clock is off, or a lost vehicle (what only an answer says), and with at least one member.
  An answer older than a plan its sender decided since (a direct plan my round did not hold back) is
  not planned with. A round once cost 5(N-1) messages; a task held at once costs 3(N-1).
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
  (``PlanDecision``). If the boundary before its start comes
  first, or the fleet changes meanwhile (a peer leaves, comes back, comes down, brakes), I drop it,
  say so, and the task fails (it is tried again). Why: a peer that left before it heard of my plan
  holds me, for good, on the cells of what it last knew I fly; had I flown a plan it never heard of,
  it planned into my cells (found by the tester's partitions, and in the field). A peer that held my
  proposal when I left holds its cells too (``maybe_flown``). A request that comes while I
  confirm is answered once decided.
* **The line moves on as I propose.** The peers that waited for my plan are answered as I propose
  it, with what I fly now and the proposal itself (``CurrentTraj.proposal``): they hold both, so
  their plans keep clear of whichever I fly. A round in line so waits for one plan and one
  message per drone before it, not for every ack. Sound: I ack their plans only if they keep clear
  of my proposal too (below), and I fly mine only once they acked it; so of any two plans flown,
  one was made against the other, or checked against it by the drone that could fly either (the
  window is symmetric). No plan keeps clear of both (my rest walls its goal off): it waits for
  my decision, which then stands for my answer. My decision came first (messages reorder): it
  said what I fly, and the answer's "what I fly now" is old.
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
  Confirming, I ack a proposal only if it keeps clear of my own as well: I may fly either, and
  whichever I fly, my plan and theirs keep apart (the window is symmetric). A message that says what a drone I held
  as gone flies (an answer, an ack, a decision, a request, its vehicle down or lost) proves it alive:
  a member again, there. Its news of its vehicle is its word on where it is: taken as the word of a
  drone back, an older plan of its, overtaken by that news, made a peer forget its vehicle was down
  and plan around it leaving (found by the tester's partition).
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
  with. No plan (or the old one ended first): I fly on what I have. A rest that
  stops short of a held cell must start before the plan flown enters it
  (``Task.start_by``); a round that would start it later ends with no plan. Sound as any
  round: my new rest avoids every answer, and a drone ahead of me in line plans
  against the plan I fly, which I do not change before it has planned. A cell
  crossed within ``lead_steps`` cannot be helped this way (found by the tester).
  No rest planned at all, nor one that stops short: I brake at once (``Brake``),
  short of the first held cell. Braked only the step before it, a peer that planned
  in behind me on my plan, its clock ahead, heard too late (found by the tester).
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
  Where a peer braked is held from its arrival there less my lead, by the plans I make as
  by the plan I fly: a plan made by the window alone went in first, then braked short of it
  as soon as flown, where the braked peer had still to pass (found by the tester).
* **A clock beyond the fleet's bound** (``ClockBound``, from the runtime's clock check). Mine off
  (most peers' clocks disagree with it), my steps are not the fleet's: I fly the plan I have to its
  end, or short of the first cell of any peer's plan (whenever it flies there), and hold there, plan
  nothing, and name every cell of that in my answers (``holds``), which peers hold for good. A peer's
  off: its proposals get no ack of mine, and every cell of what it answers is held for good; the plan
  I fly steers clear of every cell of its plan, as of a vehicle down (its steps are not ours). Nobody
  waits for it: it answers as ever. Its news (its rest, a new answer) frees no cell at once: it left
  one before it sent the news, which may find my clock up to Delta behind the fleet's, so what it was
  to fly stays held ``2 max(Delta, 1)`` steps more (``left_behind``; found by the tester, sweep 30391).
  My vehicle later than lambda is the same verdict (the runtime's lateness check), with the last step
  telemetry saw it on time (``on_time_at``): it flies my plan's cells in order, so it is somewhere on
  the plan from then on, and that is what I hold, not only the rest from when the lateness was found
  (a process behind its boundaries finds it steps late: found over 128 agents on 2 cores). Either
  way every peer is told at once where my vehicle may be (``Holding``, as for a lost vehicle, but
  ``for_now``: planned around, no wall for the task planner, which rejected mail there), again when
  my plan ends, and that it is no more once I am back within: a peer flying learns it without a
  round. A late vehicle stays held on the plan it flies until it is on time, though my steps end that
  plan first (``trailing``): a peer told only of my brake stopped in a cell my vehicle had still to
  leave (found over 128 agents).
* **The operator may release a departed drone** (``Released``): having seen its vehicle
  out of the air for good, it tells every drone to hold none of its cells.
* **My vehicle can be lost** (its link closed or silent). It may then be anywhere on
  my trajectory from when it was last seen, or where it was seen: I keep answering with
  my trajectory and also name those cells (``holds``), which every peer holds for good
  in the Psi of its next plans; I plan nothing meanwhile (a task fails at once). Every peer is
  told at once (``Holding``; ``PeerLost`` there), and steers clear of them as of a vehicle down. Holds
  are counted (``Holding.seq``: my incarnation, then a count), and a peer drops one older than the
  newest it heard from me: news reorders, and an old, wider hold come last held cells I had left for
  good (found by the tester's skews, sweep 30752). Once
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
  or answer lost must not hold it for good), each time twice as late, up to
  :data:`ASK_AGAIN_MOST_STEPS` (answers late under load are not asked for over and over).

Every transition is in :data:`TRANSITIONS`: for each state, the events it takes, the handler of each,
and the states taking it may lead to. The state changes in one place, ``_enter``, which checks each
change against the entry of the event being taken; an event a state does not take, or a change its
entry does not allow, raises :class:`~drona_gcs.errors.ProtocolViolation` naming both.

The package: :mod:`.events` and :mod:`.actions` (what it takes and gives), :mod:`.state` (its
states), :mod:`.knowledge` (what it knows, and the one place the state changes), the handlers of
:mod:`.rounds`, :mod:`.confirming` and :mod:`.flight`, :mod:`.meeting` (its quick separation check),
and :mod:`.machine` (the driver and the table).
"""

from drona_gcs.stack.protocol.actions import (
    Action,
    Braked,
    Broadcast,
    Grounded,
    Holding,
    Present,
    RerouteFailed,
    Send,
    StartExecuting,
    TaskFailed,
    Threatened,
)
from drona_gcs.stack.protocol.events import (
    Brake,
    ClockBound,
    Event,
    NewTask,
    NextStep,
    PeerAnnounced,
    PeerBraked,
    PeerDown,
    PeerJoined,
    PeerLeft,
    PeerLost,
    PlanCompleted,
    Released,
    Relocated,
    Reroute,
    VehicleDown,
    VehicleLost,
)
from drona_gcs.stack.protocol.knowledge import PlanFunction, Proposed
from drona_gcs.stack.protocol.machine import TRANSITIONS, CoordinationProtocol
from drona_gcs.stack.protocol.rounds import ASK_AGAIN_MOST_STEPS, ASK_AGAIN_STEPS
from drona_gcs.stack.protocol.state import Move, State

__all__ = [
    "ASK_AGAIN_MOST_STEPS", "ASK_AGAIN_STEPS", "TRANSITIONS", "Action", "Brake", "Braked", "Broadcast", "ClockBound",
    "CoordinationProtocol", "Event", "Grounded", "Holding", "Move", "NewTask", "NextStep", "PeerAnnounced",
    "PeerBraked", "PeerDown", "PeerJoined", "PeerLeft", "PeerLost", "PlanCompleted", "PlanFunction", "Present",
    "Proposed", "Released", "Relocated", "Reroute", "RerouteFailed", "Send", "StartExecuting", "State", "TaskFailed",
    "Threatened", "VehicleDown", "VehicleLost",
]
