"""The field's faults as transitions of the world: duplicates, cancels, vehicles down, crashed and restarted
agents, partitions and their heal, clocks beyond the fleet's bound (see :class:`.config.Faults`)."""

from __future__ import annotations

from dataclasses import replace

from drona_gcs.stack.drone import DroneStack
from drona_gcs.verify.config import PARTITION_STEPS, VERDICT_STEPS
from drona_gcs.verify.fleet import Transition
from drona_gcs.verify.monitors import SKEW_STEPS
from drona_gcs.verify.mutants import plant
from drona_gcs.verify.network import Joined, Left
from drona_gcs.verify.notices import describe
from drona_gcs.verify.service import Service
from drona_gcs.verify.verdicts import cell_text
from drona_gcs.workspace import Cell


class FieldFaults(Service):
    """The fleet and its service, with the faults the field may throw at them."""

    def _faults(self) -> list[Transition]:
        """The field's faults still allowed: a duplicate of a message in flight, a cancel of a mail that
        was given, a vehicle down (never the last one flying)."""
        limit, used, moves = self.config.faults, self.used, []
        if used.duplicates < limit.duplicates:  # liveliness changes come once each
            moves += [("duplicate", m.seq) for m in self.inflight if not isinstance(m.message, (Left, Joined))]
        if used.cancels < limit.cancels:
            moves += [("cancel", j) for j in range(self.injected)
                      if self.config.requests[j].id not in self.monitors.settled]
        in_service = [i for i, d in enumerate(self.config.drones) if d not in self.down and d not in self.crashed]
        if used.downs < limit.downs and len(in_service) > 1:
            moves += [("down", i) for i in in_service]
        if used.crashes < limit.crashes and len(in_service) > 1:
            moves += [("crash", i) for i in in_service]
        # A process that dies closes its links at once: its peers see it leave before it can restart.
        leaving = {m.sender for m in self.inflight if isinstance(m.message, Left)}
        moves += [("restart", i) for i, d in enumerate(self.config.drones) if d in self.crashed and d not in leaving]
        if self.apart:
            moves.append(("heal", 0))
        elif used.partitions < limit.partitions and len(in_service) > 1:
            moves += [("partition", i) for i in in_service]
        if used.skews < limit.skews and len(in_service) > 2:  # most clocks must agree for a verdict
            moves += [("skew", 2 * i + behind) for i in in_service if self._crossing(self.config.drones[i])
                      for behind in (0, 1)]
        moves += [("verdict", i) for i, d in enumerate(self.config.drones)
                  if self.told.get(d, frozenset()) != self.skewed]
        return moves

    def _duplicate(self, seq: int) -> None:
        self.used = replace(self.used, duplicates=self.used.duplicates + 1)
        copy = self.net.duplicate(seq)
        self.trace.append(f"net: duplicates {describe(copy.message)} to {copy.to}")

    def _cancel(self, j: int) -> None:
        request = self.config.requests[j]
        self.used = replace(self.used, cancels=self.used.cancels + 1)
        holder = self._holder(request.id)
        taken = holder is not None and self.stacks[holder].cancel(request.id)
        self.trace.append(f"env: cancel {request.id}" + (f" (taken back from {holder})" if taken else " (too late)"))
        if taken:
            self.monitors.cancelled(holder or "", request)
            self.holder.pop(request.id, None)

    def _holder(self, mail_id: str) -> str | None:
        for drone, stack in self.stacks.items():
            if any(r.id == mail_id for r in stack.mail.queue):
                return drone
        return None

    def _crossing(self, drone: str) -> bool:
        """Whether the rest of ``drone``'s plan enters a cell the rest of another drone's does: only plans
        made in step with a clock can meet once it is off, so the tester spends that fault there."""
        rest = self._rest_of_plan(drone)
        return drone not in self.skewed and any(rest & self._rest_of_plan(d) for d in self.config.drones if d != drone)

    def _rest_of_plan(self, drone: str) -> set[Cell]:
        trajectory = self.stacks[drone].protocol.trajectory
        return set(trajectory.suffix_from(self.steps[drone]).cells) if trajectory is not None else set()

    def _skew(self, drone: str, ahead: bool) -> None:
        """``drone``'s clock goes beyond the fleet's bound, Delta + SKEW_STEPS steps ahead or behind. Until
        every clock check has said so, the clocks still keep within Delta (a drifting clock is found off
        as it crosses the bound), and every check does within VERDICT_STEPS; then its steps keep within
        Delta of the others' shifted so."""
        self.used = replace(self.used, skews=self.used.skews + 1)
        self.skewed |= {drone}
        self.offsets[drone] = (1 if ahead else -1) * (self.config.delta + SKEW_STEPS)
        self.verdict_by = min(self.steps.values()) + VERDICT_STEPS
        self.trace.append(f"{drone}: its clock goes {'ahead of' if ahead else 'behind'} the fleet's bound")

    def _verdict(self, drone: str) -> None:
        """``drone``'s clock check finds the skewed clocks off (its own, or its peers'): as the agent, it
        tells its stack, and takes no task while its own is off. Once every drone knows of a skewed
        clock, that clock keeps to its offset (see _skew)."""
        self.told[drone] = self.skewed
        mine_off = drone in self.skewed
        self.monitors.clock_verdict(drone, self.skewed)
        self.trace.append(f"{drone}: its clock check finds off {sorted(self.skewed)}")
        self._carry_out(drone, self.stacks[drone].clock_bound(mine_off, self.skewed - {drone},
                                                              f"clock beyond the bound: {sorted(self.skewed)}"))
        known = frozenset.intersection(*(self.told.get(d, frozenset()) for d in self.config.drones))
        if known == self.skewed:
            self.verdict_by = None
        if known - self.unbound:
            self.monitors.unbound({d: self.offsets[d] for d in known - self.unbound}, self.steps)
            self.unbound = known

    def _crash(self, drone: str) -> None:
        """Its agent dies: the vehicle holds the cell it is in, in the air; its mail is handed back
        (lost, if on board: nobody reports it any more); its peers see it leave."""
        self.used = replace(self.used, crashes=self.used.crashes + 1)
        self.crashed.add(drone)
        stack, step = self.stacks[drone], self.steps[drone]
        self.trace.append(f"{drone}: its agent crashed; its vehicle holds {cell_text(stack.executor.cell)}")
        # What was on its way to it is lost with its session (a new one never sees it).
        lost = self.net.drop(lambda m: m.to == drone)
        if lost:
            self.trace.append(f"net: {len(lost)} message(s) to {drone} lost")
        self._carry_out(drone, stack.mail.abandon(f"drone {drone}'s agent crashed"))  # the service hears none
        self.unheard.pop(drone, None)
        self._service_lost(drone)
        for peer in self.config.drones:
            if peer != drone:
                self._post(drone, peer, Left(step))

    def _restart(self, drone: str) -> None:
        """Its agent starts again where its vehicle holds, knowing nothing of its peers; they see it join."""
        self.crashed.discard(drone)
        old = self.stacks[drone]
        peers = {**dict(zip(self.config.drones, self.config.starts, strict=True)), drone: old.executor.cell}
        self.stacks[drone] = DroneStack(drone, old.config, peers, epoch=old.clock.epoch + 1)
        self.stacks[drone].mail.cleared = set()
        plant(self.stacks[drone], self.config.bugs)
        self._service_back_new(drone)
        self.trace.append(f"{drone}: its agent restarts at {cell_text(old.executor.cell)}")
        self.last_injection_step = min(self.steps.values())  # (d)'s bound runs from the field's last change
        self.monitors.restarted(drone, old.executor.cell, self.steps[drone])
        for peer in self.config.drones:
            if peer == drone:
                continue
            self._post(drone, peer, Joined())
            if not self._across(drone, peer) and peer not in self.crashed:  # their tokens, as the agent sees
                self._post(peer, drone, Joined(), liveliness=True)
            if self._across(drone, peer) or peer in self.crashed:  # as the agent does: no token, no member
                self.monitors.left(drone, peer)
                self._carry_out(drone, self.stacks[drone].peer_left(peer))

    def _partition(self, drone: str) -> None:
        """The network cuts ``drone`` off from the rest: what is in flight across the cut is lost, and
        each side sees the other leave (its lease runs out), both alive and flying on."""
        self.used = replace(self.used, partitions=self.used.partitions + 1)
        self.apart = frozenset({drone})
        self.heal_by = min(self.steps.values()) + PARTITION_STEPS
        self.trace.append(f"net: {drone} is cut off from the rest")
        lost = self.net.drop(lambda m: self._across(m.sender, m.to) and not isinstance(m.message, (Left, Joined)))
        if lost:
            self.trace.append(f"net: {len(lost)} message(s) across the cut lost")
        for a, b in self._pairs_across():
            self._post(a, b, Left(self.steps[a]), liveliness=True)
        if drone not in self.crashed:  # each sees the other's token go
            self._service_lost(drone)
            self._carry_out(drone, self.stacks[drone].service_lost())

    def _heal(self) -> None:
        """The partition heals: each side sees the other join again."""
        pairs = self._pairs_across()
        back, self.apart, self.heal_by = self.apart, frozenset(), None
        for drone in sorted(back):  # the service's token back: the drone's last word on each mail again
            for action in self.unheard.pop(drone, {}).values():
                self._service_hears(drone, action)
        self.trace.append("net: the partition heals")
        self.last_injection_step = min(self.steps.values())  # (d)'s bound runs from the field's last change
        for a, b in pairs:
            self._post(a, b, Joined(), liveliness=True)

    def _pairs_across(self) -> list[tuple[str, str]]:
        """Ordered pairs of drones on either side of the cut, agents alive."""
        return [(a, b) for a in self.config.drones for b in self.config.drones
                if self._across(a, b) and a not in self.crashed and b not in self.crashed]

    def _vehicle_down(self, drone: str) -> None:
        self.used = replace(self.used, downs=self.used.downs + 1)
        self.down[drone] = self.stacks[drone].executor.cell  # on the ground below where it flew
        self.monitors.vehicle_down(drone, self.down[drone], max(self.steps[drone], 0))
        self.trace.append(f"{drone}: its vehicle came down by itself")
        self._carry_out(drone, self.stacks[drone].vehicle_down(f"drone {drone}'s vehicle came down",
                                                               self.down[drone]))
