"""The world's fleet: the drones' stacks over the in-memory network, and what the world knows of them.

:class:`Fleet` holds the world's state; :mod:`.service`, :mod:`.faults` and :mod:`.world` add, layer by
layer, the service's dispatch, the field's faults and the scheduler's transitions.
"""

from __future__ import annotations

from dataclasses import replace

from drona_gcs.planner import SafePlanner
from drona_gcs.stack.drone import DroneStack, StackConfig
from drona_gcs.stack.mail import MailProgress, MailRequest, Phase
from drona_gcs.verify.config import UPGRADE, Faults, WorldConfig, model_hover_lead, model_lead
from drona_gcs.verify.monitors import Monitors
from drona_gcs.verify.mutants import planner_delta, plant
from drona_gcs.verify.network import InFlight, Network
from drona_gcs.verify.notices import SERVICE, Notice, describe
from drona_gcs.verify.verdicts import cell_text
from drona_gcs.workspace import Cell

Transition = tuple[str, int]


class Fleet:
    """The drones' stacks, their clocks and batteries, the network, the faults so far, the service's
    books, and the monitors."""

    def __init__(self, config: WorldConfig, planner: SafePlanner) -> None:
        self.config = config
        needed = planner_delta(config.delta, config.bugs)
        if planner.delta != needed:
            raise ValueError(f"planner has delta {planner.delta}, the world needs {needed}")
        lead, hover = model_lead(config.delta, config.max_delay), model_hover_lead(config.delta, config.max_delay)
        stack = StackConfig(config.workspace, planner, config.battery, lead_steps=lead, hover_lead_steps=hover)
        # A rolling upgrade: the last drone runs another configuration (longer leads, other marks).
        upgraded = replace(stack, lead_steps=lead + UPGRADE.extra_lead, hover_lead_steps=hover + UPGRADE.extra_lead,
                           low_mark=UPGRADE.low_mark, recharged_mark=UPGRADE.recharged_mark)
        peers = dict(zip(config.drones, config.starts, strict=True))
        self.stacks = {d: DroneStack(d, upgraded if config.mixed and d == config.drones[-1] else stack, peers)
                       for d in config.drones}
        for planted in self.stacks.values():
            planted.mail.cleared = set()  # the service dispatches the mail, as under drona serve
            plant(planted, config.bugs)
        self.steps = dict.fromkeys(config.drones, -1)
        levels = config.initial_battery or tuple(100.0 for _ in config.drones)
        self.battery = dict(zip(config.drones, levels, strict=True))
        self.net: Network[Notice] = Network()
        self.injected = 0
        #: handed-back mail the service gives again: to which drone, and by which step of the sender's clock
        self.redispatch: list[tuple[str, MailRequest, int]] = []
        self.last_injection_step = 0
        self.used = Faults.none()  #: faults so far
        self.down: dict[str, Cell] = {}  #: vehicles that came down by themselves, and where
        self.crashed: set[str] = set()  #: drones whose agent crashed (not restarted yet)
        self.apart: frozenset[str] = frozenset()  #: drones cut off from the rest by a partition
        self.heal_by: int | None = None  #: the step of the slowest clock by which the partition heals
        self.skewed: frozenset[str] = frozenset()  #: drones whose clock went beyond the fleet's bound
        self.told: dict[str, frozenset[str]] = {}  #: each drone's clock verdict so far: the drones it found off
        self.unbound: frozenset[str] = frozenset()  #: skewed drones every drone knows of: their steps run free
        self.offsets: dict[str, int] = {}  #: each skewed clock's offset, in steps
        self.verdict_by: int | None = None  #: the step of the slowest clock by which every check has found it
        #: The service (drona serve): which drone it holds each mail given out as, the mail it cleared
        #: for pickup, and each cut-off drone's last report on each mail, which it sends again once back.
        self.holder: dict[str, str] = {}
        self.cleared: set[str] = set()
        self.unheard: dict[str, dict[str, MailProgress]] = {}
        self.monitors = Monitors(config)
        self.trace: list[str] = []

    @property
    def inflight(self) -> list[InFlight[Notice]]:
        """What is in flight, oldest first (the network's)."""
        return self.net.inflight

    @inflight.setter
    def inflight(self, messages: list[InFlight[Notice]]) -> None:
        self.net.inflight = messages

    @property
    def sent(self) -> int:
        """How many messages were ever posted: the last one's number."""
        return self.net.sent

    def _post(self, sender: str, to: str, message: Notice, liveliness: bool = False) -> None:
        """``liveliness``: a leave or join each side's session sees by itself, across a cut too."""
        if to in self.crashed:
            self.trace.append(f"net: {describe(message)} to {to} is lost (its agent crashed)")
            return
        if self._across(sender, to) and not liveliness:
            self.trace.append(f"net: {describe(message)} to {to} is lost (the partition)")
            return
        # Within max_delay steps of the sender's clock: the bound is local to the sender,
        # so sending does not depend on how far the other drones' clocks have got (the service's: the
        # receiver's).
        deadline = max(self.steps[to if sender == SERVICE else sender], 0) + self.config.max_delay
        self.net.post(sender, to, message, deadline)

    def _across(self, a: str, b: str) -> bool:
        return (a in self.apart) != (b in self.apart)

    def _where(self, drone: str) -> Cell:
        """Where the vehicle is: where it came down, or where its executor put it (a crashed agent's
        executor steps no more: its vehicle holds there)."""
        return self.down.get(drone, self.stacks[drone].executor.cell)

    def _off(self, drone: str) -> bool:
        """Its clock check found its own clock off: it takes no task (its health says so to the service)."""
        return drone in self.told.get(drone, frozenset())

    def wait_for(self) -> str:
        """Who waits for whom at the end of a run that did not finish: each drone's protocol state, the
        peers a coordinating one still needs an answer from, and the mail it holds."""
        lines = []
        for drone, stack in self.stacks.items():
            protocol, mail = stack.protocol, stack.mail
            held = [r.id for r in ([mail.current] if mail.current else []) + list(mail.queue)]
            line = f"{drone} {protocol.state.value} at {cell_text(stack.executor.cell)}, {mail.phase.value}"
            if protocol.task is not None:
                line += f", task {protocol.task.id} to {cell_text(protocol.task.goal)}"
            if protocol.coordinating:
                line += f", waits for {sorted(protocol.members - set(protocol.received)) or 'nobody'}"
            lines.append(line + f", holds {held}, battery {self.battery[drone]:.0f}%")
        return "; ".join(lines)

    def _battery_after_step(self, stack: DroneStack, level: float) -> float:
        model = self.config.battery
        if not self.config.workspace.charging_stations:
            return level  # nowhere to charge: batteries are not modelled
        if stack.mail.phase is Phase.CHARGING and stack.executor.cell in self.config.workspace.charging_stations:
            return min(100.0, level + model.charge_per_step)
        if stack.landed:
            return level
        return max(0.0, level - model.drain_per_step)
