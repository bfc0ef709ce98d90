"""A simulated fleet for the systematic tester: the real stacks over an in-memory network.

The world is the paper's mixed-synchronous abstraction (section 4.2). Its
transitions are:

* ``("deliver", k)``: the network hands in-flight message ``k`` to its
  receiver. Messages are delivered in any order (a bag, not a queue), but
  within ``max_delay`` steps: real links are fast compared with tau, and an
  unbounded delay would let the tester starve a drone of its replies forever.
* ``("inject",)``: the environment assigns the next mail request.
* ``("step", i)``: drone ``i``'s periodic processes take their next step
  boundary (executor, battery, task planner). The scheduler ``rho_Delta``
  allows it only while every pair of step counts stays within Delta
  (approximate synchrony, ``|N_i - N_j| <= Delta``). With Delta 0 the only
  step is ``("step", -1)``: every drone at once (the paper's set-valued label).

Asynchronous processes interleave freely with each other and with the
periodic ones. Monitors judge every transition; see :mod:`.monitors`.

Its layers: :mod:`.network` (the messages in flight), :mod:`.fleet` (the world's state),
:mod:`.service` (the mail's dispatch), :mod:`.faults` (the field's faults), and here the scheduler.
"""

from __future__ import annotations

import copy
from collections.abc import Hashable

from drona_gcs.stack.messages import PlanProposal, ReqForCurrentTraj
from drona_gcs.verify.config import (
    MAX_DRAWS,
    MODEL_CLIMB_STEPS,
    PARTITION_STEPS,
    UPGRADE,
    VERDICT_STEPS,
    Faults,
    Upgrade,
    WorldConfig,
    make_world_config,
    model_hover_lead,
    model_lead,
    tester_workspace,
)
from drona_gcs.verify.faults import FieldFaults
from drona_gcs.verify.fleet import Transition
from drona_gcs.verify.liveness import Flier
from drona_gcs.verify.network import InFlight, Joined, Left
from drona_gcs.verify.notices import SERVICE, Announce, Clear, Holds, Notice, describe
from drona_gcs.verify.snapshot import clone_stack, key_of_stack, shallow

__all__ = [
    "MAX_DRAWS", "MODEL_CLIMB_STEPS", "PARTITION_STEPS", "SERVICE", "UPGRADE", "VERDICT_STEPS", "Announce", "Clear",
    "Faults", "InFlight", "Joined", "Left", "Notice", "Transition", "Upgrade", "World", "WorldConfig",
    "make_world_config", "model_hover_lead", "model_lead", "tester_workspace",
]


class World(FieldFaults):
    """The fleet, its service and its faults, under the scheduler's transitions."""

    # -------------------------------------------------------- scheduling
    def enabled(self) -> list[Transition]:
        moves: list[Transition] = [("deliver", m.seq) for m in self.net.deliverable()]
        serving = bool(self._serving())  # else handed-back mail waits in the service's queue
        if self.injected < len(self.config.requests) or (self.redispatch and serving):
            moves.append(("inject", 0))
        moves += self._faults()
        deadlines = [*(m.deadline for m in self.inflight), *(d for _, _, d in self.redispatch if serving)]
        deadline = min([*deadlines, *(d for d in (self.heal_by, self.verdict_by) if d is not None)], default=None)
        if self.config.delta == 0:
            # Perfect synchrony: every executor takes the same step at once (one transition); a clock
            # found off by every drone steps on its own.
            nxt = min(s for d, s in self.steps.items() if d not in self.unbound) + 1
            if (deadline is None or nxt <= deadline) and all(nxt - self._true(d) <= 1 for d in self.unbound):
                moves.append(("step", -1))
            return moves + self._steps_of([i for i, d in enumerate(self.config.drones) if d in self.unbound],
                                          deadline)
        return moves + self._steps_of(list(range(len(self.config.drones))), deadline)

    def _steps_of(self, drones: list[int], deadline: int | None) -> list[Transition]:
        """The steps these drones may take: within Delta of every other drone's step (rho_Delta), a clock
        found off by every drone read less its offset (see Faults.skews); none past a deadline."""
        moves: list[Transition] = []
        for i in drones:
            drone = self.config.drones[i]
            nxt = self._true(drone) + 1
            others_low = min((self._true(d) for d in self.steps if d != drone), default=nxt)
            # A clock off steps on its own even at Delta 0 (the others in one transition): a step apart.
            ahead = self.config.delta if drone not in self.unbound else max(self.config.delta, 1)
            if nxt - min(others_low, nxt) > ahead:
                continue  # rho_Delta: it would run more than Delta steps ahead
            if deadline is not None and nxt > deadline:
                continue  # a message must arrive first
            moves.append(("step", i))
        return moves

    def _true(self, drone: str) -> int:
        """``drone``'s step, less its clock's offset once every drone knows it is off."""
        return self.steps[drone] - (self.offsets.get(drone, 0) if drone in self.unbound else 0)

    def apply(self, move: Transition) -> None:
        kind, arg = move
        if kind == "deliver":
            self._deliver(arg)
        elif kind == "inject":
            self._inject()
        elif kind == "duplicate":
            self._duplicate(arg)
        elif kind == "cancel":
            self._cancel(arg)
        elif kind == "down":
            self._vehicle_down(self.config.drones[arg])
        elif kind == "crash":
            self._crash(self.config.drones[arg])
        elif kind == "restart":
            self._restart(self.config.drones[arg])
        elif kind == "partition":
            self._partition(self.config.drones[arg])
        elif kind == "heal":
            self._heal()
        elif kind == "skew":
            self._skew(self.config.drones[arg // 2], ahead=arg % 2 == 0)
        elif kind == "verdict":
            self._verdict(self.config.drones[arg])
        elif arg < 0:
            for drone in self.config.drones:
                if drone not in self.unbound:
                    self._step(drone)
        else:
            self._step(self.config.drones[arg])

    def actor(self, move: Transition) -> tuple[str, str]:
        """Who makes the move: the network for a receiver, the environment, or a drone's clock."""
        kind, arg = move
        if kind == "deliver":
            return ("net", self.net.find(arg).to)
        if kind in ("inject", "cancel"):
            return ("env", "")
        if kind == "duplicate":
            return ("net", "dup")
        if kind in ("partition", "heal"):
            return ("net", "cut")
        if kind == "down":
            return ("vehicle", self.config.drones[arg])
        if kind in ("crash", "restart", "verdict"):
            return ("agent", self.config.drones[arg])
        if kind == "skew":
            return ("clock", self.config.drones[arg // 2])
        return ("clock", self.config.drones[arg] if arg >= 0 else "*")

    def state_key(self) -> Hashable:
        """The state, less what does not change the future (trace, message numbers, old history)."""
        return self.state_key_with(tuple(self.stack_key(d) for d in self.config.drones))

    def clone(self) -> World:
        """An independent copy for the DFS: machines copied one level deep, values shared
        (every value in them is immutable), the trace left behind."""
        new = copy.copy(self)
        new.stacks = {d: clone_stack(s) for d, s in self.stacks.items()}
        new.steps, new.battery, new.net = dict(self.steps), dict(self.battery), self.net.copy()
        new.redispatch, new.down, new.crashed = list(self.redispatch), dict(self.down), set(self.crashed)
        new.holder, new.cleared = dict(self.holder), set(self.cleared)
        new.unheard = {d: dict(reports) for d, reports in self.unheard.items()}
        new.told, new.offsets = dict(self.told), dict(self.offsets)
        new.monitors = shallow(self.monitors)
        new.monitors.history = {d: list(h) for d, h in self.monitors.history.items()}
        new.trace = []
        return new

    @property
    def finished(self) -> bool:
        """Every request arrived and was delivered, and the network is quiet."""
        return (self.injected == len(self.config.requests) and not self.redispatch and not self.inflight
                and len(self.monitors.settled) == len(self.config.requests))

    # ------------------------------------------------------- transitions
    def _deliver(self, seq: int) -> None:
        msg = self.net.take(seq)
        self.trace.append(f"{msg.to} <- {msg.sender}: {describe(msg.message)}")
        stack, notice = self.stacks[msg.to], msg.message
        if not isinstance(notice, (Left, PlanProposal, Clear)):  # a proposal says nothing of what it flies now
            self.monitors.heard_from(msg.to, msg.sender)
        if isinstance(notice, Announce) and notice.grounded:
            self.monitors.heard_news(msg.to, msg.sender, self.steps[msg.to])
            self._carry_out(msg.to, stack.peer_down(msg.sender, notice.trajectory.last))
        elif isinstance(notice, Announce) and notice.braked:
            self.monitors.heard_news(msg.to, msg.sender, self.steps[msg.to])
            self._carry_out(msg.to, stack.peer_braked(msg.sender, notice.trajectory))
        elif isinstance(notice, Announce):
            self._carry_out(msg.to, stack.heard(msg.sender, notice.trajectory))
        elif isinstance(notice, Holds):
            self.monitors.heard_news(msg.to, msg.sender, self.steps[msg.to])
            self._carry_out(msg.to, stack.peer_lost(msg.sender, notice.cells, notice.for_now, notice.seq))
        elif isinstance(notice, Left):
            self.monitors.left(msg.to, msg.sender)
            self._carry_out(msg.to, stack.peer_left(msg.sender, notice.since))
        elif isinstance(notice, Clear):
            stack.mail.clear(notice.mail_id)
        elif isinstance(notice, Joined):
            # As the agent does: where it was last heard of (its start, if never).
            last = stack.protocol.known.get(msg.sender)
            cell = last.last if last is not None else stack.protocol.peers[msg.sender]
            self._carry_out(msg.to, stack.peer_joined(msg.sender, cell, last))
        else:
            if isinstance(notice, ReqForCurrentTraj) and self._where(msg.to) in notice.clear:
                self.monitors.asked_to_leave(msg.to, notice.clear)
            self._carry_out(msg.to, stack.receive(notice))

    def _step(self, drone: str) -> None:
        stack = self.stacks[drone]
        step = self.steps[drone] + 1
        self.steps[drone] = step
        if drone in self.crashed:  # its clock runs on; its vehicle holds, with nobody to judge its battery
            self.monitors.position(drone, step, stack.executor.cell, self.steps, flies=False)
            return
        if drone not in self.down:  # a vehicle down is on the ground: it draws nothing
            self.battery[drone] = self._battery_after_step(stack, self.battery[drone])
        self.monitors.battery(drone, step, self.battery[drone])
        self.trace.append(f"{drone} steps to {step} (battery {self.battery[drone]:.0f})")
        # The model's vehicles fly their plans exactly: each is where its last step took it.
        self._carry_out(drone, stack.step(step, self.battery[drone], flown=self._where(drone),
                                          may_plan=drone not in self.down and not self._off(drone)))
        # A vehicle down stays where it came down, whatever its stack's plan says.
        self.monitors.position(drone, step, self._where(drone), self.steps, flies=drone not in self.down)
        if self.injected == len(self.config.requests):
            out = set(self.down) | self.crashed | {d for d in self.config.drones if self._off(d)}
            blocked = frozenset(self._where(d) for d in out)
            fleet = {d: Flier(s.executor.cell, self.battery[d], s.config.recharged_mark, s.protocol.lead_steps + 1)
                     for d, s in self.stacks.items() if d not in out}
            self.monitors.liveness(min(self.steps.values()) - self.last_injection_step, self.wait_for, blocked,
                                   fleet, frozenset(self.crashed))

    # --------------------------------------------- for the exhaustive search (see .dfs)
    def touched_by(self, move: Transition) -> frozenset[str]:
        """The drones whose stacks ``apply(move)`` may change: the receiver of a message, the drone
        that steps; none for a duplicate; every drone for the other moves."""
        kind, arg = move
        drones = self.config.drones
        if kind == "deliver":
            return frozenset(m.to for m in self.inflight if m.seq == arg)
        if kind == "step" and arg >= 0:
            return frozenset((drones[arg],))
        if kind == "duplicate":
            return frozenset()
        return frozenset(drones)

    def clone_for(self, move: Transition) -> World:
        """Like :meth:`clone`, but the stacks ``move`` leaves alone are shared, not copied: the
        search applies ``move`` to the copy and never changes a world it has copied from."""
        touched, stacks = self.touched_by(move), self.stacks
        # clone() copies what it copies; it is given only the stacks the move may change.
        self.stacks = {d: s for d, s in stacks.items() if d in touched}
        try:
            new = self.clone()
        finally:
            self.stacks = stacks
        new.stacks = {d: new.stacks.get(d, s) for d, s in stacks.items()}
        return new

    def stack_key(self, drone: str) -> Hashable:
        """One drone's stack as :meth:`state_key` sees it."""
        return key_of_stack(self.stacks[drone])

    def state_key_with(self, stack_keys: tuple[Hashable, ...]) -> Hashable:
        """:meth:`state_key`, given every stack's :meth:`stack_key` (in drone order), so that a search
        that changed one stack need not work out the others' again; and the flown cells in drone
        order, so that the order in which the drones first stepped does not tell states apart."""
        keep, history = self.config.delta + 2, self.monitors.history
        return (
            stack_keys,
            tuple(self.steps.values()), tuple(self.battery.values()),
            self.net.key(),
            self.injected, tuple((d, r.id, t) for d, r, t in self.redispatch), self.used, frozenset(self.down.items()),
            frozenset(self.holder.items()), frozenset(self.cleared),
            tuple((d, tuple(r.items())) for d, r in sorted(self.unheard.items())),
            frozenset(self.crashed), self.apart, self.heal_by, frozenset(self.monitors.settled),
            self.skewed, frozenset(self.told.items()), self.unbound, frozenset(self.offsets.items()), self.verdict_by,
            # In drone order, not in the order the drones first stepped, which is no part of the state.
            tuple(tuple(history[d][-keep:]) for d in self.config.drones if d in history),
            self.monitors.key(),
        )
