"""The protocol's confirming: a plan is flown only once every member holds it (its own proposals, and
the peers' it holds, acks or refuses)."""

from __future__ import annotations

from drona_gcs.motion import Trajectory
from drona_gcs.stack.messages import PlanAck, PlanDecision, PlanProposal, PlanRefusal, ReqForCurrentTraj, TaskId
from drona_gcs.stack.protocol.actions import Action, Broadcast, RerouteFailed, Send, StartExecuting, TaskFailed
from drona_gcs.stack.protocol.events import (
    ClockBound,
    Event,
    NextStep,
    PeerBraked,
    PeerDown,
    PeerJoined,
    PeerLeft,
    PeerLost,
    PlanCompleted,
)
from drona_gcs.stack.protocol.flight import Flight
from drona_gcs.stack.protocol.knowledge import cut_overtakes
from drona_gcs.stack.protocol.meeting import meets
from drona_gcs.stack.protocol.state import State
from drona_gcs.workspace import Cell


class Confirming(Flight):
    """Protocol 1's handlers of plans proposed: mine, until every member holds it, and the peers'."""

    def _go_if_held(self, now: int) -> list[Action]:
        """Every member holds my plan: fly it, tell them so, and answer the peers that waited for it."""
        proposed = self.proposed
        if proposed is None or not self.members <= self.acked:
            return []
        assert self.task is not None
        trajectory = proposed.proposal.trajectory
        self._enter(State.EXECUTING)
        self.proposed, self.trajectory, self.unsettled = None, trajectory, None
        return [StartExecuting(self.task, trajectory, dict(proposed.psi)),
                Broadcast(PlanDecision(self.me, self.task.id, trajectory, flown=True)),
                *self._release_pending(trajectory)]

    def _drop(self, reason: str, now: int) -> list[Action]:
        """My plan will not be held as it is: a direct one is asked for instead, a round's abandoned."""
        assert self.proposed is not None
        return self._ask_instead(now) if self.proposed.direct else self._abandon(reason, now)

    def _ask_instead(self, now: int) -> list[Action]:
        raise NotImplementedError  # a round asks: see Rounds

    def _abandon(self, reason: str, now: int) -> list[Action]:
        """Not every member held my plan in time (or the fleet changed since it was made): I fly what I
        flew before, as every peer still thinks I might, and tell them so."""
        proposed, task = self.proposed, self.task
        assert proposed is not None and task is not None
        if proposed.rerouting:
            self._enter(State.EXECUTING)
            failed: Action = RerouteFailed(task, reason)
        else:
            self._enter(State.WAIT_FOR_TASK)
            self.task = None
            failed = TaskFailed(task, reason)
        self.proposed, self.unsettled = None, None
        flown = self.current_trajectory(now)
        return [Broadcast(PlanDecision(self.me, task.id, flown, flown=False)), *self._release_pending(flown), failed]

    def _on_ack(self, event: PlanAck, now: int) -> list[Action]:
        """A member holds my plan (it checked it against what it knows: see :meth:`_clashes`), and says what
        it flies and holds: a plan across that is dropped (the acker's check runs on its clock)."""
        proposed = self.proposed
        if proposed is None or (event.task_id, event.direct) != (proposed.proposal.task_id, proposed.direct):
            return []
        mine, since = proposed.proposal.trajectory, max(now, proposed.starts)
        theirs = [event.trajectory, *(Trajectory.stationary(c, 0) for c in event.holds)]
        if any(meets(mine, other, self.delta, since) for other in theirs):
            return self._drop(f"{event.sender} flies or holds across it", now)
        if proposed.direct:  # made against what I knew of it: what it says it flies is what the plan avoids
            self.proposed = proposed.avoiding(event.sender, event.trajectory)
        self.acked.add(event.sender)
        return self._go_if_held(now)

    def _on_refusal(self, event: PlanRefusal, now: int) -> list[Action]:
        """A member will not hold my plan. Where it names cells a drone I hold as gone may be in, I hold
        them too from now (our views of where it stopped differ: its is the wider), so the next plan keeps
        clear of them; and I drop this one now rather than at its start."""
        proposed = self.proposed
        if proposed is None or (event.task_id, event.direct) != (proposed.proposal.task_id, proposed.direct):
            return []
        for drone, cells in event.gone:
            if drone in self.peers and drone not in self.members and drone != self.me:
                self.hearsay[drone] = self.hearsay.get(drone, frozenset()) | frozenset(cells)
        return self._drop(f"{event.sender} will not hold it: it flies, holds or knows of a drone across it", now)

    def _on_next_step_while_confirming(self, event: NextStep, now: int) -> list[Action]:
        """The next boundary would pass my plan's start: too late to fly it."""
        assert self.proposed is not None
        rerouting = self.proposed.rerouting
        if self.proposed.starts <= now + 1:
            actions = self._drop("not every peer held my plan in time", now)
        elif rerouting and self._enters_next(now):
            actions = self._abandon("braked", now)
        else:
            return []
        return failure_last(actions, self._on_next_step(event, now) if rerouting else [])

    def _on_completed_while_confirming(self, event: PlanCompleted, now: int) -> list[Action]:
        """The plan flown ended before its new rest could be: I rest at its end (no plan flown: nothing)."""
        assert self.proposed is not None
        if not self.proposed.rerouting:
            return []
        return failure_last(self._abandon("the plan ended first", now), self._on_completed(event, now))

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
        return used is not None and cut_overtakes(cut, used)

    def _on_proposal(self, event: PlanProposal, now: int) -> list[Action]:
        """A member's plan, not flown yet: I hold it besides what I knew, until decided, and say so."""
        sender = event.sender
        if sender == self.me or sender not in self.members or self._decided_already(event) or self._asked_since(event):
            return []  # decided already, asked for instead, or from a drone I hold as departed (it will not fly it)
        self._hold_proposal(event)
        if sender in self.outliers:
            return []  # not flown: it runs out of time (an outlier's steps are not ours)
        asked: list[Action] = []
        if self.off_since is None and self._clashes(event, now):
            # (my clock off, my steps say nothing: the cells my ack holds for good do)
            if not self._yields_to(event, now):
                return [Send(sender, PlanRefusal(self.me, event.task_id, self._gone_there(event, now), event.direct))]
            asked = self._ask_instead(now)
        elif self.proposed is not None and (event.direct or self.proposed.direct):
            # Neither plan waited for the other (a direct one asks nobody): mine keeps clear of it, checked here.
            self.proposed = self.proposed.avoiding(f"{sender}?", event.trajectory)
        ack = PlanAck(self.me, event.task_id, self.current_trajectory(now), self.holds(), event.direct)
        return [Send(sender, ack), *asked]

    def _yields_to(self, proposal: PlanProposal, now: int) -> bool:
        """Whether my direct proposal gives way to ``proposal``, which comes before it in line and meets only it:
        two drones that proposed at once across each other would each refuse the other's."""
        mine, task = self.proposed, self.task
        return (mine is not None and task is not None and mine.direct and self._outranks(proposal.task_id, task.id)
                and not self._clashes(proposal, now, mine_too=False))

    def _outranks(self, theirs: TaskId, mine: TaskId) -> bool:
        return theirs < mine

    def _asked_since(self, proposal: PlanProposal) -> bool:
        """A direct proposal whose sender asked for its task since (messages reorder): it never flies it."""
        newest = self.newest.get(proposal.sender)
        return proposal.direct and newest is not None and not proposal.task_id.newer_than(newest)

    def _decided_already(self, proposal: PlanProposal) -> bool:
        decided = self.decided.get(proposal.sender)
        return decided is not None and not proposal.task_id.newer_than(decided)

    def _hold_proposal(self, proposal: PlanProposal) -> None:
        """Held until decided (the newest a drone proposed: it may fly it)."""
        held = self.proposals.get(proposal.sender)
        after_its_round = held is not None and held.task_id == proposal.task_id and proposal.direct > held.direct
        if (held is None or not held.task_id.newer_than(proposal.task_id)) and not after_its_round:
            self.proposals[proposal.sender] = proposal

    def _clashes(self, proposal: PlanProposal, now: int, mine_too: bool = True) -> bool:
        """Whether ``proposal`` comes within the window of what I fly, or enters a cell where a drone its
        sender held as gone may be for good, as I know it: a member of mine may stop anywhere on the rest
        of what it flies or proposed (were it gone), a departed drone anywhere on its rest. A partition
        leaves views apart, and two plans made by majorities that overlap meet at a drone that holds
        both, here. Confirming, I may fly my proposal or what I fly now: it keeps clear of both (``mine_too``:
        of what I fly alone)."""
        theirs = proposal.trajectory
        cells = {c for _, rest in self._gone_there(proposal, now) for c in rest}
        mine = [self.proposed.proposal.trajectory] if self.proposed is not None and mine_too else []  # I may fly either
        flown = [self.current_trajectory(now), *mine,
                 *(Trajectory.stationary(c, 0) for c in {*self.holds(), *cells})]
        since = max(now, theirs.start_step)  # what it flew already was held before
        return any(meets(theirs, other, self.delta, since) for other in flown)

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

    def _on_decision(self, event: PlanDecision, now: int) -> list[Action]:
        sender = event.sender
        decided = self.decided.get(sender)
        if sender == self.me or (decided is not None and not event.task_id.newer_than(decided)):
            return []
        self.decided[sender] = event.task_id
        held = self.proposals.get(sender)
        if held is not None and not held.task_id.newer_than(event.task_id):
            del self.proposals[sender]
        self.heard(sender, event.trajectory, now)  # its word on what it flies, the plan or not
        if event.flown:
            self.flown[sender] = event.trajectory
        if event.flown and sender in self.received:  # what it answered this round, or its request carried, is old
            self.received[sender] = self._news(sender, event.trajectory, now)
        return []


def failure_last(abandoned: list[Action], then: list[Action]) -> list[Action]:
    """A dropped plan's actions, then what the news did (a brake, a threat), then the failure: the task
    planner decides what next knowing all of it (a reroute asked twice in one batch was refused)."""
    failed = [a for a in abandoned if isinstance(a, (TaskFailed, RerouteFailed))]
    return [*(a for a in abandoned if a not in failed), *then, *failed]
