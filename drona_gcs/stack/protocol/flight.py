"""The protocol's handlers of news for the plan a drone flies (a peer's vehicle down, lost or braked, a
clock off, the plan's end): it brakes, or has the rest of its plan made anew."""

from __future__ import annotations

from drona_gcs.errors import ProblemError
from drona_gcs.motion import Trajectory
from drona_gcs.stack.protocol.actions import (
    Action,
    Braked,
    Grounded,
    Holding,
    Present,
    RerouteFailed,
    TaskFailed,
    Threatened,
)
from drona_gcs.stack.protocol.events import (
    Brake,
    ClockBound,
    Event,
    NextStep,
    PeerAnnounced,
    PeerBraked,
    PeerDown,
    PeerLost,
    PlanCompleted,
    Released,
    Relocated,
    VehicleDown,
    VehicleLost,
)
from drona_gcs.stack.protocol.knowledge import Knowledge, cut_overtakes, rests_after
from drona_gcs.stack.protocol.state import State
from drona_gcs.workspace import Cell


class Flight(Knowledge):
    """Protocol 1's handlers of news for the plan I fly, or rest at the end of."""

    def _ignore(self, event: Event, now: int) -> list[Action]:
        return []  # a late reply to a round that is over

    def _on_announced(self, event: PeerAnnounced, now: int) -> list[Action]:
        self.heard(event.drone, event.trajectory, now)
        return []

    def _on_completed(self, event: PlanCompleted, now: int) -> list[Action]:
        """I rest at my plan's end. Out of the fleet's bound, my steps are not the fleet's: peers hold for
        good every cell of the plan they last heard of, so I tell them at once that I rest in one (a late
        vehicle, still on its way, is held on the plan's cells too), and answer with it from now on."""
        assert self.trajectory is not None
        self._enter(State.WAIT_FOR_TASK)
        self.location, self.task = self.trajectory.last, None
        return [*self._tell_rest(now), self._holding()] if self.off_since is not None else []

    def _tell_rest(self, now: int) -> list[Action]:
        """With my clock off, I say at once that I rest in my location alone, and answer with it."""
        self.trajectory = Trajectory.stationary(self.location, now)
        return [Present(peer, self.trajectory, braked=False) for peer in sorted(self.peers) if peer != self.me]

    def _holding(self) -> Holding:
        """Where my vehicle may be, for every peer: for now if it is late or my clock is off, for good if lost."""
        return self._new_holds(self.holds(), for_now=self.lost is None)

    def _new_holds(self, cells: tuple[Cell, ...], for_now: bool = False) -> Holding:
        self.holds_told += 1
        return Holding(cells, for_now, self.holds_seq)

    def _on_completed_while_rerouting(self, event: PlanCompleted, now: int) -> list[Action]:
        """The plan ended before its new rest was planned: the round is moot, and I rest at its end."""
        assert self.task is not None and self.trajectory is not None
        failed = RerouteFailed(self.task, "the plan ended first")
        self._enter(State.WAIT_FOR_TASK)
        self.location, self.task = self.trajectory.last, None
        return [*self._release_pending(self.trajectory), failed]

    def _on_vehicle_down(self, event: VehicleDown, now: int) -> list[Action]:
        """My vehicle is on the ground in ``event.cell`` for good: that is my trajectory from now, every
        peer is told, and a round under way ends with no plan."""
        task = self.task if self.coordinating else None
        rerouting = self.state is State.REROUTING
        self._enter(State.WAIT_FOR_TASK)
        self.down, self.location, self.task = event.cell, event.cell, None
        self.trajectory = Trajectory.stationary(event.cell, now)
        actions: list[Action] = [Grounded(self.trajectory), *self._release_pending(self.trajectory)]
        if task is not None and rerouting:
            actions.append(RerouteFailed(task, "my vehicle is down"))
        elif task is not None:
            actions.append(TaskFailed(task, "my vehicle is down"))
        return actions

    def _on_vehicle_lost(self, event: VehicleLost, now: int) -> list[Action]:
        """Every peer is told at once where my vehicle may be: plans made before avoided only my plan."""
        self.lost = event
        return [self._new_holds(self.holds())]

    def _on_relocated(self, event: Relocated, now: int) -> list[Action]:
        back: list[Action] = [self._new_holds(())] if self.lost is not None else []
        self._enter(State.WAIT_FOR_TASK)
        self.location, self.trajectory, self.task, self.lost = event.cell, None, None, None
        return back

    def _on_peer_down(self, event: PeerDown, now: int) -> list[Action]:
        """A peer's vehicle is on the ground for good: an obstacle for every plan from now, and for
        the plan I fly (which avoided its plan, not this) if that crosses it."""
        if event.drone == self.me or event.drone not in self.peers:
            return []
        self._reported(event.drone)
        self._leave_behind(event.drone, now)
        self.peers_down[event.drone] = event.cell
        self.proposals.pop(event.drone, None)
        self.braked.pop(event.drone, None)  # it stays where it came down: where it braked is free
        self.held_until.pop(event.drone, None)
        stays = Trajectory.stationary(event.cell, now)
        self.known[event.drone] = stays
        if event.drone in self.received:
            self.received[event.drone] = stays
        return self._steer_clear(event.drone, now)

    def _on_peer_braked(self, event: PeerBraked, now: int) -> list[Action]:
        """A peer holds where it braked, which plans made before (mine among them) did not avoid: it
        overrides what it answered of that plan, and the plan I fly steers clear of it as of a vehicle
        down (brake, or plan its rest anew)."""
        drone, cut = event.drone, event.trajectory
        if drone == self.me or drone not in self.members:
            return []
        held = self.braked.get(drone)
        if held is not None and not cut_overtakes(cut, held):
            return []  # it cut that plan again since, shorter
        known = self.known[drone]
        resting = rests_after(known, cut)  # it said it rests where it braked: the brake holds on
        if not self._reported(drone) and cut.start_step < known.start_step and not resting:
            answered = self.received.get(drone)
            if answered is not None and cut_overtakes(cut, answered):
                self.received[drone] = cut  # my round's answer was of the plan it cut
            return []  # a plan of its made since ended the brake
        self.braked[drone] = cut
        if not resting:
            self.known[drone] = cut
        if drone in self.received:
            self.received[drone] = self._news(drone, self.received[drone], now)
        return self._steer_clear(drone, now)

    def _on_peer_lost(self, event: PeerLost, now: int) -> list[Action]:
        """A peer's vehicle is lost, and may be in these cells for good: the plan I fly steers clear of
        them as of a vehicle down (brake, or plan its rest anew); every plan from now avoids them."""
        if event.drone == self.me or event.drone not in self.peers:
            return []
        if event.seq < self.holds_heard.get(event.drone, (0, 0)):
            return []  # older than holds it sent since: late news
        self.holds_heard[event.drone] = event.seq
        self._reported(event.drone)
        if not event.cells:
            self.peers_lost.pop(event.drone, None)
            self.peers_late.discard(event.drone)
            return []
        self.peers_lost[event.drone] = event.cells
        (self.peers_late.add if event.for_now else self.peers_late.discard)(event.drone)
        return self._steer_clear(event.drone, now)

    def _on_released(self, event: Released, now: int) -> list[Action]:
        """Forget where a departed drone may be: its ghost, its vehicle down, its brake."""
        if event.drone == self.me or event.drone in self.members or event.drone not in self.peers:
            raise ProblemError(f"{event.drone} is not a drone gone from the fleet: nothing to release")
        for held in (self.ghosts, self.maybe_flown, self.peers_down, self.braked, self.known, self.peers_lost,
                     self.hearsay, self.held_until):
            held.pop(event.drone, None)
        self.peers_late.discard(event.drone)
        self.released.add(event.drone)
        return []

    def _on_clock_bound(self, event: ClockBound, now: int) -> list[Action]:
        """My clock is off (every cell of the rest of my plan is held for good in my answers), or back
        within; ``outliers``' proposals get no ack of mine, and their plans are held for good."""
        was_off = self.off_since is not None
        newly_off = event.mine_off and not was_off
        if newly_off:
            self.off_since = now if event.on_time_at is None else min(now, event.on_time_at)
        elif not event.mine_off:
            self.off_since = self.trailing = None
        new, self.outliers = event.outliers - self.outliers, event.outliers
        actions: list[Action] = []
        if newly_off and self.state in (State.EXECUTING, State.REROUTING) and self.trajectory is not None:
            entry = self._entry(now)  # no rest can be planned anew with my clock off: stop short
            actions = self._brake(entry) if entry is not None else []
            self.trailing = self.trajectory if event.on_time_at is not None else None
        elif newly_off and self.trajectory is not None:  # at rest after a plan peers hold for good
            self.trailing = self.trajectory if event.on_time_at is not None else None
            actions = self._tell_rest(now)
        elif new:
            actions = self._steer_clear(", ".join(sorted(new)), now)  # once, clear of them all
        if event.mine_off != was_off:  # peers wait for no round of theirs to hear where my vehicle may be
            actions.append(self._holding())
        return actions

    def _on_next_step(self, event: NextStep, now: int) -> list[Action]:
        return self._brake(now + 1) if self._enters_next(now) else []

    def _on_brake(self, event: Brake, now: int) -> list[Action]:
        """No new rest clear of the cells held for good on my plan: I stop short of the first now. Peers
        that planned in behind me, on my plan, then have time to keep clear of where I stop; told the
        step before I would enter it, one whose clock runs ahead has none (found by the tester)."""
        entry = self._entry(now) if self.trajectory is not None else None
        return self._brake(entry) if entry is not None else []

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

    def _enters_next(self, now: int) -> bool:
        """Whether :meth:`_entry` is ``now + 1``, from the two steps that decide it (every boundary asks)."""
        return self.trajectory is not None and self._held_on_plan(now, now + 1) == [now + 1]

    def _held_on_plan(self, now: int, through: int | None = None) -> list[int]:
        """The steps from ``now`` on at which the plan I fly is in a cell held for good: a vehicle down's,
        one a departed drone may hold, one of the plan of a peer whose clock is off (or of any peer's, with
        mine off: our steps are not the same), or one a braked peer holds from when it gets there (less my
        lead, a margin for its clock) until the plan it made since starts (and Delta more), or one left
        behind by a peer whose steps are not mine, to the step it is held to. Up to step ``through``
        (None: the plan's end)."""
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
                c == cell and step <= until + self.delta for c, until in self.held_until.values()) or (
                cell != here and self.left_behind.get(cell, -1) >= step)

        last = max(now, trajectory.end_step) if through is None else min(through, max(now, trajectory.end_step))
        return [t for t in range(now, last + 1) if taken(t)]

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
            self._enter(State.EXECUTING)
            actions += [*self._release_pending(self.trajectory), RerouteFailed(self.task, "braked")]
        return actions
