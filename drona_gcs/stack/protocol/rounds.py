"""The protocol's rounds: a task's (or a new rest's) requests and answers, membership meanwhile, and
the plan made once every member answered."""

from __future__ import annotations

from drona_gcs.errors import GoalCutOff, NoPlanFound
from drona_gcs.motion import Trajectory
from drona_gcs.stack.messages import CurrentTraj, PlanDecision, PlanProposal, ReqForCurrentTraj, Task
from drona_gcs.stack.protocol.actions import Action, Broadcast, RerouteFailed, Send, TaskFailed
from drona_gcs.stack.protocol.confirming import Confirming
from drona_gcs.stack.protocol.events import NewTask, NextStep, PeerJoined, PeerLeft, Reroute
from drona_gcs.stack.protocol.knowledge import Proposed
from drona_gcs.stack.protocol.state import State

#: steps a round waits for answers before it asks the members that have not answered again; twice
#: as long each time after, up to ASK_AGAIN_MOST_STEPS: answers late, not lost, are not asked for
#: again and again by every drone waiting (a fleet short of CPU then spends it all on asking)
ASK_AGAIN_STEPS = 4
ASK_AGAIN_MOST_STEPS = 32


class Rounds(Confirming):
    """Protocol 1's handlers of rounds: collecting every member's trajectory, then planning against them."""

    def _on_new_task(self, event: NewTask, now: int) -> list[Action]:
        if self._may_propose_at_once():
            self._enter(State.COORDINATING)
            self.task, self.pending = event.task, {}
            self._forget_answers()
            self.received = {p: self.known[p] for p in sorted(self.members)}
            planned = self._plan_if_ready(now, direct=True)
            if self.state is not State.COORDINATING:
                return planned
        return self._begin_round(event.task, State.COORDINATING, now)

    def _may_propose_at_once(self) -> bool:
        """Whether what I know of every member is its word (nobody is back unheard from, off the clock, or
        holding cells its answer alone would name): then I propose a plan made against it at once."""
        return self.propose_at_once and bool(self.members) and not (self.unreported or self.outliers or self.peers_lost)

    def _on_reroute(self, event: Reroute, now: int) -> list[Action]:
        return self._begin_round(event.task, State.REROUTING, now)

    def _begin_round(self, task: Task, state: State, now: int) -> list[Action]:
        self._enter(state)
        self.task, self.asked_at, self.asked_again = task, now, 0
        self._forget_answers()
        self.pending = {}
        if not self.in_quorum():  # nothing to ask: no plan could be flown
            return self._no_plan(NoPlanFound(self._no_majority()), now)
        actions: list[Action] = [Broadcast(self._request(now))]
        return actions + self._plan_if_ready(now)

    def _ask_instead(self, now: int) -> list[Action]:
        """My direct proposal is dropped undecided: the task goes on as a round, with the same id. Those who
        held the proposal hold it until the round's decision. The requests that came meanwhile are taken as
        the round takes any: one ahead of me in line has my request as my answer, one behind waits for my
        plan, its request its answer (held until decided, they would wait on each other until asked again)."""
        task = self.task
        assert task is not None and self.proposed is not None
        self.proposed, self.acked, self.unsettled = None, set(), task.id
        deferred, self.deferred = self.deferred, {}
        actions = self._begin_round(task, State.COORDINATING, now)
        for _, request in sorted(deferred.items()):
            actions += self._on_request_again(request, now)
        return actions

    def _on_request_again(self, request: ReqForCurrentTraj, now: int) -> list[Action]:
        if self.coordinating:
            return self._on_request_while_coordinating(request, now)
        if self.state is State.CONFIRMING:  # planned at once: nobody left to wait on
            self.pending[request.sender] = request.task_id
            return []
        return self._answer(request, now)  # the round ended with no plan: my location

    def _forget_answers(self) -> None:
        """A new round starts from no answers: last round's trajectories may have changed since."""
        self.received, self.peer_holds, self.pledged = {}, {}, {}

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
        self._answered(event.sender, event.trajectory, now)
        self.peer_holds[event.sender] = event.holds
        return [*admitted, *self._plan_if_ready(now)]

    def _answered(self, sender: str, trajectory: Trajectory, now: int) -> None:
        """``sender``'s answer this round, and my word from now on on what it flies."""
        self.received[sender] = self.known[sender] = self._news(sender, trajectory, now)

    def _on_reply(self, event: CurrentTraj, now: int) -> list[Action]:
        assert self.task is not None
        if event.in_reply_to != self.task.id or event.sender not in self.members:
            return []  # an answer to an older request, or from a drone that left
        sender, proposal = event.sender, event.proposal
        if proposal is not None and self._decided_already(proposal):
            self.received[sender] = self.known[sender]  # its decision came first: it said what it flies
        elif proposal is None and self._flown_since(sender, event.trajectory):
            self.received[sender] = self.known[sender]
        else:
            self._answered(sender, event.trajectory, now)
            if proposal is not None:
                self._hold_proposal(proposal)
                self.pledged[sender] = proposal.task_id
            else:  # its round is over: no decision of it to wait for
                self.pledged.pop(sender, None)
        self.peer_holds[sender] = event.holds
        return self._plan_if_ready(now)

    def _flown_since(self, sender: str, answer: Trajectory) -> bool:
        """Whether ``sender`` decided to fly a plan since it answered (a direct plan, which my round did not
        hold back; messages reorder), and that is still the last I know of it."""
        flown = self.flown.get(sender)
        return flown is not None and flown.start_step > answer.start_step and self.known[sender] == flown

    def _on_decision_while_coordinating(self, event: PlanDecision, now: int) -> list[Action]:
        """A decision I wait for (see :meth:`_wait_for_decisions`) is the answer it stood for."""
        self._on_decision(event, now)
        sender, pledged = event.sender, self.pledged.get(event.sender)
        if (pledged is None or pledged.newer_than(event.task_id)  # (a later decision also says what it flies)
                or sender in self.received or sender not in self.members):
            return []
        del self.pledged[sender]
        self._answered(sender, event.trajectory, now)
        return self._plan_if_ready(now)

    def _wait_for_decisions(self) -> bool:
        """No plan keeps clear of both what a peer flies and what it proposed: its decision will say which
        holds, and answer me (whether I wait for any). Once per proposal: a decision lost, I ask again,
        and its answer (with no proposal) ends the wait."""
        undecided = [p for p, task_id in self.pledged.items()
                     if p in self.proposals and self.proposals[p].task_id == task_id and p in self.received]
        for p in undecided:
            del self.received[p]
        return bool(undecided)

    def _on_next_step_while_coordinating(self, event: NextStep, now: int) -> list[Action]:
        return self._ask_again(now)

    def _ask_again(self, now: int) -> list[Action]:
        """A round still waiting :data:`ASK_AGAIN_STEPS` after it asked asks again the members that have not
        answered: one request lost (a link just back drops what it carries before its routes are up) would
        hold a round for good. A copy is harmless: it is answered, or held for an answer, again. Each
        time it waits twice as long (see :data:`ASK_AGAIN_MOST_STEPS`)."""
        if now - self.asked_at < min(ASK_AGAIN_STEPS << self.asked_again, ASK_AGAIN_MOST_STEPS):
            return []
        self.asked_at, self.asked_again = now, self.asked_again + 1
        request = self._request(now)
        return [Send(p, request) for p in sorted(self.members - set(self.received))]

    def _on_peer_left(self, event: PeerLeft, now: int) -> list[Action]:
        if event.drone not in self.members:
            return []
        self.members.discard(event.drone)
        self.flown.pop(event.drone, None)  # back, its agent may have restarted: its answers are news again
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
            return self._present(event.drone, now)
        self._leave_behind(event.drone, now)  # an outlier back: where it may have been stays held a while
        self.members.add(event.drone)
        self.released.discard(event.drone)
        self.proposals.pop(event.drone, None)
        self.newest.pop(event.drone, None)  # it may have restarted, and its clock with it
        self.known[event.drone] = event.announced(now)
        self.unreported.add(event.drone)
        told = self._present(event.drone, now)
        if self.coordinating and self.task is not None:
            return [*told, Send(event.drone, self._request(now))]
        return told

    def _plan_if_ready(self, now: int, direct: bool = False) -> list[Action]:
        """``direct``: the answers are what I know; no plan found, nothing is done (a round asks)."""
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
               **{p: self.received[p] for p in sorted(self.members)}, **self._braked_holds(),
               **self._undecided(), **self._held_for_outliers(sparing=here),
               **self._left_behind_obstacles(now, sparing=here),
               **{f"{p}!": Trajectory.stationary(c, now) for p, c in sorted(self.peers_down.items())},
               **{f"{p}~lost{i}": Trajectory.stationary(c, now) for p, cells in sorted(self.peers_lost.items())
                  for i, c in enumerate(cells) if c != here}}
        max_length = task.max_length(start_step)
        unfit = self._unfit_to_plan(max_length) or self._too_late(task, start_step)
        if unfit is not None:
            return self._no_plan(NoPlanFound(unfit), now)
        try:
            plan = self.plan(start, task.goal, start_step, psi, max_length)
        except NoPlanFound as exc:
            return [] if direct or self._wait_for_decisions() else self._no_plan(exc, now)
        trajectory = flying.spliced(plan.trajectory) if flying is not None else plan.trajectory
        proposal = PlanProposal(self.me, task.id, trajectory, tuple(sorted(self.members)), direct)
        self._enter(State.CONFIRMING)
        self.proposed = Proposed(proposal, tuple(psi.items()), plan.trajectory.start_step, flying is not None,
                                 direct)
        self.acked = set()
        # The peers that waited for me plan now, against what I fly and what I propose alike (held as
        # undecided): whichever I end up flying, their plans keep clear of it.
        return [Broadcast(proposal), *self._release_pending(self.current_trajectory(now), proposal),
                *self._go_if_held(now)]

    def _unfit_to_plan(self, max_length: int | None) -> str | None:
        """Why no plan of mine could be flown whatever the peers fly, if so."""
        if not self.in_quorum():
            return self._no_majority()
        if self.lost is not None:
            return "my vehicle is lost"
        if self.off_since is not None:
            return "my clock is beyond the fleet's bound"
        if self.down is not None:
            return "my vehicle is down"
        if max_length is not None and max_length < 0:
            return "the battery no longer affords the task"
        return None

    @staticmethod
    def _too_late(task: Task, start_step: int) -> str | None:
        if task.start_by is not None and start_step > task.start_by:
            return f"too late: a rest from step {start_step} would part from my plan past the cell it stops short of"
        return None

    def _no_plan(self, exc: NoPlanFound, now: int) -> list[Action]:
        """I stay: my last plan (or my location) is still the truth, including the recent steps a peer up
        to Delta behind me still needs."""
        task = self.task
        assert task is not None
        if self.state is State.REROUTING and self.trajectory is not None:
            self._enter(State.EXECUTING)
            return [*self._release_pending(self.trajectory), RerouteFailed(task, str(exc))]
        self._enter(State.WAIT_FOR_TASK)
        self.task = None
        failed = TaskFailed(task, str(exc), isinstance(exc, GoalCutOff))
        flown = self.current_trajectory(now)
        settled = [Broadcast(PlanDecision(self.me, task.id, flown, flown=False))] if self.unsettled == task.id else []
        self.unsettled = None
        return [*settled, *self._release_pending(flown), failed]
