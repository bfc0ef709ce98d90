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
"""

from __future__ import annotations

import copy
import functools
import random
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, TypeVar

from drona_gcs.dispatch import Candidate, choose_drone
from drona_gcs.errors import ProblemError
from drona_gcs.motion import Trajectory
from drona_gcs.planner import SafePlanner
from drona_gcs.stack.battery import BatteryLow, BatteryModel, BatteryRecharged
from drona_gcs.stack.drone import DroneStack, StackConfig, leg_overhead
from drona_gcs.stack.mail import (
    GoTo,
    MailDelivered,
    MailLost,
    MailPickedUp,
    MailPlanner,
    MailProgress,
    MailRejected,
    MailRequest,
    MailStarted,
    Phase,
)
from drona_gcs.stack.messages import CurrentTraj, Message, PlanDecision, PlanProposal, ReqForCurrentTraj
from drona_gcs.stack.protocol import (
    Braked,
    Broadcast,
    Grounded,
    Present,
    RerouteFailed,
    Send,
    StartExecuting,
    State,
    TaskFailed,
    Threatened,
)
from drona_gcs.verify.monitors import SKEW_STEPS, Flier, Monitors, cell_text, cells_text
from drona_gcs.verify.mutants import planner_delta, plant
from drona_gcs.workload import random_workspace
from drona_gcs.workspace import Cell, Workspace

Transition = tuple[str, int]
_T = TypeVar("_T")


@dataclass(frozen=True)
class Faults:
    """How many of each fault of the field a run may see (each at any point the schedule picks)."""

    duplicates: int = 2  #: a message delivered twice
    cancels: int = 1  #: a mail cancelled by its sender (taken back only while it waits in a queue)
    downs: int = 1  #: a vehicle that comes down by itself: its mail is handed back (or lost, on board)
    #: agents that crash (the vehicle holds its cell in the air; messages to it are lost; its peers
    #: see it leave) and may restart there later (its peers see it join); none unless asked for
    crashes: int = 0
    #: a drone cut off from the rest for a while (messages across the cut lost; each side sees the
    #: other leave, and join again once it heals, within PARTITION_STEPS); none unless asked for
    partitions: int = 0
    #: a drone whose clock goes beyond the fleet's bound: each drone's clock check says so at a point the
    #: schedule picks (to the drone: its clock is off; to a peer: that drone's is), and once every drone
    #: knows, its steps keep within Delta of the others' shifted by Delta + SKEW_STEPS, ahead or behind;
    #: none unless asked for
    skews: int = 0

    @classmethod
    def none(cls) -> Faults:
        """The paper's model: none of the field's faults."""
        return cls(0, 0, 0, 0)


@dataclass(frozen=True)
class Upgrade:
    """The configuration of the mixed fleet's last drone, as during a rolling upgrade."""

    extra_lead: int = 2  #: lead steps more than the others' (see :func:`model_lead`)
    low_mark: float = 35.0
    recharged_mark: float = 90.0


UPGRADE = Upgrade()


MODEL_CLIMB_STEPS = 2  #: a landed model drone's take-off before its plan starts (one in the air needs none)


def model_hover_lead(delta: int, max_delay: int) -> int:
    """Lead steps of the model's drones in the air: the stack's default (Delta + 1), and at least a
    plan's round trip to be held by every peer (its proposal and the acks, ``max_delay`` steps each)
    and a step, so that a plan is never dropped for the model's network alone."""
    return max(delta + 1, 2 * max_delay + 1)


def model_lead(delta: int, max_delay: int) -> int:
    """Lead steps of the model's landed drones, which climb first."""
    return model_hover_lead(delta, max_delay) + MODEL_CLIMB_STEPS
PARTITION_STEPS = 20  #: a partition heals within this many steps of the slowest clock
VERDICT_STEPS = 2  #: every clock check finds a clock off within this many steps of the slowest clock
MAX_DRAWS = 1000  #: random draws of a mail the service accepts, before giving up


@dataclass(frozen=True)
class WorldConfig:
    workspace: Workspace
    drones: tuple[str, ...]
    starts: tuple[Cell, ...]
    requests: tuple[MailRequest, ...]
    assignees: tuple[str, ...]
    delta: int
    bugs: frozenset[str] = frozenset()
    battery: BatteryModel = field(default_factory=BatteryModel)
    initial_battery: tuple[float, ...] = ()  #: per drone; empty: all full
    max_delay: int = 2
    liveness_steps: int = 120  #: every mail delivered within this many steps after the last one arrives
    faults: Faults = field(default_factory=Faults)
    mixed: bool = True  #: the last drone runs another configuration, as during a rolling upgrade


    def __deepcopy__(self, memo: dict[int, object]) -> WorldConfig:
        return self


def make_world_config(workspace: Workspace, drones: int, requests: int, delta: int, seed: int,
                      bugs: frozenset[str] = frozenset(), **options: object) -> WorldConfig:
    """Drones at the workspace's starts (random free cells for the rest) and random mail."""
    rng = random.Random(seed)
    region = sorted(workspace.main_region)
    ids = list(workspace.drones)[:drones]
    starts = [workspace.drones[d] for d in ids]
    spare = [c for c in region if c not in starts and c not in workspace.charging_stations
             and c not in workspace.parking]
    while len(ids) < drones:
        cell = rng.choice(spare)
        spare.remove(cell)
        ids.append(f"d{len(ids)}")
        starts.append(cell)
    # Mail never goes to a parking cell or charger: a drone may rest there for good.
    spots = set(workspace.parking) | set(workspace.charging_stations)
    pickups = [c for c in list(workspace.pickups) or region if c not in spots]
    dropoffs = [c for c in list(workspace.dropoffs) or region if c not in spots]
    model = options.get("battery") or _battery_for(workspace)
    assert isinstance(model, BatteryModel)
    options = {**options, "battery": model}
    max_delay = options.get("max_delay", WorldConfig.max_delay)
    assert isinstance(max_delay, int)
    accepts = _service_check(workspace, model, model_lead(delta, max_delay))
    mail = []
    for i in range(requests):
        for _ in range(MAX_DRAWS):
            pickup = rng.choice(pickups)
            request = MailRequest(f"m{i}", pickup, rng.choice([c for c in dropoffs if c != pickup]),
                                  rng.randint(0, 9), seq=i)
            if accepts(request):
                break
        else:
            raise ProblemError(f"no mail a charged drone can fly in {MAX_DRAWS} draws: grid too large for the battery")
        mail.append(request)
    assignees = tuple(ids[i % len(ids)] for i in range(requests))
    # Batteries start part-charged, so charging and the energy checks are exercised.
    levels = tuple(_initial_level(workspace, start, model, rng) if workspace.charging_stations else 100.0
                   for start in starts)
    # Generous enough for a drone's share of the mail, a charge and the detours of a busy grid. The
    # share is of the drones left flying once the faults took theirs: the service gives their mail on.
    faults = options.get("faults", Faults())
    assert isinstance(faults, Faults)
    per_drone = -(-requests // max(1, len(ids) - faults.crashes - faults.downs))
    span = workspace.nx + workspace.ny + workspace.nz
    liveness = 8 * span * (per_drone + 1) + 100
    defaults: dict[str, object] = {"initial_battery": levels, "liveness_steps": liveness}
    return WorldConfig(workspace, tuple(ids), tuple(starts), tuple(mail), assignees, delta, bugs,
                       **{**defaults, **options})  # type: ignore[arg-type]


def _battery_for(workspace: Workspace) -> BatteryModel:
    """A battery that flies across the workspace and back, with its margin: the default one where it
    does (8x8, 16x16), a slower drain on larger grids (32x32), where no mail would be affordable."""
    default = BatteryModel()
    need = 2 * (workspace.nx + workspace.ny + workspace.nz - 3) + default.margin_steps
    affordable = default.steps_affordable(95.0)
    if need <= affordable:
        return default
    return BatteryModel(drain_per_step=default.drain_per_step * affordable / need)


def _service_check(workspace: Workspace, model: BatteryModel, lead: int) -> Callable[[MailRequest], bool]:
    """The service's energy check: it takes only mail that a drone charged at a station can fly,
    whichever configuration it runs (see :data:`UPGRADE`)."""
    chargers = workspace.charging_stations
    to = functools.lru_cache(maxsize=None)(workspace.distances_from)

    def distance(a: Cell, b: Cell) -> int:
        return to(b).get(a, 10**6)

    def accepts(request: MailRequest) -> bool:
        for recharged, steps in ((95.0, lead), (UPGRADE.recharged_mark, lead + UPGRADE.extra_lead)):
            planner = MailPlanner(chargers[0], chargers, workspace.parking, distance, model,
                                  recharged_level=recharged, leg_overhead=leg_overhead(steps))
            planner.assign(request)
            if any(isinstance(a, MailRejected) for a in planner.decide(0, recharged, ())):
                return False
        return True

    return accepts if chargers else lambda request: True


def _initial_level(workspace: Workspace, start: Cell, model: BatteryModel, rng: random.Random) -> float:
    """Part-charged, so charging and the energy rules are exercised: enough to reach the second
    nearest charger with the margin to spare, plus up to 20 points."""
    far = workspace.distances_from(start)
    ways = sorted(far.get(c, 0) for c in workspace.charging_stations)
    reach = ways[min(1, len(ways) - 1)] if ways else 0
    floor = model.safe_threshold + (reach + model.margin_steps) * model.drain_per_step
    return float(min(100, round(floor) + 1 + rng.randint(0, 20)))


def tester_workspace(width: int, height: int, layers: int, obstacle_ratio: float, seed: int,
                     drones: int) -> Workspace:
    """A random grid for the tester, with two chargers and a parking cell per drone on its rim."""
    rough = random_workspace(width, height, random.Random(seed), obstacle_ratio, layers)
    free = sorted(rough.main_region)
    rim = [c for c in free if c[0] in (0, width - 1) or c[1] in (0, height - 1)] or free

    def nearest(target: Cell, pool: list[Cell]) -> Cell:
        return min(pool, key=lambda c: (abs(c[0] - target[0]) + abs(c[1] - target[1]) + c[2], c))

    chargers: list[Cell] = []
    parking: list[Cell] = []

    def usable(cell: Cell, group: list[Cell]) -> bool:
        """Drones resting on the group and ``cell`` must not cut the grid."""
        return cell not in chargers and cell not in parking and not rough.cells_cut_off_by([*group, cell])

    for corner in ((0, 0, 0), (width - 1, height - 1, 0)):
        chargers.append(nearest(corner, [c for c in rim if usable(c, chargers)]))
    for i in range(drones):
        pool = [c for c in rim if usable(c, parking) and not rough.cells_cut_off_by([*parking, *chargers, c])]
        if not pool:
            break
        parking.append(pool[(i * len(pool)) // drones])
    return Workspace.build(size=rough.size, obstacles=rough.obstacles, charging_stations=tuple(chargers),
                           parking=tuple(parking), name=f"tester-{width}x{height}x{layers}-{seed}")


@dataclass(frozen=True)
class Announce:
    """The sender's new plan, as every drone reads it (the answers on ``answers``, or ``plan/<me>``)."""

    trajectory: Trajectory
    grounded: bool = False  #: the sender's vehicle came down: it stays at the trajectory's end for good
    braked: bool = False  #: the sender cut its plan short of a cell held for good (read as any plan)


@dataclass(frozen=True)
class Left:
    """Liveliness: the sender's agent is gone, silent since its step ``since``."""

    since: int


@dataclass(frozen=True)
class Joined:
    """Liveliness: the sender's agent is back."""


@dataclass(frozen=True)
class Clear:
    """The service holds ``mail_id`` as the receiver's from now on: it may take it on board."""

    mail_id: str


#: The sender of the service's clearances (``drona serve``: the drone's mail/clear query).
SERVICE = "service"

Notice = Message | Announce | Left | Joined | Clear


@dataclass(frozen=True)
class InFlight:
    seq: int
    sender: str
    to: str
    message: Notice
    deadline: int
    sent: int = -1  #: the seq it was sent as (a duplicate keeps its original's); -1: ``seq``

    @property
    def sent_as(self) -> int:
        return self.seq if self.sent < 0 else self.sent

    @functools.cached_property
    def key(self) -> tuple[str, str, str, int]:
        """What it is in a state's key: not its number. Worked out once, as copies of a world share it."""
        return (self.sender, self.to, repr(self.message), self.deadline)


class World:
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
        self.inflight: list[InFlight] = []
        self.injected = 0
        #: handed-back mail the service gives again: to which drone, and by which step of the sender's clock
        self.redispatch: list[tuple[str, MailRequest, int]] = []
        self.last_injection_step = 0
        self.sent = 0
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

    # -------------------------------------------------------- scheduling
    def enabled(self) -> list[Transition]:
        moves: list[Transition] = [("deliver", m.seq) for m in self.inflight if self._in_order(m)]
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
            return ("net", next(m.to for m in self.inflight if m.seq == arg))
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
        new.stacks = {d: _clone_stack(s) for d, s in self.stacks.items()}
        new.steps, new.battery, new.inflight = dict(self.steps), dict(self.battery), list(self.inflight)
        new.redispatch, new.down, new.crashed = list(self.redispatch), dict(self.down), set(self.crashed)
        new.holder, new.cleared = dict(self.holder), set(self.cleared)
        new.unheard = {d: dict(reports) for d, reports in self.unheard.items()}
        new.told, new.offsets = dict(self.told), dict(self.offsets)
        new.monitors = _shallow(self.monitors)
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
        index = next(i for i, m in enumerate(self.inflight) if m.seq == seq)
        msg = self.inflight.pop(index)
        self.trace.append(f"{msg.to} <- {msg.sender}: {_describe(msg.message)}")
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

    def _inject(self) -> None:
        serving = self._serving()
        if self.redispatch and serving:
            handed_back_by, request, _ = self.redispatch.pop(0)
            drone = self._reassign(request, handed_back_by, serving)
        else:
            request, drone = self.config.requests[self.injected], self.config.assignees[self.injected]
            self.injected += 1
            if drone not in serving:  # out of service, or of touch: another, or the queue until one is back
                if not serving:
                    self.trace.append(f"env: mail {request.id} waits: no drone in service and in touch")
                    self.redispatch.append((drone, request, max(self.steps[drone], 0) + self.config.max_delay))
                    return
                drone = self._reassign(request, drone, serving)
        self.last_injection_step = min(self.steps.values())
        self.trace.append(f"env -> {drone}: mail {request.id} p{request.priority} "
                          f"{cell_text(request.pickup)}->{cell_text(request.dropoff)}")
        self.monitors.given_mail(drone, request)
        self.holder[request.id] = drone
        self._carry_out(drone, self.stacks[drone].assign(request))

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

    def _in_order(self, message: InFlight) -> bool:
        """Liveliness changes come in order, and a leave only once the lease outlasted every message
        its agent sent before: after all that went earlier from the same sender to the same drone.
        A message sent after a leave comes after it: the lease ran out while nothing came through
        (one sent after a join may come before it: the join is news of its own)."""
        same_way = [m for m in self.inflight if m.sender == message.sender and m.to == message.to]
        if not isinstance(message.message, (Left, Joined)):
            return not any(isinstance(m.message, Left) and m.seq < message.sent_as for m in same_way)
        return not any(m.sent_as < message.seq for m in same_way)

    def _duplicate(self, seq: int) -> None:
        original = next(m for m in self.inflight if m.seq == seq)
        self.used = replace(self.used, duplicates=self.used.duplicates + 1)
        self.sent += 1
        # A copy of what was sent before a leave still comes before it (one session, in order).
        self.inflight.append(replace(original, seq=self.sent, sent=original.sent_as))
        self.trace.append(f"net: duplicates {_describe(original.message)} to {original.to}")

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
        lost = [m for m in self.inflight if m.to == drone]
        self.inflight = [m for m in self.inflight if m.to != drone]
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
        lost = [m for m in self.inflight if self._across(m.sender, m.to) and not isinstance(m.message, (Left, Joined))]
        self.inflight = [m for m in self.inflight if m not in lost]
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

    def _across(self, a: str, b: str) -> bool:
        return (a in self.apart) != (b in self.apart)

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
                                   fleet)

    def _where(self, drone: str) -> Cell:
        """Where the vehicle is: where it came down, or where its executor put it (a crashed agent's
        executor steps no more: its vehicle holds there)."""
        return self.down.get(drone, self.stacks[drone].executor.cell)

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

    def _carry_out(self, drone: str, actions: Sequence[object]) -> None:
        for action in actions:
            if isinstance(action, Send):
                self._post(drone, action.to, action.message)
            elif isinstance(action, Broadcast):
                for peer in self.config.drones:
                    if peer != drone:
                        self._post(drone, peer, action.message)
            note = _note(action)
            if note:
                self.trace.append(f"{drone}: {note}")
            self.monitors.action(drone, action)
            if isinstance(action, Present):
                self._post(drone, action.to, Announce(action.trajectory, braked=action.braked))
            if isinstance(action, (Grounded, Braked)):  # as the agent does
                for peer in self.config.drones:
                    if peer != drone:
                        self._post(drone, peer, Announce(action.trajectory, grounded=isinstance(action, Grounded),
                                                         braked=isinstance(action, Braked)))
            if isinstance(action, MailProgress):
                self.stacks[drone].mail.reported(action)
                self._report(drone, action)

    # --------------------------------------------------------- the service
    def _report(self, drone: str, action: MailProgress) -> None:
        """A drone's report on its mail: heard by the service, kept for it while cut off, lost with a
        crashed agent."""
        if drone in self.crashed:
            return
        if drone in self.apart:
            kept = self.unheard.setdefault(drone, {})
            kept.pop(action.request.id, None)
            kept[action.request.id] = action
            return
        self._service_hears(drone, action)

    def _service_hears(self, drone: str, action: MailProgress) -> None:
        """As ``drona serve``: a report on mail it holds as another's is ignored; a start is cleared, a
        hand-back given to another drone, a delivery or a loss closes the mail."""
        mail = action.request.id
        if self.holder.get(mail) != drone:
            return
        if isinstance(action, MailStarted) and mail not in self.cleared:
            self.cleared.add(mail)
            self._post(SERVICE, drone, Clear(mail))
        elif isinstance(action, MailRejected):
            self._requeue(drone, action.request)
        elif isinstance(action, (MailDelivered, MailLost)):
            del self.holder[mail]
            self.cleared.discard(mail)

    def _requeue(self, drone: str, request: MailRequest) -> None:
        """The service gives ``request`` to another drone that flies, as promptly as a message: a liveness
        bound needs the service to be fair."""
        del self.holder[request.id]
        self.cleared.discard(request.id)
        self.redispatch.append((drone, request, max(self.steps[drone], 0) + self.config.max_delay))

    def _service_lost(self, drone: str) -> None:
        """The service sees ``drone`` go: the mail it was not cleared to pick up goes to another drone;
        the rest stays its own (it may be on board). Mail cleared to a crashed agent is never delivered
        (nobody can tell whether it is on board): (d) expects it no more."""
        for mail, holder in sorted(self.holder.items()):
            if holder != drone:
                continue
            if mail not in self.cleared:
                self.trace.append(f"service: {drone} lost before the pickup of {mail}: given to another")
                self._requeue(drone, self._request(mail))
            elif drone in self.crashed:
                self.monitors.given_up(drone, self._request(mail))

    def _service_back_new(self, drone: str) -> None:
        """A restarted agent knows none of its old mail: what the service cleared it for may be on board
        the vehicle its old agent left, and is failed (never given to a second drone)."""
        for mail, holder in sorted(self.holder.items()):
            if holder == drone:
                self.trace.append(f"service: {drone} restarted: {mail} failed (it may be on board)")
                del self.holder[mail]
                self.cleared.discard(mail)
                self.monitors.given_up(drone, self._request(mail))

    def _request(self, mail_id: str) -> MailRequest:
        return next(r for r in self.config.requests if r.id == mail_id)

    def _serving(self) -> list[str]:
        """The drones the service may give mail: vehicle flying, agent alive, in touch."""
        return [d for d in self.config.drones
                if d not in self.down and d not in self.crashed and d not in self.apart and not self._off(d)]

    def _off(self, drone: str) -> bool:
        """Its clock check found its own clock off: it takes no task (its health says so to the service)."""
        return drone in self.told.get(drone, frozenset())

    def _reassign(self, request: MailRequest, handed_back_by: str, serving: list[str]) -> str:
        """The drone the service gives ``request`` to, by the fleet's one rule (as ``drona serve``'s):
        of the drones ``serving`` but the one that handed it back (if there are others), the fewest
        mails held, idle first, the nearest to the pickup."""
        others = [d for d in serving if d != handed_back_by] or serving
        candidates = [Candidate(d, self._where(d), _held(self.stacks[d]),
                                self.stacks[d].protocol.state is not State.WAIT_FOR_TASK) for d in others]
        chosen = choose_drone(candidates, request.pickup)
        assert chosen is not None  # serving is not empty
        return chosen

    def _post(self, sender: str, to: str, message: Notice, liveliness: bool = False) -> None:
        """``liveliness``: a leave or join each side's session sees by itself, across a cut too."""
        if to in self.crashed:
            self.trace.append(f"net: {_describe(message)} to {to} is lost (its agent crashed)")
            return
        if self._across(sender, to) and not liveliness:
            self.trace.append(f"net: {_describe(message)} to {to} is lost (the partition)")
            return
        self.sent += 1
        # Within max_delay steps of the sender's clock: the bound is local to the sender,
        # so sending does not depend on how far the other drones' clocks have got (the service's: the
        # receiver's).
        deadline = max(self.steps[to if sender == SERVICE else sender], 0) + self.config.max_delay
        self.inflight.append(InFlight(self.sent, sender, to, message, deadline))

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
        return _stack_key(self.stacks[drone])

    def state_key_with(self, stack_keys: tuple[Hashable, ...]) -> Hashable:
        """:meth:`state_key`, given every stack's :meth:`stack_key` (in drone order), so that a search
        that changed one stack need not work out the others' again; and the flown cells in drone
        order, so that the order in which the drones first stepped does not tell states apart."""
        keep, history = self.config.delta + 2, self.monitors.history
        return (
            stack_keys,
            tuple(self.steps.values()), tuple(self.battery.values()),
            tuple(sorted(m.key for m in self.inflight)),
            self.injected, tuple((d, r.id, t) for d, r, t in self.redispatch), self.used, frozenset(self.down.items()),
            frozenset(self.holder.items()), frozenset(self.cleared),
            tuple((d, tuple(r.items())) for d, r in sorted(self.unheard.items())),
            frozenset(self.crashed), self.apart, self.heal_by, frozenset(self.monitors.settled),
            self.skewed, frozenset(self.told.items()), self.unbound, frozenset(self.offsets.items()), self.verdict_by,
            # In drone order, not in the order the drones first stepped, which is no part of the state.
            tuple(tuple(history[d][-keep:]) for d in self.config.drones if d in history),
            self.monitors.key(),
        )

def _describe(message: Notice) -> str:
    name = type(message).__name__
    if isinstance(message, CurrentTraj):
        return f"{name}(from {message.sender}, re {message.in_reply_to}, {cells_text(message.trajectory)})"
    if isinstance(message, Announce) and message.grounded:
        return f"{name}(vehicle down in {cell_text(message.trajectory.last)})"
    if isinstance(message, Announce):
        return f"{name}({cells_text(message.trajectory)})"
    if isinstance(message, Left):
        return f"{name}(silent since step {message.since})"
    if isinstance(message, Joined):
        return name
    if isinstance(message, Clear):
        return f"{name}({message.mail_id})"
    if isinstance(message, PlanDecision):
        return f"{name}(task {message.task_id} of {message.sender}: {'flown' if message.flown else 'dropped'})"
    return f"{name}(task {message.task_id} of {message.sender})"


def _note(action: object) -> str:
    """A line of the trace for the actions worth reading; empty for the rest."""
    if isinstance(action, StartExecuting):
        t = action.trajectory
        return f"plans task {action.task.id}: {cells_text(t, len(t.cells))}"
    if isinstance(action, TaskFailed):
        return f"no plan for task {action.task.id} to {cell_text(action.task.goal)}: {action.reason}"
    if isinstance(action, Threatened):
        return f"{action.departed} may hold {cell_text(action.cells[0])} of my plan for good: plans its rest anew"
    if isinstance(action, RerouteFailed):
        return f"no new plan for the rest of mine (task {action.task.id}): {action.reason}"
    if isinstance(action, Braked):
        t = action.trajectory
        return f"brakes short of {cell_text(action.held)}, held for good: holds {cell_text(t.last)} from {t.end_step}"
    if isinstance(action, GoTo):
        by = f" within {action.flight_steps} steps of flight" if action.flight_steps is not None else ""
        return f"task planner: go to {cell_text(action.goal)} for {action.purpose.value}{by}"
    if isinstance(action, (MailStarted, MailPickedUp, MailDelivered)):
        return f"{type(action).__name__} {action.request.id}"
    if isinstance(action, (MailRejected, MailLost)):
        return f"{type(action).__name__} {action.request.id}: {action.reason}"
    if isinstance(action, (BatteryLow, BatteryRecharged)):
        return f"{type(action).__name__} at {action.level:.0f}%"
    return ""


#: Attributes that are the same in every state of a run (shared, immutable or functions).
_STATIC = frozenset({"config", "plan", "distance", "bugs", "peers", "battery", "chargers", "parking"})
_MACHINES = ("clock", "protocol", "executor", "monitor", "mail")


def _shallow(machine: _T) -> _T:
    """A copy whose containers are new and whose values (all immutable) are shared."""
    new = object.__new__(type(machine))
    vars(new).update({name: value.copy() if isinstance(value, (dict, list, set)) else value
                      for name, value in vars(machine).items()})
    return new


def _clone_stack(stack: DroneStack) -> DroneStack:
    new = stack.copy()
    for name in _MACHINES:
        setattr(new, name, _shallow(getattr(new, name)))
    return new


def _stack_key(stack: DroneStack) -> Hashable:
    # What the stack keeps besides its machines.
    own = (stack.arrival, stack.unreached, stack.asked_clear, stack.stuck, stack.stop_short, stack.threat,
           stack.braked, stack.resting_now, stack.in_touch)
    return (*(_machine_key(getattr(stack, name)) for name in _MACHINES), own)


def _machine_key(machine: object) -> Hashable:
    return tuple(_FREEZE.get(type(value), _as_is)(value) for name, value in vars(machine).items()
                 if name not in _STATIC)


def _as_is(value: Hashable) -> Hashable:
    return value


#: How a machine's mutable attribute enters the key (any other value is immutable, and enters as it is).
_FREEZE: dict[type, Callable[[Any], Hashable]] = {
    dict: lambda value: frozenset(value.items()), set: frozenset, list: tuple,
}


def _held(stack: DroneStack) -> int:
    """The mail a drone holds: queued, current or on board."""
    return len(stack.mail.queue) + (stack.mail.current is not None)
