"""Protocol 1 for one drone (:class:`CoordinationProtocol`), and the one table of its states
(:data:`TRANSITIONS`): the handlers live in :mod:`.rounds`, :mod:`.confirming` and :mod:`.flight`."""

from __future__ import annotations

from drona_gcs.motion import Trajectory
from drona_gcs.stack.messages import CurrentTraj, PlanAck, PlanDecision, PlanProposal, PlanRefusal, ReqForCurrentTraj
from drona_gcs.stack.protocol.actions import Action
from drona_gcs.stack.protocol.confirming import failure_last
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
from drona_gcs.stack.protocol.rounds import Rounds
from drona_gcs.stack.protocol.state import Move, State, Taking
from drona_gcs.stack.transitions import checked


class CoordinationProtocol(Rounds):
    """Protocol 1 for drone ``me``. ``peers`` maps each peer to where it starts. Its handlers come from
    :class:`.rounds.Rounds`, :class:`.confirming.Confirming` and :class:`.flight.Flight`, each built on the
    one after it (a round's plan is confirmed, a dropped one flown on), over :class:`.knowledge.Knowledge`."""

    def handle(self, event: Event, now: int) -> list[Action]:
        """Take one event at local step ``now``; return what to do. The table's entry for the event in this
        state names its handler, and the states it may lead to (:meth:`_enter` checks each change)."""
        admitted = self._alive(event, now)
        move = checked(f"drone {self.me!r}", self.state, type(event), TRANSITIONS[self.state].get(type(event)))
        outer, self._taking = self._taking, Taking(self.state, type(event), move.targets)
        try:
            return [*admitted, *move.handler(self, event, now)]
        finally:
            self._taking = outer

    def _alive(self, event: Event, now: int) -> list[Action]:
        """A message that says what a drone I hold as gone flies proves it alive (its lease outlasts what
        it sent before): a member again, there. (A request does so in :meth:`_admit`.) So does an
        announcement of its, which may come before its return does, and its news of its vehicle down
        or lost: its word, which what it sent before (an older plan, late) must not undo."""
        if isinstance(event, (PeerAnnounced, PeerBraked)):
            sender, flies = event.drone, event.trajectory
        elif isinstance(event, (CurrentTraj, PlanAck, PlanDecision)):
            sender, flies = event.sender, event.trajectory
        elif isinstance(event, PeerDown):
            sender, flies = event.drone, Trajectory.stationary(event.cell, now)
        elif isinstance(event, PeerLost) and event.drone in self.known:
            sender, flies = event.drone, self.known[event.drone]
        else:
            return []
        if sender in self.members or sender == self.me or sender not in self.peers:
            return []
        return self.handle(PeerJoined(sender, flies.last, flies), now)

    def _on_request_while_confirming(self, event: ReqForCurrentTraj, now: int) -> list[Action]:
        """My plan is made: every requester gets it once decided (within the lead). One from a drone I hold
        as gone is news of the fleet (see :meth:`_on_news_while_confirming`)."""
        if event.sender not in self.members and event.sender != self.me:
            return self._on_news_while_confirming(event, now)
        if event.sender == self.me or not self._current(event):
            return []
        self.pending[event.sender] = event.task_id
        if self.proposed is not None and self.proposed.direct:
            self.deferred[event.sender] = event
        return []

    def _on_news_while_confirming(self, event: Event, now: int) -> list[Action]:
        """The fleet changed under my plan (a peer left, came back, came down, braked; my vehicle is lost or
        down): it avoided what no longer holds. I drop it, then take the news as I would flying."""
        if not self._changes_fleet(event):  # a peer I hold as gone already, or old news: nothing my plan did not avoid
            if isinstance(event, ClockBound):
                return self._on_clock_bound(event, now)
            return self._on_peer_lost(event, now) if isinstance(event, PeerLost) else []
        actions = self._abandon(f"{type(event).__name__} came before every peer held my plan", now)
        return failure_last(actions, self.handle(event, now))


#: a round ends planned (flown at once if every member holds the plan already), or with no plan
_ENDS_ROUND = frozenset({State.CONFIRMING, State.EXECUTING, State.WAIT_FOR_TASK})
#: a round for a new rest ends planned (as a round does), or flying on the plan I have
_ENDS_REROUTE = frozenset({State.CONFIRMING, State.EXECUTING})
#: my proposal is flown, or dropped (a new rest dropped: I fly on the plan I have)
_DECIDES = frozenset({State.EXECUTING, State.WAIT_FOR_TASK})
_RESTS = frozenset({State.WAIT_FOR_TASK})
_BRAKES = frozenset({State.EXECUTING})  #: a brake ends a round for a new rest
#: my proposal is decided, or (a direct one, not held as it is) a round asks instead
_DECIDES_OR_ASKS = _DECIDES | frozenset({State.COORDINATING}) | _ENDS_ROUND

#: News every state takes alike: a peer's plan, announced, proposed or decided; a departed drone released.
_NEWS: dict[type, Move] = {
    PeerAnnounced: Move(CoordinationProtocol._on_announced),
    Released: Move(CoordinationProtocol._on_released),
    PlanProposal: Move(CoordinationProtocol._on_proposal),  # held, and acknowledged
    PlanDecision: Move(CoordinationProtocol._on_decision),
}
#: What every state but CONFIRMING (no plan of mine waits on the fleet) takes alike.
_UNCONFIRMED: dict[type, Move] = {
    **_NEWS,
    PlanAck: Move(CoordinationProtocol._ignore),  # a late one
    PlanRefusal: Move(CoordinationProtocol._ignore),  # a late one
    PeerJoined: Move(CoordinationProtocol._on_peer_joined),  # coordinating, asked too
    VehicleLost: Move(CoordinationProtocol._on_vehicle_lost),  # a round under way ends in no plan, or flown on
    VehicleDown: Move(CoordinationProtocol._on_vehicle_down, _RESTS),
}

#: Everything that moves the protocol between states: TRANSITIONS[state][event type] -> Move(handler, the
#: states it may lead to; none: it stays). An event missing from its state's row is a protocol violation.
TRANSITIONS: dict[State, dict[type, Move]] = {
    State.WAIT_FOR_TASK: {
        **_UNCONFIRMED,
        NewTask: Move(CoordinationProtocol._on_new_task, frozenset({State.COORDINATING}) | _ENDS_ROUND),
        ReqForCurrentTraj: Move(CoordinationProtocol._on_request),  # answered with my location
        CurrentTraj: Move(CoordinationProtocol._ignore),
        PeerLeft: Move(CoordinationProtocol._on_peer_left),
        Relocated: Move(CoordinationProtocol._on_relocated, _RESTS),
        PeerDown: Move(CoordinationProtocol._on_peer_down),
        PeerBraked: Move(CoordinationProtocol._on_peer_braked),
        ClockBound: Move(CoordinationProtocol._on_clock_bound),
        PeerLost: Move(CoordinationProtocol._on_peer_lost),
        NextStep: Move(CoordinationProtocol._ignore),
    },
    State.COORDINATING: {
        **_UNCONFIRMED,
        ReqForCurrentTraj: Move(CoordinationProtocol._on_request_while_coordinating, _ENDS_ROUND),
        CurrentTraj: Move(CoordinationProtocol._on_reply, _ENDS_ROUND),
        PeerLeft: Move(CoordinationProtocol._on_peer_left, _ENDS_ROUND),  # waited for no more
        PeerDown: Move(CoordinationProtocol._on_peer_down),
        PeerBraked: Move(CoordinationProtocol._on_peer_braked),
        ClockBound: Move(CoordinationProtocol._on_clock_bound),
        PeerLost: Move(CoordinationProtocol._on_peer_lost),
        NextStep: Move(CoordinationProtocol._on_next_step_while_coordinating),  # nothing is flown yet: ask again
        PlanDecision: Move(CoordinationProtocol._on_decision_while_coordinating, _ENDS_ROUND),  # may answer
    },
    State.EXECUTING: {
        **_UNCONFIRMED,
        ReqForCurrentTraj: Move(CoordinationProtocol._on_request),  # answered with my trajectory
        CurrentTraj: Move(CoordinationProtocol._ignore),
        PlanCompleted: Move(CoordinationProtocol._on_completed, _RESTS),
        Reroute: Move(CoordinationProtocol._on_reroute, frozenset({State.REROUTING}) | _ENDS_REROUTE),
        PeerLeft: Move(CoordinationProtocol._on_peer_left),  # may brake, or report Threatened
        Relocated: Move(CoordinationProtocol._on_relocated, _RESTS),
        PeerDown: Move(CoordinationProtocol._on_peer_down),  # may brake, or report Threatened
        PeerBraked: Move(CoordinationProtocol._on_peer_braked),  # may brake, or report Threatened
        ClockBound: Move(CoordinationProtocol._on_clock_bound),  # may brake
        PeerLost: Move(CoordinationProtocol._on_peer_lost),  # may brake, or report Threatened
        NextStep: Move(CoordinationProtocol._on_next_step),  # may brake
        Brake: Move(CoordinationProtocol._on_brake),  # no new rest: stop short of the cells held for good
    },
    State.REROUTING: {  # a round as COORDINATING's, while the plan is flown on
        **_UNCONFIRMED,
        ReqForCurrentTraj: Move(CoordinationProtocol._on_request_while_coordinating, _ENDS_REROUTE),
        CurrentTraj: Move(CoordinationProtocol._on_reply, _ENDS_REROUTE),
        PlanCompleted: Move(CoordinationProtocol._on_completed_while_rerouting, _RESTS),
        PeerLeft: Move(CoordinationProtocol._on_peer_left, _ENDS_REROUTE),
        PeerDown: Move(CoordinationProtocol._on_peer_down, _BRAKES),
        PeerBraked: Move(CoordinationProtocol._on_peer_braked, _BRAKES),  # or reports Threatened
        ClockBound: Move(CoordinationProtocol._on_clock_bound, _BRAKES),
        PeerLost: Move(CoordinationProtocol._on_peer_lost, _BRAKES),
        NextStep: Move(CoordinationProtocol._on_next_step, _BRAKES),
        PlanDecision: Move(CoordinationProtocol._on_decision_while_coordinating, _ENDS_REROUTE),  # may answer
    },
    State.CONFIRMING: {  # planned: the plan is flown once every member holds it, or dropped
        **_NEWS,
        PlanProposal: Move(CoordinationProtocol._on_proposal, _DECIDES_OR_ASKS),  # a direct one may give way
        PlanAck: Move(CoordinationProtocol._on_ack, _DECIDES_OR_ASKS),  # flown once every member's came
        PlanRefusal: Move(CoordinationProtocol._on_refusal, _DECIDES_OR_ASKS),  # dropped
        NextStep: Move(CoordinationProtocol._on_next_step_while_confirming, _DECIDES_OR_ASKS),  # too late: dropped
        ReqForCurrentTraj: Move(CoordinationProtocol._on_request_while_confirming, _DECIDES),  # answered once decided
        CurrentTraj: Move(CoordinationProtocol._ignore),
        PlanCompleted: Move(CoordinationProtocol._on_completed_while_confirming, _DECIDES),  # the rest dropped, I rest
        # The plan avoided what these change: it is dropped, and the news taken as flying.
        PeerJoined: Move(CoordinationProtocol._on_news_while_confirming, _DECIDES),
        PeerLeft: Move(CoordinationProtocol._on_news_while_confirming, _DECIDES),
        PeerDown: Move(CoordinationProtocol._on_news_while_confirming, _DECIDES),
        PeerBraked: Move(CoordinationProtocol._on_news_while_confirming, _DECIDES),
        VehicleLost: Move(CoordinationProtocol._on_news_while_confirming, _DECIDES),
        VehicleDown: Move(CoordinationProtocol._on_news_while_confirming, _DECIDES),
        ClockBound: Move(CoordinationProtocol._on_news_while_confirming, _DECIDES),
        PeerLost: Move(CoordinationProtocol._on_news_while_confirming, _DECIDES),
    },
}
